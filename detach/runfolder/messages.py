"""The JSON messages of a run folder: status.json (`Status`, its `RunSummary`) and the
log.mcap topics (/metrics `MetricsMessage`, /scene `SceneMessage`, /episode/bodies
`EpisodeFrame`), with their JSON schemas.

`from_json` raises `ContractError` (a ValueError with one line saying what is wrong) for a
message that does not follow the format, so readers can skip or report it.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

from detach.runfolder.names import EPISODE_TOPIC, METRICS_TOPIC, RUN_STATES, SCENE_TOPIC, STATUS_FILE


class ContractError(ValueError):
    """A file or message that does not follow the run-folder format."""


MAX_TEXT = 64
"""Longest name a viewer shows from a log (a skill, a subtask): longer ones are cut."""
MAX_COORD = 1e4
"""Coordinates beyond this (m) are not a scene's: a viewer drops them."""


# ------------------------------------------------------------------------------- checks
def need_key(data: Any, key: str, kinds: type | tuple[type, ...], where: str, optional: bool = False) -> Any:
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


def need_number(data: Any, key: str, where: str, optional: bool = False, finite: bool = True) -> float | None:
    value = need_key(data, key, (int, float), where, optional)
    if value is None:
        return None
    if finite and not math.isfinite(value):
        raise ContractError(f"{where}: '{key}' is {value} (not a finite number)")
    return float(value)


# ------------------------------------------------------------------------------- status.json
@dataclass(frozen=True)
class RunSummary:
    """What a run is, for `detach-run list` and the dashboard: written into status.json when
    the run folder is made, from the resolved config (`detach.runfolder.summary` derives it from
    config.yaml for folders of earlier versions, with the project's bounded YAML loader)."""

    task: str
    model: str
    seed: int
    samples_per_iteration: int | None = None
    """Environment steps per training iteration (sim.num_envs x train.num_steps_per_env)."""

    def to_json(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_json(cls, data: Any, where: str = f"{STATUS_FILE}: summary") -> "RunSummary":
        return cls(task=need_key(data, "task", str, where), model=need_key(data, "model", str, where),
                   seed=need_key(data, "seed", int, where),
                   samples_per_iteration=need_key(data, "samples_per_iteration", int, where, optional=True))


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
    summary: RunSummary | None = None
    """Task, model, seed and samples per iteration; None in folders of earlier versions."""

    def to_json(self) -> dict[str, Any]:
        return {k: v for k, v in asdict(self).items() if v is not None or k in ("error", "started", "pid")}

    @classmethod
    def from_json(cls, data: Any) -> "Status":
        state = need_key(data, "state", str, STATUS_FILE)
        if state not in RUN_STATES:
            raise ContractError(f"{STATUS_FILE}: unknown state {state!r}; expected one of {', '.join(RUN_STATES)}")
        return cls(state=state, iteration=int(need_key(data, "iteration", int, STATUS_FILE, optional=True) or 0),
                   pid=need_key(data, "pid", int, STATUS_FILE, optional=True),
                   started=need_number(data, "started", STATUS_FILE, optional=True),
                   updated=need_number(data, "updated", STATUS_FILE, optional=True),
                   error=need_key(data, "error", str, STATUS_FILE, optional=True),
                   cell=need_key(data, "cell", str, STATUS_FILE, optional=True),
                   host=need_key(data, "host", str, STATUS_FILE, optional=True),
                   run_id=need_key(data, "run_id", str, STATUS_FILE, optional=True),
                   summary=_summary(data))


def _summary(data: dict[str, Any]) -> RunSummary | None:
    value = need_key(data, "summary", dict, STATUS_FILE, optional=True)
    return None if value is None else RunSummary.from_json(value)


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
        it = need_key(data, "iteration", int, METRICS_TOPIC)
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
        for i, o in enumerate(need_key(data, "objects", list, w)):
            where = f"{w} objects[{i}]"
            objects.append(SceneObject(
                name=str(need_key(o, "name", str, where)), category=str(o.get("category", "")),
                mesh=str(need_key(o, "mesh", str, where)), pos=_vec(o, "pos", 3, where), quat=_vec(o, "quat", 4, where),
                bbox=_vec(o, "bbox", 3, where), static=bool(o.get("static", True))))
        targets = [SceneTarget(int(need_key(t, "subtask", int, f"{w} targets[{i}]")),
                               str(need_key(t, "skill", str, f"{w} targets[{i}]")),
                               _vec(t, "pos", 3, f"{w} targets[{i}]"),
                               [int(c) for c in t.get("color", [220, 40, 40])][:3])
                   for i, t in enumerate(need_key(data, "targets", list, w))]
        trajectories = {str(k): [[float(x) for x in p][:2] for p in v]
                        for k, v in need_key(data, "trajectories", dict, w).items()}
        geoms = [BodyGeom(str(g["body"]), str(g["type"]), [float(x) for x in g["size"]],
                          [float(x) for x in g["pos"]], [float(x) for x in g["quat"]])
                 for g in data.get("body_geoms", []) if isinstance(g, dict)]
        return cls(str(data.get("task", "")), objects, trajectories, targets,
                   [str(b) for b in data.get("bodies", [])], geoms)

    @classmethod
    def salvage(cls, data: Any) -> tuple["SceneMessage", list[str]]:
        """What a viewer can draw of a /scene message that may not follow the format, and a
        note for each part left out: a broken log must not stop the dashboard. Missing poses
        and sizes of an object or a geom take neutral defaults (origin, identity, a 0.3 m box);
        a malformed object, path or target is left out; one malformed geom drops them all (the
        character is then drawn as a sphere per body); coordinates past `MAX_COORD` and names
        past `MAX_TEXT` count as malformed and cut."""
        notes: list[str] = []

        def part(what: str, fn, *args):
            try:
                return fn(*args)
            except (ContractError, TypeError, ValueError, KeyError, AttributeError) as exc:
                notes.append(f"{SCENE_TOPIC} {what}: skipped ({exc!r:.120})")
                return None

        if not isinstance(data, dict):
            return cls("", [], {}, [], [], []), [f"{SCENE_TOPIC}: skipped (expected an object, found "
                                                 f"{type(data).__name__})"]
        objects = [o for i, raw in enumerate(_as_list(data.get("objects")))
                   if (o := part(f"object {i}", _salvage_object, i, raw)) is not None]
        paths = data.get("trajectories")
        trajectories = {str(k): way for k, raw in (paths.items() if isinstance(paths, dict) else ())
                        if (way := part(f"trajectory {k}", _salvage_path, raw)) is not None}
        targets = [t for i, raw in enumerate(_as_list(data.get("targets")))
                   if (t := part(f"target {i}", _salvage_target, raw)) is not None]
        bodies = [str(b)[:MAX_TEXT] for b in _as_list(data.get("bodies"))]
        geoms = part("body_geoms", lambda: [_salvage_geom(g) for g in _as_list(data.get("body_geoms"))]) or []
        return cls(str(data.get("task", ""))[:MAX_TEXT], objects, trajectories, targets, bodies, geoms), notes


def _as_list(value: Any) -> list:
    return value if isinstance(value, list) else []


def finite_coords(value: Any, n: int, default: tuple[float, ...] | None = None,
                  at_least: bool = False) -> list[float]:
    """`value` (from a file anyone may have written) as n (or, `at_least`, n or more) finite
    numbers within MAX_COORD, else ContractError; `default` when absent."""
    if value is None and default is not None:
        return list(default)
    if not isinstance(value, (list, tuple)) or (len(value) < n if at_least else len(value) != n):
        raise ContractError(f"expected {n} numbers, found {value!r:.40}")
    if not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
               and abs(v) <= MAX_COORD for v in value):
        raise ContractError(f"expected finite coordinates within {MAX_COORD:g} m, found {value!r:.40}")
    return [float(v) for v in value]


def _salvage_object(i: int, o: Any) -> SceneObject:
    if not isinstance(o, dict):
        raise ContractError(f"expected an object, found {type(o).__name__}")
    return SceneObject(name=str(o.get("name", f"object_{i}"))[:MAX_TEXT], category=str(o.get("category", "")),
                       mesh=str(o.get("mesh") or ""), pos=finite_coords(o.get("pos"), 3, (0.0, 0.0, 0.0)),
                       quat=finite_coords(o.get("quat"), 4, (1.0, 0.0, 0.0, 0.0)),
                       bbox=finite_coords(o.get("bbox"), 3, (0.3, 0.3, 0.3)),
                       static=bool(o.get("static", True)))


def _salvage_path(way: Any) -> list[list[float]]:
    return [finite_coords(p, 2, at_least=True)[:2] for p in (way if isinstance(way, list) else [way])]


def _salvage_target(t: Any) -> SceneTarget:
    sub, skill = need_key(t, "subtask", int, "target"), need_key(t, "skill", str, "target")
    color = t.get("color")
    try:
        rgb = [int(min(max(c, 0), 255)) for c in finite_coords(color, 3)]
    except ContractError:
        rgb = [220, 40, 40]  # no colour, or a bad one: the default
    return SceneTarget(sub, skill[:MAX_TEXT], finite_coords(t.get("pos"), 3), rgb)


def _salvage_geom(g: Any) -> BodyGeom:
    if not isinstance(g, dict):
        raise ContractError(f"expected an object, found {type(g).__name__}")
    return BodyGeom(str(g.get("body", "")), str(g.get("type", "")),
                    finite_coords(g.get("size"), 1, (0.05,), at_least=True),
                    finite_coords(g.get("pos"), 3, (0.0, 0.0, 0.0)),
                    finite_coords(g.get("quat"), 4, (1.0, 0.0, 0.0, 0.0)))


def _vec(data: Any, key: str, n: int, where: str) -> list[float]:
    value = need_key(data, key, list, where)
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

    @classmethod
    def from_json(cls, data: Any) -> "EpisodeFrame":
        """A frame as `to_json` writes it, whatever the order of its keys; ContractError for
        one without its episode, frame, bodies and one position and rotation per body."""
        w = EPISODE_TOPIC
        bodies = [str(b) for b in need_key(data, "bodies", list, w)]
        pos, quat = need_key(data, "pos", list, w), need_key(data, "quat", list, w)
        if len(pos) != len(bodies) or len(quat) != len(bodies):
            raise ContractError(f"{w}: expected one 'pos' and one 'quat' per body ({len(bodies)}), "
                                f"found {len(pos)} and {len(quat)}")
        frame = need_key(data, "frame", int, w)
        target, path, scores = data.get("target"), data.get("path"), data.get("scores")
        return cls(episode=need_key(data, "episode", int, w), frame=frame,
                   time=need_number(data, "time", w, optional=True) if "time" in data else frame / 30.0,
                   bodies=bodies, pos=pos, quat=quat,
                   objects=[o for o in data.get("objects", ()) if isinstance(o, dict)],
                   subtask=int(data.get("subtask", 0) or 0), skill=str(data.get("skill", "")),
                   trial=int(data.get("trial", 0) or 0), target=target if isinstance(target, list) else None,
                   path=path if isinstance(path, list) else None,
                   path_index=need_number(data, "path_index", w, optional=True),
                   outcome=str(data.get("outcome", "") or ""), scores=scores if isinstance(scores, list) else None)


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
