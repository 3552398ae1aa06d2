"""The names inside a run folder: its files, checkpoints, MCAP topics and run states.

Only the run-folder package joins these names onto paths (tests/test_architecture.py checks
it); other modules ask `detach.runfolder.folder.RunFolder` for a path, and may print a name.
"""

from __future__ import annotations

CONFIG_FILE = "config.yaml"
STATUS_FILE = "status.json"
STDOUT_FILE = "stdout.log"
LOG_FILE = "log.mcap"
CHECKPOINT_DIR = "checkpoints"
EVAL_FILE = "eval.json"
EVAL_GLOB = "eval*.json"
SELECTION_FILE = "selection.json"
PROVENANCE_FILE = "provenance.json"
PARAMS_DIR = "params"
AGENT_PARAMS_FILE = "params/agent.yaml"
"""rsl-rl's train config of the run (IsaacLab's name), relative to the run folder."""
EXPORT_DIR = "exported"
EXPORT_FORMATS: dict[str, str] = {"onnx": ".onnx", "jit": ".pt", "init": ".init.pt", "policy": ".policy.pt"}
"""`detach-run export --format` -> file suffix."""
RUN_MARKERS = (CONFIG_FILE, STATUS_FILE)
"""A folder holding either file is a run folder."""

METRICS_TOPIC = "/metrics"
SCENE_TOPIC = "/scene"
EPISODE_TOPIC = "/episode/bodies"
TF_TOPIC = "/tf"

RUN_STATES: tuple[str, ...] = ("queued", "running", "finished", "failed", "interrupted")
LIVE_STATES: tuple[str, ...] = ("queued", "running")
"""States in which a run's files may still grow."""

CHECKPOINT_PREFIX = "model_"


def _numbered(name: str, prefix: str, suffix: str = ".pt") -> int | None:
    """N of a name `<prefix>N<suffix>` (N decimal digits), None for any other name."""
    number = name[len(prefix):-len(suffix)] if name.startswith(prefix) and name.endswith(suffix) else ""
    return int(number) if number.isdecimal() else None


def checkpoint_file(iteration: int) -> str:
    """File name of the checkpoint after `iteration` (the last completed one)."""
    return f"{CHECKPOINT_PREFIX}{int(iteration)}.pt"


def checkpoint_iteration(name: str) -> int | None:
    """Iteration of a checkpoint file name, None if the name is not one."""
    return _numbered(name, CHECKPOINT_PREFIX)


REPLAY_PREFIX = "amp_replay_"


def replay_file(iteration: int) -> str:
    """File name (in checkpoints/) of the AMP replay buffer saved with `checkpoint_file(iteration)`.

    A sidecar, not part of the checkpoint: the buffer holds up to `train.amp.replay_size`
    windows (~350 MB for the humanoid), so only the newest checkpoint keeps one."""
    return f"{REPLAY_PREFIX}{int(iteration)}.pt"


def replay_iteration(name: str) -> int | None:
    """Iteration of a replay sidecar file name, None if the name is not one."""
    return _numbered(name, REPLAY_PREFIX)


TEMP_SUFFIX = ".tmp"
"""Files being written are `.<name>.<pid>.<random>.tmp` beside their target: readers skip
them, and a run cleans up the ones a killed process left behind (`is_temp_file`)."""


def is_temp_file(name: str) -> bool:
    return name.startswith(".") and name.endswith(TEMP_SUFFIX)


def export_file(iteration: int, fmt: str) -> str:
    """File name (in exported/) of the policy of checkpoint `iteration` in `fmt` (onnx, jit, init);
    its layout description is the same name with `.json`."""
    return f"policy_{int(iteration)}{EXPORT_FORMATS[fmt]}"


TEST_EVAL_SUFFIX = ".test"
"""Before `.json` in the name of an evaluation on the held-out test trials
(`detach.eval.trial_sets`): eval.test.json, eval_<task>.test.json."""


def eval_file(task: str | None = None, trial_set: str | None = None) -> str:
    """eval.json (the run's own task, task None) or eval_<task>.json (another task), on the
    development trials; with trial_set "test", eval.test.json / eval_<task>.test.json."""
    if trial_set not in (None, "development", "test"):
        raise ValueError(f"an evaluation file holds development or test trials, not {trial_set!r}")
    stem = EVAL_FILE[:-len(".json")] if task is None else f"eval_{task}"
    return stem + (TEST_EVAL_SUFFIX if trial_set == "test" else "") + ".json"


def policy_eval_file(checkpoint: str, task: str, seed: int, trial_set: str | None = None) -> str:
    """The evaluation of a checkpoint file given outside its run (`detach-run --eval FILE`),
    written beside it: <stem>.eval_<task>_s<seed>[.test].json."""
    suffix = TEST_EVAL_SUFFIX if trial_set == "test" else ""
    return f"{checkpoint.removesuffix('.pt')}.eval_{task}_s{seed}{suffix}.json"


def trial_set_of_file(name: str) -> str:
    """The trial set an eval*.json's name says it holds: test or development."""
    return "test" if name.endswith(TEST_EVAL_SUFFIX + ".json") else "development"


def is_eval_file(name: str) -> bool:
    return name.startswith("eval") and name.endswith(".json")


