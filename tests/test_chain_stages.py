"""The chain's declared stages and the runner that resumes them (no simulation: the stages' calls are
only declared here, and the runner is driven with stand-ins)."""

from base_suites.runtime.compute import ComputeConfig
from elegant.chain_config import ChainConfig
from elegant.chain_stages import ChainPaths, Stage, chain_stages, run_stages


def test_the_runner_skips_finished_stages_and_always_runs_those_without_an_output(tmp_path):
    done = tmp_path / "demos.hdf5"
    done.write_text("finished")
    ran, said = [], []
    stages = [
        Stage("demos", "make demos", str(done), lambda: ran.append("demos")),
        Stage("policy", "train", str(tmp_path / "policy"), lambda: ran.append("policy") or "trained"),
        Stage("eval", "evaluate", None, lambda: ran.append("eval") or {"esr": 0.5}),
    ]
    assert run_stages(stages, said.append) == {"policy": "trained", "eval": {"esr": 0.5}}
    assert ran == ["policy", "eval"] and said == ["train", "evaluate"]


def names(config: ChainConfig, tmp_path) -> list[str]:
    paths = ChainPaths(str(tmp_path), config.suites, config.modes, config.critic_members)
    stages = chain_stages(paths, config, ([0, 1], [2, 3]), progress=False, workers=1, compute=ComputeConfig())
    return [stage.name for stage in stages]


def test_the_chain_declares_its_stages_in_order_and_only_those_its_modes_need(tmp_path):
    gated = ChainConfig(suites=("libero_object",), critic_members=2)
    assert names(gated, tmp_path) == [
        "demos libero_object",
        "annotate libero_object",
        "policy",
        "rollouts libero_object",
        "annotate rollouts libero_object",
        "critic 1",
        "critic 2",
        "gate libero_object",
        "eval base libero_object",
        "eval always libero_object",
        "eval jiti libero_object",
    ]
    # the policy benchmark and the critic-free controls need no critic: no rollouts, critics or gate
    controls = ChainConfig(suites=("libero_object",), modes=("base", "likelihood", "consensus"), jiti_gate=False)
    assert names(controls, tmp_path) == [
        "demos libero_object",
        "annotate libero_object",
        "policy",
        "eval base libero_object",
        "eval likelihood libero_object",
        "eval consensus libero_object",
    ]
