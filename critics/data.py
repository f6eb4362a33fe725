"""From annotated HDF5 files to a TorchRL replay buffer of Cal-QL transitions.

Each step t of each demo becomes one transition, in TorchRL's layout (batch = transitions):

    observation        (D,)  float32  the state encoded by the critic's encoding (`annotations.features`:
                                      padded + task one-hot, or goal-relative), its continuous part
                                      normalised with the dataset's mean/std
    action             (A,)  float32  the dataset action mapped onto [-1, 1] with the dataset's bounds
    mc_return          (1,)  float32  discounted return-to-go of the training reward, with the critic's
                                      discount (by default the annotation's; Cal-QL's floor;
                                      NO_FLOOR for demos that end without success)
    next/observation   (D,)  float32  the same encoding of the state after the action
    next/action        (A,)  float32  the dataset's next action (the demo's following step's; its own at
                                      the demo's last step): what the in-sample backup bootstraps with
    next/reward        (1,)  float32  the violation penalty: 0 where all four ITCs hold, -1 where one
                                      is violated, judged per step (r_t - 1 of the elegance reward r_t,
                                      `reward="step"`) or per 25-frame window (`reward="segment"`: every
                                      step of a window that violates a criterion gets -1); with
                                      `reward="elegant"` instead 1 at the last step of an elegant
                                      success, else 0 (see `_elegant_success`)
    next/done          (1,)  bool     True at the last step of a demo
    next/terminated    (1,)  bool     True at the last step of a demo that reached the task goal
    next/truncated     (1,)  bool     True at the last step of a demo that did not

Action chunks (`chunk` > 1, for a critic that scores the chunks a chunked policy commits to): step t's
action is the chunk a_t .. a_{t+chunk-1} of its demo, each step normalised as above and flattened
(chunk * A,), repeating the demo's last action past its end, as the BC policy is trained. TorchRL's
`MultiStep` turns the per-step transitions into chunk transitions: next/reward becomes the discounted
sum of the chunk's penalties, next/observation the state after the chunk (or after the demo's last step),
next/action the chunk that starts there, and `steps_to_next_obs` (1,) int64 how many steps that is, so
the loss discounts the bootstrap by gamma ** steps_to_next_obs (Q-chunking's unbiased chunk backup).
next/done, terminated and truncated are those of the chunk's last step (`MultiStep` keeps step t's).
`mc_return` stays the per-step return-to-go from t, which is exactly the value of the chunk executed
from t in the dataset.

Episode ends: the returns-to-go are computed with `torchrl.objectives.value.functional.reward2go`, the
demo's last step being its end, so the return of the last step is its own reward. A demo that reaches
the goal ends in a terminal state (the TD target does not bootstrap past it); a demo that stops without
success is truncated, not terminal: its TD target still bootstraps from the last next-state, while its
Monte-Carlo return, which stops there, bounds the true return from above under the penalty reward, so
those transitions get no Cal-QL floor. The file's own `mc_return` (of the elegance reward, with the
gamma stored in the annotation attrs) is recomputed and checked first, so a file annotated with a
different convention is refused instead of silently miscalibrating the critic.
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch
from tensordict import TensorDict
from torchrl.data import LazyTensorStorage, RandomSampler, TensorDictReplayBuffer
from torchrl.data.postprocs import MultiStep
from torchrl.objectives.value.functional import reward2go

from annotations import CRITERIA, DemoFile, FeatureEncoder, make_encoder
from base_suites.runtime.errors import UserInputError, unknown_choice
from critics.config import REWARDS, TrainConfig
from critics.normalization import Normalization

NO_FLOOR = -1.0e6  # an MC "floor" that never clips (for demos whose return is not a lower bound)

MC_RETURN_TOLERANCE = 1e-4


@dataclass
class TransitionData:
    """The transitions of a set of annotated files and what the critic must remember about them."""

    transitions: TensorDict
    encoder: FeatureEncoder
    normalization: Normalization
    gamma: float
    n_demos: int
    explored: torch.Tensor  # (B,) bool: the transition's action is one a rollout drew at random (`explored_steps`)
    chunk: int = 1

    @property
    def obs_dim(self) -> int:
        return int(self.transitions["observation"].shape[-1])

    @property
    def action_dim(self) -> int:
        return int(self.transitions["action"].shape[-1])

    def fingerprint(self) -> str:
        """A digest of every transition: a resumed training run checks it still reads the same data.
        next/action is left out: it follows from the actions and the demo ends, and runs checkpointed before
        it existed still resume. The explored mask counts only where rows are explored: data without any
        digests as it did before the mask existed."""
        digest = hashlib.sha256()
        for key in sorted((k for k in self.transitions.keys(True, True) if k != ("next", "action")), key=str):
            digest.update(str(key).encode())
            digest.update(self.transitions.get(key).numpy().tobytes())
        if bool(self.explored.any()):
            digest.update(b"explored")
            digest.update(self.explored.numpy().tobytes())
        return digest.hexdigest()


@dataclass
class _RawDemo:
    path: str
    name: str
    task: str
    metadata: dict  # what an env's metadata would say of it: suite, task_index, state_layout, goal_geometry
    obs: np.ndarray
    next_obs: np.ndarray
    actions: np.ndarray
    reward: np.ndarray
    mc_return: np.ndarray
    window_kept: np.ndarray  # per step: did its 25-frame window keep all four criteria
    success: bool
    explored: np.ndarray  # per step: was its action (chunk) an explored decision's


def explored_mask(attrs: dict, steps: int, where: str) -> np.ndarray:
    """The steps a rollout took a random candidate at (attr `explored_steps`, written by `elegant rollouts`);
    none for demos without it."""
    mask = np.zeros(steps, dtype=bool)
    listed = attrs.get("explored_steps") or []
    if not isinstance(listed, list) or not all(isinstance(t, int) and 0 <= t < steps for t in listed):
        raise UserInputError(f"{where}: attr explored_steps must list step indices in [0, {steps}), got {listed!r}")
    mask[listed] = True
    return mask


def _annotation_gamma(f: DemoFile) -> float:
    annotation = f.attrs.get("annotation")
    if not isinstance(annotation, dict) or "gamma" not in annotation:
        raise UserInputError(
            f"{f.path}: data.annotation has no 'gamma' (expected the JSON written by `elegant annotate`)"
        )
    return float(annotation["gamma"])


def segment_length(f: DemoFile) -> int:
    """The window length the file's segment labels were computed with."""
    annotation = f.attrs.get("annotation")
    if not isinstance(annotation, dict) or "segment_length" not in annotation:
        raise UserInputError(
            f"{f.path}: data.annotation has no 'segment_length' (expected the JSON written by `elegant annotate`)"
        )
    return int(annotation["segment_length"])


def step_window_labels(demo, length: int, where: str) -> dict[str, np.ndarray]:
    """Per criterion, per step: did the step's window keep it (human labels included: they live there)."""
    windows = np.arange(demo.num_samples) // length
    expected = int(windows[-1]) + 1
    labels = {}
    for c in CRITERIA:
        segments = demo.itc_segments[c]
        if segments.shape != (expected,):
            raise UserInputError(
                f"{where}/itc_segments/{c} has shape {segments.shape}, expected ({expected},) windows of {length} steps"
            )
        labels[c] = segments[windows]
    return labels


def _read_demos(f: DemoFile, layouts: dict[str, list]) -> list[_RawDemo]:
    demos = []
    length = segment_length(f)
    for demo in f:
        where = f"{f.path}: data/{demo.name}"
        if demo.task_key not in layouts:
            raise UserInputError(f"{f.path}: data.state_layouts has no layout for task {demo.task_key} of {demo.name}")
        width = sum(int(s) for _, s in layouts[demo.task_key])
        t = demo.num_samples
        if t == 0:
            raise UserInputError(f"{where} has no steps")
        for field, value, shape in (
            ("obs/state", demo.obs, (t, width)),
            ("next_obs/state", demo.next_obs, (t, width)),
            ("elegance_reward", demo.elegance_reward, (t,)),
            ("mc_return", demo.mc_return, (t,)),
        ):
            if value.shape != shape:
                raise UserInputError(f"{where}/{field} has shape {value.shape}, expected {shape}")
        demos.append(
            _RawDemo(
                path=f.path,
                name=demo.name,
                task=demo.task_key,
                metadata={
                    "suite": demo.attrs["suite"],
                    "task_index": demo.attrs["task_index"],
                    "state_layout": layouts[demo.task_key],
                    "goal_geometry": demo.attrs.get("goal_geometry"),
                },
                obs=demo.obs,
                next_obs=demo.next_obs,
                actions=np.asarray(demo.actions, dtype=np.float32),
                reward=np.asarray(demo.elegance_reward, dtype=np.float32),
                mc_return=np.asarray(demo.mc_return, dtype=np.float32),
                window_kept=np.logical_and.reduce(list(step_window_labels(demo, length, where).values())),
                success=bool(demo.rewards[-1] > 0),
                explored=explored_mask(demo.attrs, t, where),
            )
        )
    return demos


def _check_returns(demos: list[_RawDemo], returns: np.ndarray, gamma: float) -> None:
    start = 0
    for d in demos:
        mine = returns[start : start + len(d.reward)]
        start += len(d.reward)
        if not np.allclose(mine, d.mc_return, rtol=MC_RETURN_TOLERANCE, atol=MC_RETURN_TOLERANCE):
            worst = int(np.argmax(np.abs(mine - d.mc_return)))
            raise UserInputError(
                f"{d.path}: data/{d.name}/mc_return differs from the discounted return-to-go of elegance_reward "
                f"with gamma={gamma} at step {worst} ({d.mc_return[worst]:.6g} stored, {mine[worst]:.6g} expected)"
            )


def _column(values: np.ndarray | torch.Tensor) -> torch.Tensor:
    """TorchRL keeps rewards, flags and returns as (B, 1)."""
    return torch.as_tensor(values).unsqueeze(-1)


def action_chunks(actions: np.ndarray, chunk: int) -> np.ndarray:
    """(T, A) actions of one episode -> (T, chunk * A): row t holds actions t .. t + chunk - 1, the last
    action repeated past the episode's end."""
    actions = np.asarray(actions)
    ahead = np.minimum(np.arange(len(actions))[:, None] + np.arange(int(chunk)), len(actions) - 1)
    return actions[ahead].reshape(len(actions), -1)


def _following(rows: torch.Tensor, offsets: torch.Tensor | int) -> torch.Tensor:
    """Row t + offsets[t] of one demo's rows, its last row past its end."""
    index = (torch.arange(len(rows)) + offsets).clamp(max=len(rows) - 1)
    return rows[index]


def chunk_transitions(transitions: TensorDict, lengths: Sequence[int], chunk: int, gamma: float) -> TensorDict:
    """Per-step transitions of demos stored back to back (`lengths` steps each) -> chunk transitions (see
    the module docstring); chunk 1 returns them unchanged."""
    if chunk == 1:
        return transitions
    multi_step = MultiStep(gamma=gamma, n_steps=chunk)
    out = []
    for demo in transitions.split(list(lengths)):
        steps = len(demo)
        stepped = multi_step(demo)  # works on a shallow copy
        to_next = stepped["steps_to_next_obs"].reshape(steps)
        last = torch.arange(steps) + to_next - 1  # the chunk's last step
        flags = {key: demo["next", key][last] for key in ("done", "terminated", "truncated")}
        chunks = torch.from_numpy(action_chunks(demo["action"].numpy(), chunk))
        out.append(
            TensorDict(
                {
                    "observation": demo["observation"],
                    "action": chunks,
                    "mc_return": demo["mc_return"],
                    "steps_to_next_obs": to_next.unsqueeze(-1),
                    "next": {
                        "observation": stepped["next", "observation"],
                        "reward": stepped["next", "reward"],
                        "action": _following(chunks, to_next),
                        **flags,
                    },
                },
                batch_size=[steps],
            )
        )
    return torch.cat(out)


def _elegant_success(demos: list[_RawDemo], gamma: float) -> tuple[torch.Tensor, torch.Tensor, np.ndarray]:
    """Reward "elegant": 1 at the last step of an elegant success, else 0, and an episode ends for the critic
    at every step of a violating window and after (absorbing: from there no elegant success is possible).
    Returns the per-step reward, the MC return (exact at every step, so Cal-QL floors with all of them),
    and where episodes end, all of them terminal (a failed episode's return is 0, not cut short)."""
    rewards, returns, ended = [], [], []
    for d in demos:
        alive = np.logical_and.accumulate(d.window_kept)
        elegant_success = bool(alive[-1]) and d.success
        steps = len(d.reward)
        reward = np.zeros(steps, dtype=np.float32)
        reward[-1] = float(elegant_success)
        to_go = gamma ** np.arange(steps - 1, -1, -1, dtype=np.float64)
        returns.append((to_go * elegant_success).astype(np.float32))
        end = ~alive
        end[-1] = True
        rewards.append(reward)
        ended.append(end)
    return torch.from_numpy(np.concatenate(rewards)), torch.from_numpy(np.concatenate(returns)), np.concatenate(ended)


def load_transitions(paths: Sequence[str], config: TrainConfig) -> TransitionData:
    """Read annotated files (refusing unlabelled ones) into normalised Cal-QL transitions, as `config` says
    (its `gamma`, `reward`, `chunk`, `bootstrap`, `encoding` and `tasks`; the other fields are training's).

    gamma: the critic's discount (None: the annotation's). A shorter horizon than the annotation's
    makes Q judge the violations about to happen rather than the rest of the episode, which is what
    picking among candidate actions at one moment needs; the returns are recomputed with it.
    reward: "step" penalises the steps at which a criterion is violated; "segment" every step of a
    25-frame window that violates one; "elegant" is 1 for an elegant success, the episode ending at its
    first violating window. A violation judged at one instant (an object coming to rest off target) is one
    step under "step", next to a tilt's dozens, so Q barely registers it; per window every violation weighs
    a window, the actions leading up to it inside the window share its penalty, and human labels (which
    are per window) reach the critic as they are.
    chunk: the number of actions each transition's action holds (see the module docstring).
    bootstrap: a seed, to train on as many episodes drawn with replacement from all of them (a bootstrap
    resample): critics trained on different resamples err apart where the data says little, which a
    `CriticEnsemble` needs and different network seeds on the same data do not give.
    encoding: how states become inputs (`annotations.features.ENCODINGS`); "goal-relative" needs each
    demo's `goal_geometry` attribute, which annotation records.
    tasks: keep only these tasks' demos (keys "suite/index"); a task the files do not hold is refused."""
    gamma, reward, chunk, bootstrap, encoding = (
        config.gamma,
        config.reward,
        config.chunk,
        config.bootstrap,
        config.encoding,
    )
    tasks = None if config.tasks is None else list(config.tasks)
    if gamma is not None and not 0.0 < gamma < 1.0:
        raise UserInputError(f"gamma must lie in (0, 1), got {gamma}")
    if int(chunk) != chunk or chunk < 1:
        raise UserInputError(f"chunk must be a positive integer, got {chunk!r}")
    if reward not in REWARDS:
        raise unknown_choice("reward", reward, REWARDS)
    if not paths:
        raise UserInputError("no annotated HDF5 files given")
    layouts: dict[str, list] = {}
    annotation_gamma: float | None = None
    demos: list[_RawDemo] = []
    for path in paths:
        with DemoFile(path, require_labels=True) as f:
            file_gamma = _annotation_gamma(f)
            if annotation_gamma is not None and file_gamma != annotation_gamma:
                raise UserInputError(
                    f"{f.path}: data.annotation gamma is {file_gamma}, but {paths[0]} uses {annotation_gamma}; "
                    "annotate all files with one gamma"
                )
            annotation_gamma = file_gamma
            for key, layout in f.state_layouts.items():
                if key in layouts and [[str(n), int(s)] for n, s in layout] != [
                    [str(n), int(s)] for n, s in layouts[key]
                ]:
                    raise UserInputError(
                        f"{f.path}: data.state_layouts[{key!r}] differs from the layout of that task in an earlier file"
                    )
                layouts.setdefault(key, layout)
            demos += _read_demos(f, f.state_layouts)
    if tasks is not None:
        missing = sorted(set(tasks) - {d.task for d in demos})
        if missing:
            raise UserInputError(f"{', '.join(paths)}: tasks {', '.join(missing)} have no demos (train-critic tasks)")
        demos = [d for d in demos if d.task in set(tasks)]
        layouts = {k: v for k, v in layouts.items() if k in set(tasks)}
    if not demos:
        raise UserInputError(f"{', '.join(paths)}: no demos to train on")
    if bootstrap is not None:
        demos = [demos[i] for i in np.random.default_rng(int(bootstrap)).integers(0, len(demos), len(demos))]
    encoder = make_encoder(encoding, layouts)
    contexts = [encoder.check_env(d.metadata, f"{d.path}: data/{d.name}") for d in demos]
    obs = np.concatenate([encoder.encode(d.obs, c) for d, c in zip(demos, contexts)])
    next_obs = np.concatenate([encoder.encode(d.next_obs, c) for d, c in zip(demos, contexts)])
    actions = np.concatenate([d.actions for d in demos])
    elegance = torch.from_numpy(np.concatenate([d.reward for d in demos]))
    last = np.zeros(len(elegance), dtype=bool)
    last[np.cumsum([len(d.reward) for d in demos]) - 1] = True
    terminal = np.zeros_like(last)
    terminal[last] = [d.success for d in demos]
    done = torch.from_numpy(last)
    _check_returns(demos, reward2go(elegance, done, annotation_gamma, time_dim=-1).numpy(), annotation_gamma)
    gamma = annotation_gamma if gamma is None else float(gamma)
    # Train on a violation penalty (0 where all four ITCs hold, -1 where one breaks), not on r itself:
    # with r, Q counts the kept steps still to come, so it mostly measures how long the episode has left
    # and rewards dawdling; with the penalty it is minus the discounted violations to come. Or, with
    # "elegant", on the discounted chance of an elegant success: the binary outcome ESR counts.
    if reward == "elegant":
        train_reward, mc_return, last = _elegant_success(demos, gamma)
        terminal, done = last.copy(), torch.from_numpy(last)
    else:
        if reward == "segment":
            elegance = torch.from_numpy(np.concatenate([d.window_kept for d in demos]).astype(np.float32))
        train_reward = elegance - 1.0
        mc_return = reward2go(train_reward, done, gamma, time_dim=-1)
        # A demo cut off without success could have violated more later: its MC return is then an upper
        # bound, not the lower bound Cal-QL's floor needs, so those transitions get no floor.
        truncated_rows = torch.from_numpy(np.repeat([not d.success for d in demos], [len(d.reward) for d in demos]))
        mc_return = torch.where(truncated_rows, torch.full_like(mc_return, NO_FLOOR), mc_return)

    normalization = Normalization.fit(obs, actions, encoder.state_dim)
    lengths = [len(d.reward) for d in demos]
    scaled_actions = torch.from_numpy(normalization.actions(actions))
    transitions = TensorDict(
        {
            "observation": torch.from_numpy(normalization.observations(obs)),
            "action": scaled_actions,
            "mc_return": _column(mc_return),
            "next": {
                "observation": torch.from_numpy(normalization.observations(next_obs)),
                "reward": _column(train_reward),
                "action": torch.cat([_following(a, 1) for a in scaled_actions.split(lengths)]),
                "done": _column(done),
                "terminated": _column(torch.from_numpy(terminal)),
                "truncated": _column(torch.from_numpy(last & ~terminal)),
            },
        },
        batch_size=[len(train_reward)],
    )
    transitions = chunk_transitions(transitions, lengths, int(chunk), gamma)
    explored = torch.from_numpy(np.concatenate([d.explored for d in demos]))
    return TransitionData(transitions, encoder, normalization, float(gamma), len(demos), explored, int(chunk))


def make_replay_buffer(transitions: TensorDict, batch_size: int, generator: torch.Generator) -> TensorDictReplayBuffer:
    """All transitions in memory, sampled uniformly with replacement from `generator` (seed it for repeatability)."""
    buffer = TensorDictReplayBuffer(
        storage=LazyTensorStorage(len(transitions)),
        sampler=RandomSampler(),
        batch_size=batch_size,
        generator=generator,
    )
    buffer.extend(transitions)
    return buffer
