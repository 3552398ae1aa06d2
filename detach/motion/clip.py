"""The motion clip: one reference motion of our humanoid, and its npz file format.

File format (`save_clip` / `load_clip`), one clip per `.npz`; frame k is at time k / fps:

| key            | shape / type | meaning |
| ---            | ---          | --- |
| format_version | int          | `FORMAT_VERSION` |
| name           | str          | clip name (unique within a library) |
| skill          | str          | one of `detach.motion.labels.MOTION_LABELS` |
| fps            | float        | frames per second (> 0) |
| root_pos       | [F, 3]       | pelvis origin, world frame, metres (Z up, floor at z = 0) |
| root_quat      | [F, 4]       | pelvis orientation, world frame, wxyz (unit) |
| dof_pos        | [F, 32]      | hinge angles in radians, `DOF_NAMES` order |
| body_pos       | [F, 15, 3]   | body origins, world, metres, `BODY_NAMES` order (MuJoCo FK of the above) |
| dof_names      | [32] str     | `DOF_NAMES` when written (checked on load) |
| body_names     | [15] str     | `BODY_NAMES` when written (checked on load) |
| meta           | str (JSON)   | optional: source, props (boxes the motion stands/sits on), notes |

Arrays are float32 on disk (float64 in memory). Loading checks shapes, finiteness, the skill
label and the name lists, and fails with one line naming the file (`ClipError`).
"""

from __future__ import annotations

import json
import os
import tempfile
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from detach.character.body import BODY_NAMES, DOF_NAMES
from detach.motion.labels import MOTION_LABELS

FORMAT_VERSION = 1
NUM_DOF = len(DOF_NAMES)
NUM_BODIES = len(BODY_NAMES)


class ClipError(ValueError):
    """A clip file or clip object is invalid; the message is one line naming the file."""


@dataclass
class MotionClip:
    """One motion of our humanoid; arrays are float64, F frames at `fps`."""

    name: str
    skill: str
    fps: float
    root_pos: np.ndarray
    """[F, 3] world, metres."""
    root_quat: np.ndarray
    """[F, 4] world, wxyz."""
    dof_pos: np.ndarray
    """[F, 32] radians, DOF_NAMES order."""
    body_pos: np.ndarray
    """[F, 15, 3] world, metres, BODY_NAMES order (forward kinematics of the above)."""
    meta: dict = field(default_factory=dict)
    """JSON-serialisable extras: `source`, `synthetic`, `props` (list of boxes
    {"center": [x, y, z], "half": [hx, hy, hz]} in the clip's world frame), notes."""

    @property
    def num_frames(self) -> int:
        return int(self.root_pos.shape[0])

    @property
    def duration(self) -> float:
        """Seconds from the first to the last frame."""
        return (self.num_frames - 1) / self.fps

    def validate(self, where: str = "<clip>") -> None:
        """Raise ClipError (one line, prefixed with `where`) unless shapes/values are sane."""
        _validate(self, where)


def _validate(c: MotionClip, where: str) -> None:
    def bad(msg: str) -> ClipError:
        return ClipError(f"{where}: {msg}")

    if not isinstance(c.name, str) or not c.name:
        raise bad("name must be a non-empty string")
    if c.skill not in MOTION_LABELS:
        raise bad(f"unknown skill label {c.skill!r}; expected one of {', '.join(MOTION_LABELS)}")
    if not (isinstance(c.fps, (int, float, np.floating, np.integer)) and np.isfinite(c.fps) and c.fps > 0):
        raise bad(f"fps must be a positive number, got {c.fps!r}")
    f = np.shape(c.root_pos)[0] if np.ndim(c.root_pos) >= 1 else 0
    if f < 1:
        raise bad("clip has no frames")
    for key, shape in (("root_pos", (f, 3)), ("root_quat", (f, 4)), ("dof_pos", (f, NUM_DOF)),
                       ("body_pos", (f, NUM_BODIES, 3))):
        arr = getattr(c, key)
        if np.shape(arr) != shape:
            raise bad(f"{key} has shape {list(np.shape(arr))}, expected {list(shape)}")
        if not np.all(np.isfinite(arr)):
            raise bad(f"{key} contains NaN or inf")
    norms = np.linalg.norm(c.root_quat, axis=-1)
    if np.any(np.abs(norms - 1.0) > 1e-3):
        i = int(np.argmax(np.abs(norms - 1.0)))
        raise bad(f"root_quat is not unit length (frame {i}: norm {norms[i]:.4f}); expected wxyz unit quaternions")


def clip_from_arrays(name: str, skill: str, fps: float, root_pos, root_quat, dof_pos,
                     body_pos, meta: dict | None = None, where: str = "<clip>") -> MotionClip:
    """Build and validate a clip; arrays become float64 and quaternions are re-normalised."""
    clip = MotionClip(name=name, skill=skill, fps=float(fps),
                      root_pos=np.asarray(root_pos, dtype=np.float64),
                      root_quat=np.asarray(root_quat, dtype=np.float64),
                      dof_pos=np.asarray(dof_pos, dtype=np.float64),
                      body_pos=np.asarray(body_pos, dtype=np.float64), meta=dict(meta or {}))
    clip.validate(where)
    clip.root_quat = clip.root_quat / np.linalg.norm(clip.root_quat, axis=-1, keepdims=True)
    return clip


def save_clip(clip: MotionClip, path: str | os.PathLike) -> Path:
    """Validate and write `clip` to `path` (atomically: temp file, then rename); returns the path."""
    path = Path(path)
    clip.validate(str(path))
    path.parent.mkdir(parents=True, exist_ok=True)
    arrays = {
        "format_version": np.int64(FORMAT_VERSION),
        "name": np.str_(clip.name),
        "skill": np.str_(clip.skill),
        "fps": np.float64(clip.fps),
        "root_pos": clip.root_pos.astype(np.float32),
        "root_quat": clip.root_quat.astype(np.float32),
        "dof_pos": clip.dof_pos.astype(np.float32),
        "body_pos": clip.body_pos.astype(np.float32),
        "dof_names": np.array(DOF_NAMES),
        "body_names": np.array(BODY_NAMES),
        "meta": np.str_(json.dumps(clip.meta, sort_keys=True)),
    }
    fd, tmp = tempfile.mkstemp(suffix=".npz.tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            np.savez_compressed(fh, **arrays)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


_REQUIRED = ("name", "skill", "fps", "root_pos", "root_quat", "dof_pos", "body_pos")


def load_clip(path: str | os.PathLike) -> MotionClip:
    """Read and validate one clip file; ClipError (one line naming the file) if it is not one."""
    path = Path(path)
    if not path.is_file():
        raise ClipError(f"{path}: no such file")
    try:
        with np.load(path, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as e:
        raise ClipError(f"{path}: not a motion clip npz ({type(e).__name__}: {e})") from None
    missing = [k for k in _REQUIRED if k not in data]
    if missing:
        raise ClipError(f"{path}: missing key(s) {', '.join(missing)}; expected {', '.join(_REQUIRED)}")
    version = int(data.get("format_version", FORMAT_VERSION))
    if version > FORMAT_VERSION:
        raise ClipError(f"{path}: format_version {version} is newer than this reader ({FORMAT_VERSION})")
    for key, expected in (("dof_names", DOF_NAMES), ("body_names", BODY_NAMES)):
        if key in data and tuple(str(s) for s in data[key]) != tuple(expected):
            raise ClipError(f"{path}: {key} do not match the humanoid's {key} (clip made for another character?)")
    try:
        meta = json.loads(str(data["meta"])) if "meta" in data else {}
    except json.JSONDecodeError as e:
        raise ClipError(f"{path}: meta is not valid JSON ({e})") from None
    try:
        fps = float(data["fps"])
    except (TypeError, ValueError):
        raise ClipError(f"{path}: fps must be a number, got {data['fps']!r}") from None
    arrays = {}
    for key in ("root_pos", "root_quat", "dof_pos", "body_pos"):
        if not np.issubdtype(data[key].dtype, np.number):
            raise ClipError(f"{path}: {key} must be numeric, got dtype {data[key].dtype}")
        arrays[key] = data[key]
    return clip_from_arrays(str(data["name"]), str(data["skill"]), fps, meta=meta, where=str(path), **arrays)


def load_clips(folder: str | os.PathLike) -> list[MotionClip]:
    """All `*.npz` clips of a folder, sorted by file name; ClipError if the folder is missing."""
    folder = Path(folder)
    if not folder.is_dir():
        raise ClipError(f"{folder}: no such folder of motion clips")
    return [load_clip(p) for p in sorted(folder.glob("*.npz"))]
