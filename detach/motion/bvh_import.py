"""Read a BVH file into plain numpy arrays of the source skeleton.

BVH semantics used here: every joint's rest frame has the world axes (no rest rotation);
OFFSET is the joint's position in its parent's frame; a frame's rotation channels give the
joint's rotation relative to that rest frame, composed intrinsically in channel order
("Zrotation Xrotation Yrotation" -> Rz Rx Ry). So the world rotation of a joint is the product
of local rotations from the root, and the rest pose is all-identity. Position channels replace
the matching OFFSET component (the root's give its per-frame position; those of other joints
are not used: retargeting needs rotations and the root path only).

Parsed here with numpy rather than with bvhio, which implements the same semantics (the tests
compare both on every test file) but builds a Python object per joint and frame: 9.7 s for a
12,000-frame CMU-size file (100 s at 120 fps) against ~0.3 s here, and it loops forever on some
truncated files. The text is checked first (header, balanced braces, MOTION section, frame
count and values per frame); every problem is a `BvhError` with one line naming the file.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from detach.motion.rotations import quat_from_axis_angle, quat_mul

_AXIS = {"Xrotation": 0, "Yrotation": 1, "Zrotation": 2}
_POSITION = {"Xposition": 0, "Yposition": 1, "Zposition": 2}


class BvhError(ValueError):
    """The file is missing or is not a readable BVH; the message names the file."""


@dataclass
class BvhData:
    """A BVH skeleton and its motion, in the file's own axes and length units."""

    path: str
    names: list[str]
    """Joint names, depth-first (file) order; index 0 is the root."""
    parents: list[int]
    """Parent index per joint (-1 for the root)."""
    offsets: np.ndarray
    """[J, 3] rest offsets in the parent frame (file units)."""
    frame_time: float
    """Seconds per frame."""
    local_quat: np.ndarray
    """[F, J, 4] wxyz rotation of each joint relative to its (identity) rest frame."""
    root_pos: np.ndarray
    """[F, 3] root position, file units and axes."""

    @property
    def num_frames(self) -> int:
        return int(self.local_quat.shape[0])

    def index(self, name: str) -> int:
        return self.names.index(name)

    def global_quat(self) -> np.ndarray:
        """[F, J, 4] world rotations (file axes): product of local rotations from the root."""
        g = np.empty_like(self.local_quat)
        for j, p in enumerate(self.parents):
            g[:, j] = self.local_quat[:, j] if p < 0 else quat_mul(g[:, p], self.local_quat[:, j])
        return g

    def rest_positions(self) -> np.ndarray:
        """[J, 3] joint positions in the rest pose relative to the root (file units)."""
        pos = np.zeros((len(self.names), 3))
        for j, p in enumerate(self.parents):
            if p >= 0:
                pos[j] = pos[p] + self.offsets[j]
        return pos


def read_bvh(path: str | os.PathLike) -> BvhData:
    """Parse `path`; BvhError (one line naming the file) if it is not a valid BVH."""
    path = Path(path)
    lines = _precheck(path)
    m = next(i for i, t in enumerate(lines) if t[0] == "MOTION")
    names, parents, offsets, channels = _hierarchy(path, lines[1:m])
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise BvhError(f"{path}: duplicate joint name(s) {', '.join(dup)}")
    frames = int(lines[m + 1][1])
    try:
        frame_time = float(lines[m + 2][2])
        values = np.array([v for t in lines[m + 3:m + 3 + frames] for v in t], dtype=np.float64)
    except (IndexError, ValueError):
        raise BvhError(f"{path}: Frame Time and frame values must be numbers") from None
    values = values.reshape(frames, -1)
    if not np.all(np.isfinite(values)):
        raise BvhError(f"{path}: motion data contains NaN or inf")
    if not frame_time > 0:
        raise BvhError(f"{path}: Frame Time must be > 0, got {frame_time}")
    quat = np.empty((frames, len(names), 4))
    root_pos = np.tile(offsets[0], (frames, 1))
    column = 0
    for j, chans in enumerate(channels):
        q = np.tile([1.0, 0.0, 0.0, 0.0], (frames, 1))
        for c in chans:
            if c in _AXIS:
                axis = np.zeros(3)
                axis[_AXIS[c]] = 1.0
                q = quat_mul(q, quat_from_axis_angle(axis, np.deg2rad(values[:, column])))
            elif c in _POSITION and j == 0:
                root_pos[:, _POSITION[c]] = values[:, column]
            column += 1
        quat[:, j] = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return BvhData(str(path), names, parents, np.array(offsets), frame_time, quat, root_pos)


def _hierarchy(path: Path, lines: list[list[str]]) -> tuple[list[str], list[int], np.ndarray, list[list[str]]]:
    """(names, parents, offsets [J, 3], channel names per joint) of the HIERARCHY section."""
    tokens = [tok for t in lines for tok in t]
    names: list[str] = []
    parents: list[int] = []
    offsets: list[list[float]] = []
    channels: list[list[str]] = []
    stack: list[int] = []  # open joints (-1 for an End Site block)
    i = 0

    def take(count: int, what: str) -> list[str]:
        nonlocal i
        if i + count > len(tokens):
            raise BvhError(f"{path}: HIERARCHY ends inside {what}")
        out = tokens[i:i + count]
        i += count
        return out

    while i < len(tokens):
        tok = take(1, "a joint")[0]
        if tok in ("ROOT", "JOINT"):
            if (tok == "ROOT") != (not names):
                raise BvhError(f"{path}: expected exactly one ROOT, first in HIERARCHY")
            names.append(take(1, "a joint name")[0])
            parents.append(next((k for k in reversed(stack) if k >= 0), -1))
            offsets.append([0.0, 0.0, 0.0])
            channels.append([])
            if take(1, f"joint {names[-1]}") != ["{"]:
                raise BvhError(f"{path}: joint {names[-1]}: expected '{{' after its name")
            stack.append(len(names) - 1)
        elif tok == "End":
            take(2, "an End Site")  # "Site" "{"
            stack.append(-1)
        elif tok == "OFFSET":
            try:
                offset = [float(v) for v in take(3, "an OFFSET")]
            except ValueError:
                raise BvhError(f"{path}: OFFSET values must be numbers") from None
            if stack and stack[-1] >= 0:
                offsets[stack[-1]] = offset
        elif tok == "CHANNELS":
            count = int(take(1, "CHANNELS")[0])
            chans = take(count, "CHANNELS")
            bad = [c for c in chans if c not in _AXIS and c not in _POSITION]
            if bad or not stack or stack[-1] < 0:
                raise BvhError(f"{path}: bad CHANNELS {' '.join(chans)!r} (expected X/Y/Z position/rotation)")
            channels[stack[-1]] = chans
        elif tok == "}":
            if not stack:
                raise BvhError(f"{path}: unbalanced braces in the HIERARCHY section")
            stack.pop()
        else:
            raise BvhError(f"{path}: unexpected {tok!r} in the HIERARCHY section")
    if not names:
        raise BvhError(f"{path}: no ROOT joint in the HIERARCHY section")
    return names, parents, np.array(offsets, dtype=np.float64), channels


def _precheck(path: Path) -> list[list[str]]:
    """Structural checks before parsing; returns the file's non-empty lines as token lists."""
    if not path.is_file():
        raise BvhError(f"{path}: no such file")
    try:
        text = path.read_text(encoding="utf-8", errors="strict")
    except (UnicodeDecodeError, OSError) as e:
        raise BvhError(f"{path}: not a BVH text file ({type(e).__name__})") from None
    lines = [ln.split() for ln in text.splitlines()]
    lines = [t for t in lines if t]
    if not lines or lines[0] != ["HIERARCHY"]:
        raise BvhError(f"{path}: not a BVH file (expected 'HIERARCHY' on the first line)")
    try:
        m = next(i for i, t in enumerate(lines) if t[0] == "MOTION")
    except StopIteration:
        raise BvhError(f"{path}: no MOTION section") from None
    head = [tok for t in lines[:m] for tok in t]
    if head.count("{") != head.count("}") or head.count("{") == 0:
        raise BvhError(f"{path}: unbalanced braces in the HIERARCHY section")
    channels = 0
    for t in lines[:m]:
        if t[0] == "CHANNELS":
            try:
                channels += int(t[1])
            except (IndexError, ValueError):
                raise BvhError(f"{path}: bad CHANNELS line {' '.join(t)!r}") from None
    if len(lines) < m + 3 or lines[m + 1][0] != "Frames:" or lines[m + 2][:2] != ["Frame", "Time:"]:
        raise BvhError(f"{path}: MOTION must be followed by 'Frames: N' and 'Frame Time: T'")
    try:
        frames = int(lines[m + 1][1])
    except (IndexError, ValueError):
        raise BvhError(f"{path}: bad frame count {' '.join(lines[m + 1])!r}") from None
    if frames < 1:
        raise BvhError(f"{path}: no frames (Frames: {frames})")
    data = lines[m + 3:]
    if len(data) < frames:
        raise BvhError(f"{path}: Frames: {frames} but only {len(data)} frame lines (truncated file?)")
    for k, t in enumerate(data[:frames]):
        if len(t) != channels:
            raise BvhError(f"{path}: frame {k} has {len(t)} values, expected {channels} (one per channel)")
    return lines
