"""The demonstration / annotated-episode HDF5 layout (LIBERO's robomimic layout plus ITC labels).

One file holds demos of one or more tasks::

    data/                          attrs: format_version, env_args (JSON), problem_info (JSON),
                                          language_instruction, total, state_layouts (JSON {task_key: layout}),
                                          annotation (JSON, annotated files only: schema_version, gamma,
                                          segment_length, itc_params), collection (JSON: the settings that
                                          made the episodes, e.g. quality and seed, or policy and rollout
                                          settings; a resumed collection must match them)
    data/demo_<i>/                 attrs: num_samples, suite, task_index, task_name, language_instruction,
                                          init_state_index, seed, knobs (JSON), expert_version, success,
                                          perturbation (JSON list), reset_seed, fixture_layout (JSON
                                          {fixture: [x, y, z, qw, qx, qy, qz]}: where LIBERO placed
                                          the fixtures, which `states` does not hold),
                                          goal_geometry (JSON: where the goal's regions and
                                          articulations stand, `base_suites.goal_geometry`);
                                          annotated files add: elegant, violated (JSON list of criteria)
        actions        (T, 7)  float64  OSC_POSE delta + gripper, in [-1, 1]
        states         (T, S)  float64  flattened MuJoCo state (time, qpos, qvel) before each action
        obs/state      (T, D)  float32  the env's low-dimensional `state` before each action
        next_obs/state (T, D)  float32  the same after each action
        rewards        (T,)    float32  1.0 where the task goal holds after the action
        dones          (T,)    uint8    1 at the last step
        final_state    (S,)    float64  the MuJoCo state after the last action (recorded episodes; LIBERO's
                                        own files lack it, and a replay then steps the env once instead)
      annotated files add:
        itc/<criterion>           (T,)          bool  True where the criterion is kept at that step
        itc_segments/<criterion>  (ceil(T/25),) bool  True where the whole window kept it
        elegance_reward           (T,)          float32  1.0 where all four criteria hold
        mc_return                 (T,)          float32  discounted return-to-go of elegance_reward

Step 0 is the first policy step after the settle phase. A task is keyed "<suite>/<task_index>".
The format is versioned from day one: readers refuse files of another major version.
"""

from __future__ import annotations

__all__ = [
    "ANNOTATION_SCHEMA_VERSION",
    "CRITERIA",
    "FORMAT_VERSION",
    "SEGMENT_LENGTH",
    "demo_index",
    "demo_name",
    "task_key",
]

from itc import CRITERIA, ITCParams

FORMAT_VERSION = "libero-elegant/1"
ANNOTATION_SCHEMA_VERSION = 1
SEGMENT_LENGTH = ITCParams().segment_length


def task_key(suite: str, task_index: int) -> str:
    """The key naming a task in files and checkpoints."""
    return f"{suite}/{int(task_index)}"


def demo_name(i: int) -> str:
    return f"demo_{i}"


def demo_index(name: str) -> int:
    return int(name.split("_", 1)[1])
