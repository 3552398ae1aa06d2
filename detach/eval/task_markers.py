"""Pictures of the task: one backend-neutral list of markers per frame, drawn alike by every view.

A video of a character on an empty floor does not say whether it did its task. Each frame's
markers say it: the Follow path (the part the moving reference point has passed, and the part
ahead of it), each subtask's target (the current one larger, with a ring of the success
distance on the floor), the current subtask's name and the elapsed time, and at the
episode's end a success or failure mark. They are computed from what the run log already
carries (`SceneMessage.targets`, an `EpisodeFrame`'s subtask, target, path and outcome), so a
live rollout and a recorded episode give the same markers.

The adapters are thin and live with their backends: MuJoCo user geoms and a text overlay for
the offscreen video (`detach.runs.marker_render`), viser primitives for the dashboard replay
and the live player (`server.marker_view`), Foxglove SceneUpdate entities for the MCAP log
(`detach.runs.foxglove.task_update`).

Recorded frames come from files that anyone may have written: `task_state` checks every field
(finite numbers, bounded sizes, a known outcome) and drops what does not pass.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Sequence, Union

import numpy as np

from detach.runfolder.messages import MAX_COORD, MAX_TEXT, ContractError, SceneTarget, finite_coords

RGB = tuple[int, int, int]

PATH_COLOR: RGB = (0, 170, 200)
"""The part of the Follow path still ahead of the reference point (the dashboard's planned-path blue)."""
DONE_PATH_COLOR: RGB = (95, 105, 120)
"""The part of the path the reference point has passed."""
REFERENCE_COLOR: RGB = (255, 255, 255)
"""The moving reference point the character follows."""
TARGET_COLOR: RGB = (220, 40, 40)
"""A target whose skill has no display colour."""
SUCCESS_COLOR: RGB = (40, 200, 60)
FAILURE_COLOR: RGB = (230, 30, 30)
TEXT_COLOR: RGB = (255, 255, 255)
SUCCESS_RADIUS = 0.3
"""The ring around the current target: the paper's success distance (`env.success_threshold`)."""
PATH_Z = 0.05
"""Height of the path over the floor (m), above the floor's lines and a scene's planned paths."""
MAX_PATH_POINTS = 4096
"""A recorded path longer than this is dropped (a shipped path has ~100 vertices)."""
MAX_SCORES = 64
OUTCOMES = ("success", "failure")


@dataclass(frozen=True)
class Polyline:
    """A line through `points` [K, 3] (world, m), `width` metres thick."""

    name: str
    points: np.ndarray
    color: RGB
    width: float


@dataclass(frozen=True)
class Sphere:
    name: str
    pos: np.ndarray
    radius: float
    color: RGB
    opacity: float = 1.0


@dataclass(frozen=True)
class Disc:
    """A flat cylinder lying on the floor under `pos` (x, y; z ignored)."""

    name: str
    pos: np.ndarray
    radius: float
    color: RGB
    opacity: float = 0.6


@dataclass(frozen=True)
class Text:
    """A line of text: a 3-D view shows it at `pos` (above the character), the video as a
    caption in its corner, one line per Text in list order."""

    name: str
    text: str
    pos: np.ndarray
    color: RGB = TEXT_COLOR


Marker = Union[Polyline, Sphere, Disc, Text]


@dataclass(frozen=True)
class TaskState:
    """What one frame's markers are drawn from."""

    time: float
    """Seconds since the episode started."""
    subtask: int
    skill: str
    root: np.ndarray
    """[3] the character's root (pelvis) position: where the caption and verdict go."""
    target: np.ndarray | None = None
    """[3] the current subtask's target now (None: the scene's static one, if any)."""
    path: np.ndarray | None = None
    """[K, 2] the current Follow path."""
    path_index: float | None = None
    """The reference point's place on `path` (fractional vertex index)."""
    outcome: str = ""
    """"success" / "failure" at the episode's end, else ""."""
    scores: tuple[float, ...] = ()


def skill_look(skill: str) -> tuple[str, RGB]:
    """A skill's display name and colour (its own name and `TARGET_COLOR` if unknown)."""
    from detach.skills import skill_class

    try:
        cls = skill_class(skill)
    except (KeyError, ValueError):
        return skill, TARGET_COLOR
    return str(cls.display_name), tuple(int(c) for c in cls.color)[:3]  # type: ignore[return-value]


def split_path(path: np.ndarray, index: float | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(done [A, 2], remaining [B, 2], reference point [2]) of a path cut at a fractional vertex
    index; both parts include the reference point, so together they draw the whole path."""
    path = np.asarray(path, dtype=np.float64)
    s = 0.0 if index is None else float(np.clip(index, 0.0, len(path) - 1))
    k = int(math.floor(s))
    ref = path[k] if k + 1 >= len(path) else path[k] + (s - k) * (path[k + 1] - path[k])
    done = np.vstack([path[: k + 1], ref[None]])
    remaining = np.vstack([ref[None], path[k + 1:]])
    return done, remaining, ref


def _lift(xy: np.ndarray, z: float = PATH_Z) -> np.ndarray:
    return np.column_stack([xy, np.full(len(xy), z)])


def task_markers(targets: Sequence[SceneTarget], state: TaskState) -> list[Marker]:
    """The markers of one frame: path (done, remaining, reference point), targets, caption,
    verdict. `targets` are the scene's (`SceneMessage.targets`, one per subtask that has a
    fixed one); the current subtask's live target, where the state has one, takes its place."""
    out: list[Marker] = []
    root = np.asarray(state.root, dtype=np.float64)
    if state.path is not None and len(state.path) >= 2:
        done, remaining, ref = split_path(state.path, state.path_index)
        if len(done) >= 2:
            out.append(Polyline("path/done", _lift(done), DONE_PATH_COLOR, 0.035))
        if len(remaining) >= 2:
            out.append(Polyline("path/remaining", _lift(remaining), PATH_COLOR, 0.05))
        out.append(Sphere("path/reference", np.array([ref[0], ref[1], 0.08]), 0.08, REFERENCE_COLOR))
    name, color = skill_look(state.skill)
    for t in targets:
        if t.subtask == state.subtask and state.target is not None:
            continue  # drawn below, where it is now
        current = t.subtask == state.subtask
        out.append(Sphere(f"target/{t.subtask}", np.asarray(t.pos, dtype=np.float64), 0.14 if current else 0.1,
                          tuple(t.color)[:3], 1.0 if current or t.subtask > state.subtask else 0.35))
        if current:
            out.append(Disc("target/ring", np.asarray(t.pos, dtype=np.float64), SUCCESS_RADIUS, tuple(t.color)[:3]))
    if state.target is not None:
        here = np.asarray(state.target, dtype=np.float64)
        out.append(Sphere(f"target/{state.subtask}", here, 0.14, color))
        out.append(Disc("target/ring", here, SUCCESS_RADIUS, color))
    above = root + np.array([0.0, 0.0, 1.1])
    caption = f"subtask {state.subtask}: {name}" if state.skill else "no subtask"
    out.append(Text("caption", f"{caption} · t = {state.time:.1f} s", above))
    if state.outcome in OUTCOMES:
        ok = state.outcome == "success"
        mark = SUCCESS_COLOR if ok else FAILURE_COLOR
        reached = f" ({sum(s >= 1.0 for s in state.scores)}/{len(state.scores)} subtasks)" if state.scores else ""
        out.append(Disc("verdict/ring", root, 0.7, mark, 0.7))
        out.append(Text("verdict", ("SUCCESS" if ok else "FAILURE") + reached, above + np.array([0.0, 0.0, 0.45]),
                        mark))
    return out


# --- recorded frames (untrusted) -----------------------------------------------------------
def _finite(value: Any, n: int) -> np.ndarray | None:
    """`value` as n finite numbers within `MAX_COORD`, else None."""
    try:
        return np.asarray(finite_coords(value, n), dtype=np.float64)
    except ContractError:
        return None


def parse_path(value: Any) -> np.ndarray | None:
    """A recorded "path": [K, 2] finite XY points (K <= MAX_PATH_POINTS), [0, 2] for [],
    None when malformed."""
    if not isinstance(value, list) or len(value) > MAX_PATH_POINTS:
        return None
    points = [_finite(p, 2) for p in value]
    if any(p is None for p in points):
        return None
    return np.asarray(points, dtype=np.float64).reshape(-1, 2)


class PathMemo:
    """The path in force for each recorded episode (a frame names its path only when it
    changed, `EpisodeFrame.path`): feed the frames of an episode in order."""

    def __init__(self) -> None:
        self._paths: dict[Any, np.ndarray | None] = {}

    def update(self, key: Any, frame: dict[str, Any]) -> np.ndarray | None:
        """The path of this frame of recording `key` (a frame 0 starts the recording afresh)."""
        if frame.get("frame") == 0:
            self._paths[key] = None
        if "path" in frame:
            path = parse_path(frame["path"])
            self._paths[key] = path if path is not None and len(path) >= 2 else None
        return self._paths.get(key)

    def forget(self, key: Any) -> None:
        self._paths.pop(key, None)


def task_state(frame: dict[str, Any], root: Any, path: np.ndarray | None) -> TaskState:
    """The TaskState of a recorded /episode/bodies frame (a JSON object from a log), with the
    path in force (`PathMemo`); malformed fields are left out."""
    def number(key: str, default: float | None) -> float | None:
        v = frame.get(key)
        ok = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and abs(v) <= MAX_COORD
        return float(v) if ok else default

    subtask = frame.get("subtask")
    skill = frame.get("skill")
    scores = frame.get("scores")
    good_scores = isinstance(scores, list) and len(scores) <= MAX_SCORES and all(
        isinstance(s, (int, float)) and not isinstance(s, bool) and math.isfinite(s) for s in scores)
    outcome = frame.get("outcome")
    root_xyz = _finite(list(np.asarray(root, dtype=np.float64).reshape(-1)[:3]), 3)
    return TaskState(
        time=number("time", 0.0) or 0.0,
        subtask=subtask if isinstance(subtask, int) and not isinstance(subtask, bool) and 0 <= subtask < 10_000 else 0,
        skill=skill[:MAX_TEXT] if isinstance(skill, str) else "",
        root=root_xyz if root_xyz is not None else np.zeros(3),
        target=_finite(frame.get("target"), 3), path=path, path_index=number("path_index", None),
        outcome=outcome if outcome in OUTCOMES else "",
        scores=tuple(float(s) for s in scores) if good_scores else ())
