"""The run-folder format: file names, MCAP topics and the JSON messages, as one contract.

A run folder is the only thing a run leaves behind and the only thing the dashboard reads, so
its format is defined here once and every writer and reader (training, evaluation, tables,
`detach-run list`, the dashboard) uses these names and classes. It imports nothing of the
project: any layer may read it. docs/ARCHITECTURE.md ("Run folder") describes it in prose.

    runs/<YYYYmmdd-HHMMSS>-<task>-<model>-s<seed>/
        config.yaml          fully resolved RunConfig (reloads identically)
        status.json          `Status`
        stdout.log           everything the run printed
        log.mcap             /metrics `MetricsMessage` per iteration, /scene `SceneMessage`,
                             /episode/bodies `EpisodeFrame` per recorded frame; for Foxglove
                             /tf (frame transforms), /foxglove/scene (the scene's meshes) and
                             /foxglove/task (each frame's task markers)
        checkpoints/model_<iteration>.pt
        checkpoints/amp_replay_<iteration>.pt   AMP replay buffer of the newest checkpoint
        selection.json       with train.select_checkpoint_trials: each checkpoint's validation
                             score and the one chosen as the run's policy (`selected_checkpoint`)
        eval.json            `EvalResult` on the run's own task; eval_<task>.json on another
        provenance.json      code and machine of the run: commit, dirty diff, python, package
                             versions, device, command line (one record per start / resume)
        params/agent.yaml    rsl-rl's train config (OnPolicyRunner(env, it).load(checkpoint))
        events.out.tfevents.*, wandb/   with train.logger tensorboard / wandb
        exported/policy_<iteration>.onnx | .pt (+ .json: input layout)   `detach-run export`

JSON, YAML and checkpoint files are written through `atomic_writer` (whole or not at all, with
the user's umask); stdout.log and log.mcap grow by appending and read up to a crash.
`from_json` raises `ContractError` (a ValueError with one line saying what is wrong) for a
message that does not follow the format, so readers can skip or report it.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import re
import secrets
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import IO, Any, Iterator

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

_CHECKPOINT = re.compile(r"^model_(\d+)\.pt$")


class ContractError(ValueError):
    """A file or message that does not follow the run-folder format."""


def checkpoint_file(iteration: int) -> str:
    """File name of the checkpoint after `iteration` (the last completed one)."""
    return f"model_{int(iteration)}.pt"


def checkpoint_iteration(name: str) -> int | None:
    """Iteration of a checkpoint file name, None if the name is not one."""
    m = _CHECKPOINT.match(name)
    return int(m.group(1)) if m else None


def selected_checkpoint(run_dir: Path) -> Path | None:
    """The checkpoint that selection.json names as the run's policy, None when there is no
    selection (the run's policy is then its newest checkpoint) or its file is gone. A
    selection.json that does not follow the format raises ContractError."""
    path = Path(run_dir) / SELECTION_FILE
    try:
        text = path.read_text()
    except FileNotFoundError:
        return None
    try:
        name = json.loads(text)["checkpoint"]
    except (ValueError, KeyError, TypeError):
        raise ContractError(f"{path}: expected a JSON object with a 'checkpoint' file name") from None
    if not isinstance(name, str) or checkpoint_iteration(name) is None:
        raise ContractError(f"{path}: 'checkpoint' is not a checkpoint file name: {name!r}")
    chosen = Path(run_dir) / CHECKPOINT_DIR / name
    return chosen if chosen.is_file() else None


REPLAY_PREFIX = "amp_replay_"
_REPLAY = re.compile(r"^amp_replay_(\d+)\.pt$")


def replay_file(iteration: int) -> str:
    """File name (in checkpoints/) of the AMP replay buffer saved with `checkpoint_file(iteration)`.

    A sidecar, not part of the checkpoint: the buffer holds up to `train.amp.replay_size`
    windows (~350 MB for the humanoid), so only the newest checkpoint keeps one."""
    return f"{REPLAY_PREFIX}{int(iteration)}.pt"


def replay_iteration(name: str) -> int | None:
    """Iteration of a replay sidecar file name, None if the name is not one."""
    m = _REPLAY.match(name)
    return int(m.group(1)) if m else None


TEMP_SUFFIX = ".tmp"
"""Files being written are `.<name>.<pid>.<random>.tmp` beside their target: readers skip
them, and a run cleans up the ones a killed process left behind (`is_temp_file`)."""


def is_temp_file(name: str) -> bool:
    return name.startswith(".") and name.endswith(TEMP_SUFFIX)


@contextlib.contextmanager
def atomic_writer(path: Path, binary: bool = True) -> Iterator[IO[Any]]:
    """Open a temporary file that replaces `path` when the block ends without an error.

    Readers see the old file or the complete new one, never a part: the data is fsynced
    before the rename and the folder after it, so a power cut cannot leave an empty file
    under the final name either. The file gets the user's umask (0666 & ~umask, unlike
    tempfile's 0600), so a dashboard run by another user can read it. On any failure (a
    full disk, a signal) the temporary file is removed and the error re-raised.
    """
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}{TEMP_SUFFIX}")
    f = open(tmp, "xb") if binary else open(tmp, "x", encoding="utf-8")  # 0666 & ~umask
    try:
        with f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    fsync_folder(path.parent)


def fsync_folder(folder: Path) -> None:
    """Make a rename or unlink in `folder` durable (best effort: not every filesystem can)."""
    with contextlib.suppress(OSError):
        fd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


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


def trial_set_of_file(name: str) -> str:
    """The trial set an eval*.json's name says it holds: test or development."""
    return "test" if name.endswith(TEST_EVAL_SUFFIX + ".json") else "development"


def is_eval_file(name: str) -> bool:
    return name.startswith("eval") and name.endswith(".json")


# ------------------------------------------------------------------------------- checks
def _need(data: Any, key: str, kinds: type | tuple[type, ...], where: str, optional: bool = False) -> Any:
    if not isinstance(data, dict):
        raise ContractError(f"{where}: expected an object, found {type(data).__name__}")
    if key not in data or data[key] is None:
        if optional:
            return None
        raise ContractError(f"{where}: missing '{key}'")
    value = data[key]
    if isinstance(value, bool) and bool not in (kinds if isinstance(kinds, tuple) else (kinds,)):
        raise ContractError(f"{where}: '{key}' must be {_kind_name(kinds)}, found {value!r}")
    if not isinstance(value, kinds):
        raise ContractError(f"{where}: '{key}' must be {_kind_name(kinds)}, found {type(value).__name__} {value!r:.40}")
    return value


def _kind_name(kinds: type | tuple[type, ...]) -> str:
    names = {int: "an integer", float: "a number", str: "a string", list: "a list", dict: "an object",
             bool: "true or false"}
    kinds = kinds if isinstance(kinds, tuple) else (kinds,)
    return " or ".join(dict.fromkeys(names.get(k, k.__name__) for k in kinds))


def _number(data: Any, key: str, where: str, optional: bool = False, finite: bool = True) -> float | None:
    value = _need(data, key, (int, float), where, optional)
    if value is None:
        return None
    if finite and not math.isfinite(value):
        raise ContractError(f"{where}: '{key}' is {value} (not a finite number)")
    return float(value)


# ------------------------------------------------------------------------------- status.json
@dataclass
class Status:
    """status.json: where a run stands. `updated` and `started` are Unix times (s)."""

    state: str
    iteration: int = 0
    pid: int | None = None
    started: float | None = None
    updated: float | None = None
    error: str | None = None
    cell: str | None = None
    """The sweep cell this run belongs to (`<sweep>/<task>/<model>/s<seed>`), if any."""
    host: str | None = None
    """Host name of the machine whose process `pid` is: on a runs folder shared by several
    machines, only that machine can tell whether the process is alive."""
    run_id: str | None = None
    """Random id written when the run folder is created: a copy of the folder (`cp -r RUN
    RUN.bak`) is the same run, counted once by tables. Folders of earlier versions have none:
    their folder name identifies them."""

    def to_json(self) -> dict[str, Any]:
        return {k: v for k, v in asdict(self).items() if v is not None or k in ("error", "started", "pid")}

    @classmethod
    def from_json(cls, data: Any) -> "Status":
        state = _need(data, "state", str, STATUS_FILE)
        if state not in RUN_STATES:
            raise ContractError(f"{STATUS_FILE}: unknown state {state!r}; expected one of {', '.join(RUN_STATES)}")
        return cls(state=state, iteration=int(_need(data, "iteration", int, STATUS_FILE, optional=True) or 0),
                   pid=_need(data, "pid", int, STATUS_FILE, optional=True),
                   started=_number(data, "started", STATUS_FILE, optional=True),
                   updated=_number(data, "updated", STATUS_FILE, optional=True),
                   error=_need(data, "error", str, STATUS_FILE, optional=True),
                   cell=_need(data, "cell", str, STATUS_FILE, optional=True),
                   host=_need(data, "host", str, STATUS_FILE, optional=True),
                   run_id=_need(data, "run_id", str, STATUS_FILE, optional=True))


# ------------------------------------------------------------------------------- log.mcap
@dataclass
class MetricsMessage:
    """/metrics: one message per training iteration; `values` are flat scalars named with
    rsl-rl's prefixes (`Loss/`, `Train/`, `Perf/`, `Episode/`, ...)."""

    iteration: int
    stage: str = ""
    values: dict[str, float] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        return {"iteration": int(self.iteration), "stage": self.stage,
                **{k: float(v) for k, v in self.values.items()}}

    @classmethod
    def from_json(cls, data: Any) -> "MetricsMessage":
        it = _need(data, "iteration", int, METRICS_TOPIC)
        values = {k: float(v) for k, v in data.items()
                  if k not in ("iteration", "stage") and isinstance(v, (int, float)) and not isinstance(v, bool)}
        return cls(it, str(data.get("stage", "")), values)


@dataclass
class SceneObject:
    name: str
    category: str
    mesh: str
    """The asset's mesh.obj (object frame, centred on its bbox): a path relative to the
    assets root the run used (`<category>/<model_id>/mesh.obj`)."""
    pos: list[float]
    quat: list[float]
    """wxyz."""
    bbox: list[float]
    static: bool


@dataclass
class SceneTarget:
    subtask: int
    skill: str
    pos: list[float]
    color: list[int] = field(default_factory=lambda: [220, 40, 40])
    """The skill's display colour (RGB 0-255)."""


@dataclass
class BodyGeom:
    """One collision primitive of the character, in its body's frame (MuJoCo geom size)."""

    body: str
    type: str
    """capsule, sphere or box."""
    size: list[float]
    pos: list[float]
    quat: list[float]


@dataclass
class SceneMessage:
    """/scene: the static scene of a run (written at the start and by each evaluation)."""

    task: str
    objects: list[SceneObject]
    trajectories: dict[str, list[list[float]]]
    targets: list[SceneTarget]
    bodies: list[str]
    body_geoms: list[BodyGeom]

    def to_json(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_json(cls, data: Any) -> "SceneMessage":
        w = SCENE_TOPIC
        objects = []
        for i, o in enumerate(_need(data, "objects", list, w)):
            where = f"{w} objects[{i}]"
            objects.append(SceneObject(
                name=str(_need(o, "name", str, where)), category=str(o.get("category", "")),
                mesh=str(_need(o, "mesh", str, where)), pos=_vec(o, "pos", 3, where), quat=_vec(o, "quat", 4, where),
                bbox=_vec(o, "bbox", 3, where), static=bool(o.get("static", True))))
        targets = [SceneTarget(int(_need(t, "subtask", int, f"{w} targets[{i}]")),
                               str(_need(t, "skill", str, f"{w} targets[{i}]")),
                               _vec(t, "pos", 3, f"{w} targets[{i}]"),
                               [int(c) for c in t.get("color", [220, 40, 40])][:3])
                   for i, t in enumerate(_need(data, "targets", list, w))]
        trajectories = {str(k): [[float(x) for x in p][:2] for p in v]
                        for k, v in _need(data, "trajectories", dict, w).items()}
        geoms = [BodyGeom(str(g["body"]), str(g["type"]), [float(x) for x in g["size"]],
                          [float(x) for x in g["pos"]], [float(x) for x in g["quat"]])
                 for g in data.get("body_geoms", []) if isinstance(g, dict)]
        return cls(str(data.get("task", "")), objects, trajectories, targets,
                   [str(b) for b in data.get("bodies", [])], geoms)


def _vec(data: Any, key: str, n: int, where: str) -> list[float]:
    value = _need(data, key, list, where)
    if len(value) != n or not all(isinstance(v, (int, float)) and math.isfinite(v) for v in value):
        raise ContractError(f"{where}: '{key}' must be {n} finite numbers, found {value!r:.60}")
    return [float(v) for v in value]


@dataclass
class EpisodeFrame:
    """/episode/bodies: one frame of a recorded episode. `to_json` writes "episode" and
    "trial" first (readers may find a frame's episode without parsing the whole message).
    A recorded episode is (episode, trial): an evaluation records every trial under the
    checkpoint's iteration, trial 0, 1, ... in the order the trials started; training
    records env 0's next whole episode after each checkpoint as (its iteration, trial -1)."""

    episode: int
    frame: int
    time: float
    """Seconds since the episode started."""
    bodies: list[str]
    pos: list[list[float]]
    quat: list[list[float]]
    objects: list[dict[str, Any]] = field(default_factory=list)
    """Dynamic objects: {"name", "pos", "quat"}."""
    subtask: int = 0
    skill: str = ""
    trial: int = 0
    target: list[float] | None = None
    """The current subtask's target now (world, m): what the task markers draw; None where
    the recorder had none (logs of earlier versions)."""
    path: list[list[float]] | None = None
    """The XY path the current Follow subtask walks, written only on the frames where it
    changed (the first frame of a recording, a new Follow subtask; [] when the subtask walks
    none): readers carry it forward (`detach.eval.task_markers.PathMemo`)."""
    path_index: float | None = None
    """Where the moving reference point is on `path`, as a fractional vertex index: the done
    part of the path lies before it."""
    outcome: str = ""
    """"success" or "failure" on the frame that closes a recorded episode (it repeats the
    last pose: the env has reset by the time the verdict is known), else empty."""
    scores: list[float] | None = None
    """Each subtask's score (1: succeeded), on the closing frame."""

    def to_json(self) -> dict[str, Any]:
        data = {"episode": int(self.episode), "trial": int(self.trial), "frame": int(self.frame),
                "time": float(self.time),
                "bodies": list(self.bodies),
                "pos": [[round(float(v), 5) for v in p] for p in self.pos],
                "quat": [[round(float(v), 5) for v in q] for q in self.quat],
                "objects": list(self.objects), "subtask": int(self.subtask), "skill": self.skill}
        if self.target is not None:
            data["target"] = [round(float(v), 4) for v in self.target]
        if self.path is not None:
            data["path"] = [[round(float(v), 3) for v in p[:2]] for p in self.path]
        if self.path_index is not None:
            data["path_index"] = round(float(self.path_index), 3)
        if self.outcome:
            data["outcome"] = self.outcome
        if self.scores is not None:
            data["scores"] = [float(v) for v in self.scores]
        return data


# ------------------------------------------------------------------------------- eval.json
@dataclass
class RateResult:
    """A success rate with its confidence interval (all in [0, 1]) over n trials."""

    rate: float
    ci: list[float]
    n: int

    @classmethod
    def from_json(cls, data: Any, where: str) -> "RateResult":
        rate = _number(data, "rate", where)
        if not 0.0 <= rate <= 1.0:
            raise ContractError(f"{where}: 'rate' must be in [0, 1], found {rate}")
        ci = _need(data, "ci", list, where)
        if len(ci) != 2 or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                                   and 0.0 <= v <= 1.0 for v in ci) or ci[0] > ci[1]:
            raise ContractError(f"{where}: 'ci' must be two numbers 0 <= low <= high <= 1, found {ci!r:.60}")
        n = _need(data, "n", int, where)
        if n < 0:
            raise ContractError(f"{where}: 'n' must be >= 0, found {n}")
        return cls(rate, [float(ci[0]), float(ci[1])], int(n))


@dataclass
class SubtaskResult(RateResult):
    index: int = 0
    skill: str = ""
    mean_time: float | None = None
    """Mean execution time (s) of the subtask over the trials that completed it."""
    reached: int | None = None
    """Trials that got to this subtask (None in files of earlier versions): a subtask no trial
    reached has no measured rate, whatever its 0.00 says."""

    def to_json(self) -> dict[str, Any]:
        return {"index": self.index, "skill": self.skill, "rate": self.rate, "ci": self.ci, "n": self.n,
                "mean_time": self.mean_time, "reached": self.reached}


SGR_VARIANTS: tuple[str, ...] = ("reported", "formula")
"""Skill generalisation rate: `formula` = ((S_climb + S_sit) / 2) / ((S_follow + S_carry) / 2)
as the paper prints it; `reported` = mean of the novel skills the plan has / (S_follow +
S_carry), which reproduces the values the paper reports (e.g. its LH3 0.13). The default is
the first."""


@dataclass
class EvalResult:
    """eval.json / eval_<task>.json: the evaluation of one checkpoint on one task."""

    task: str
    model: str
    trials: int
    plan: list[str]
    subtasks: list[SubtaskResult]
    lh_chain: RateResult
    """Every subtask of the plan succeeded in the same episode."""
    lh_mean: RateResult
    """The mean of the subtask rates (the paper's LH success): the mean over trials of each
    trial's mean subtask score, with a normal interval."""
    sgr: dict[str, float]
    """Skill generalisation rate per variant (`SGR_VARIANTS`)."""
    confidence: float = 0.95
    trained_on: str | None = None
    seed: int | None = None
    checkpoint: str | None = None
    iteration: int | None = None
    mean_execution_time: float | None = None
    """Mean time (s) from the start of the task to the completion of its last subtask, over the
    episodes that completed the whole plan (None when none did)."""
    execution_time_ci: list[float] | None = None
    trial_scores: list[list[float]] | None = None
    """Per trial, every subtask's score: what tables pool across seeds."""
    trial_set: str = "development"
    """Which trials were played (`detach.eval.trial_sets`): development (files of earlier
    versions, which all played the run's own seed) or test."""
    trial_seed: int | None = None
    """The evaluation env's seed (None in files of earlier versions: the run's seed)."""
    aids: list[str] | None = None
    """What the run used that the paper's recipe does not (`detach.eval.aids`; None in files
    of earlier versions: unknown, tables then read the run's config)."""

    @property
    def lh_success(self) -> RateResult:
        """The strict LH success (`lh_chain`), by its name in files of earlier versions."""
        return self.lh_chain

    def to_json(self) -> dict[str, Any]:
        return {"task": self.task, "trained_on": self.trained_on, "model": self.model, "seed": self.seed,
                "checkpoint": self.checkpoint, "iteration": self.iteration, "trials": self.trials,
                "confidence": self.confidence, "plan": list(self.plan),
                "subtasks": [s.to_json() for s in self.subtasks],
                "lh_mean": asdict(self.lh_mean), "lh_chain": asdict(self.lh_chain),
                "mean_execution_time": self.mean_execution_time, "execution_time_ci": self.execution_time_ci,
                "sgr": dict(self.sgr), "trial_scores": self.trial_scores, "trial_set": self.trial_set,
                "trial_seed": self.trial_seed, "aids": self.aids}

    @classmethod
    def from_json(cls, data: Any, where: str = EVAL_FILE) -> "EvalResult":
        subtasks = []
        for i, s in enumerate(_need(data, "subtasks", list, where)):
            w = f"{where}: subtasks[{i}]"
            r = RateResult.from_json(s, w)
            subtasks.append(SubtaskResult(r.rate, r.ci, r.n, index=int(_need(s, "index", int, w)),
                                          skill=str(_need(s, "skill", str, w)),
                                          mean_time=_number(s, "mean_time", w, optional=True),
                                          reached=_need(s, "reached", int, w, optional=True)))
        plan = [str(p) for p in _need(data, "plan", list, where)]
        ci = data.get("execution_time_ci") if isinstance(data, dict) else None
        chain_key = "lh_chain" if "lh_chain" in data else "lh_success"  # its name before the two LH rates
        lh_chain = RateResult.from_json(_need(data, chain_key, dict, where), f"{where}: {chain_key}")
        if "lh_mean" in data:
            lh_mean = RateResult.from_json(_need(data, "lh_mean", dict, where), f"{where}: lh_mean")
        else:  # an older file: the mean of its subtask rates, without an interval of its own
            mean = sum(s.rate for s in subtasks) / max(len(subtasks), 1)
            lh_mean = RateResult(mean, [mean, mean], lh_chain.n)
        sgr = data.get("sgr")
        if isinstance(sgr, (int, float)) and not isinstance(sgr, bool):
            sgr = {"formula": float(sgr)}
        if not isinstance(sgr, dict) or not all(isinstance(v, (int, float)) for v in sgr.values()):
            raise ContractError(f"{where}: 'sgr' must map variants ({', '.join(SGR_VARIANTS)}) to numbers")
        scores = data.get("trial_scores")
        if scores is not None and not (isinstance(scores, list) and all(
                isinstance(t, list) and len(t) == len(plan) and all(isinstance(v, (int, float)) for v in t)
                for t in scores)):
            raise ContractError(f"{where}: 'trial_scores' must be one list of {len(plan)} numbers per trial")
        return cls(task=str(_need(data, "task", str, where)), model=str(_need(data, "model", str, where)),
                   trials=int(_need(data, "trials", int, where)), plan=plan, subtasks=subtasks,
                   lh_chain=lh_chain, lh_mean=lh_mean, sgr={str(k): float(v) for k, v in sgr.items()},
                   trial_scores=scores,
                   confidence=float(_number(data, "confidence", where, optional=True) or 0.95),
                   trained_on=_need(data, "trained_on", str, where, optional=True),
                   seed=_need(data, "seed", int, where, optional=True),
                   checkpoint=_need(data, "checkpoint", str, where, optional=True),
                   iteration=_need(data, "iteration", int, where, optional=True),
                   mean_execution_time=_number(data, "mean_execution_time", where, optional=True),
                   execution_time_ci=[float(v) for v in ci] if isinstance(ci, list) else None,
                   trial_set=_trial_set(data, where), trial_seed=_need(data, "trial_seed", int, where, optional=True),
                   aids=_aids(data, where))


def _trial_set(data: Any, where: str) -> str:
    value = data.get("trial_set", "development") if isinstance(data, dict) else "development"
    if value not in ("development", "test"):
        raise ContractError(f"{where}: 'trial_set' must be 'development' or 'test', found {value!r}")
    return str(value)


def _aids(data: Any, where: str) -> list[str] | None:
    value = data.get("aids") if isinstance(data, dict) else None
    if value is not None and not (isinstance(value, list) and all(isinstance(a, str) for a in value)):
        raise ContractError(f"{where}: 'aids' must be a list of names")
    return value


MCAP_SCHEMAS: dict[str, dict[str, Any]] = {
    METRICS_TOPIC: {"title": "detach.Metrics", "type": "object",
                    "properties": {"iteration": {"type": "integer"}, "stage": {"type": "string"}},
                    "required": ["iteration"], "additionalProperties": {"type": "number"}},
    SCENE_TOPIC: {"title": "detach.Scene", "type": "object",
                  "properties": {"objects": {"type": "array", "items": {"type": "object"}},
                                 "trajectories": {"type": "object"}, "targets": {"type": "array"}}},
    EPISODE_TOPIC: {"title": "detach.EpisodeBodies", "type": "object",
                    "properties": {"episode": {"type": "integer"}, "frame": {"type": "integer"},
                                   "time": {"type": "number"}, "bodies": {"type": "array", "items": {"type": "string"}},
                                   "pos": {"type": "array"}, "quat": {"type": "array"},
                                   "objects": {"type": "array"}, "subtask": {"type": "integer"},
                                   "skill": {"type": "string"}, "target": {"type": "array"},
                                   "path": {"type": "array"}, "path_index": {"type": "number"},
                                   "outcome": {"type": "string"}, "scores": {"type": "array"}},
                    "required": ["episode", "frame", "bodies", "pos", "quat"]},
}
"""JSON schemas of the project's topics, registered in every log.mcap."""
