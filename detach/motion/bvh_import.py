"""Read a BVH file into plain numpy arrays of the source skeleton.

BVH semantics used here: every joint's rest frame has the world axes (no rest rotation);
OFFSET is the joint's position in its parent's frame; a frame's rotation channels give the
joint's rotation relative to that rest frame, composed intrinsically in channel order
("Zrotation Xrotation Yrotation" -> Rz Rx Ry). So the world rotation of a joint is the product
of local rotations from the root, and the rest pose is all-identity. Position channels replace
the matching OFFSET component: the root's give its per-frame position, those of other joints
are kept per frame in `joint_pos` (used for the path of a map root below the file's ROOT).

Parsed here with numpy rather than with bvhio, which implements the same semantics (the tests
compare both on every test file) but builds a Python object per joint and frame: 9.7 s for a
12,000-frame CMU-size file (100 s at 120 fps) against ~0.3 s here, and it loops forever on some
truncated files. The text is checked first (header, balanced braces, MOTION section, frame
count and values per frame); every problem is a `BvhError` with one line naming the file.
"""

from __future__ import annotations

import io
import os
from dataclasses import dataclass, field
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
    joint_pos: dict[int, np.ndarray] = field(default_factory=dict)
    """[F, 3] per-frame offsets of the non-root joints that have position channels (the OFFSET
    with those components replaced), e.g. Hips under a static `Reference` root."""

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
    sections = _sections(path)
    names, parents, offsets, channels = _hierarchy(path, sections.header)
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise BvhError(f"{path}: duplicate joint name(s) {', '.join(dup)}")
    frames = sections.frames
    try:
        frame_time = float(sections.frame_time)
    except ValueError:
        raise BvhError(f"{path}: Frame Time must be a number, got {sections.frame_time!r}") from None
    values = _values(path, sections)
    if not np.all(np.isfinite(values)):
        raise BvhError(f"{path}: motion data contains NaN or inf")
    if not frame_time > 0:
        raise BvhError(f"{path}: Frame Time must be > 0, got {frame_time}")
    quat = np.empty((frames, len(names), 4))
    root_pos = np.tile(offsets[0], (frames, 1))
    column = 0
    joint_pos: dict[int, np.ndarray] = {}
    for j, chans in enumerate(channels):
        q = np.tile([1.0, 0.0, 0.0, 0.0], (frames, 1))
        for c in chans:
            if c in _AXIS:
                axis = np.zeros(3)
                axis[_AXIS[c]] = 1.0
                q = quat_mul(q, quat_from_axis_angle(axis, np.deg2rad(values[:, column])))
            elif j == 0:
                root_pos[:, _POSITION[c]] = values[:, column]
            else:
                joint_pos.setdefault(j, np.tile(offsets[j], (frames, 1)))[:, _POSITION[c]] = values[:, column]
            column += 1
        quat[:, j] = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return BvhData(str(path), names, parents, np.array(offsets), frame_time, quat, root_pos, joint_pos)


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


@dataclass
class _Sections:
    """A BVH file split into its parts, after the structural checks."""

    header: list[list[str]]
    """Token lists of the non-empty lines before MOTION ("HIERARCHY" excluded)."""
    frames: int
    frame_time: str
    data: list[str]
    """The `frames` non-empty lines of values."""
    channels: int


def _read_text(path: Path, kind: str = "BVH") -> str:
    """The file's text (UTF-8, else Latin-1: some exporters write accented names)."""
    if not path.is_file():
        raise BvhError(f"{path}: no such file")
    raw = path.read_bytes()
    if b"\0" in raw[:4096]:
        raise BvhError(f"{path}: not a {kind} text file (binary data)")
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError:
        return raw.decode("latin-1")


def _sections(path: Path) -> _Sections:
    """Structural checks before parsing (header, balanced braces, MOTION, frame count, values
    per frame), so that a truncated or malformed file is one line naming it."""
    lines = [ln for ln in _read_text(path).splitlines() if ln.strip()]
    if not lines or lines[0].split() != ["HIERARCHY"]:
        raise BvhError(f"{path}: not a BVH file (expected 'HIERARCHY' on the first line)")
    try:
        m = next(i for i, ln in enumerate(lines) if ln.split()[0] == "MOTION")
    except StopIteration:
        raise BvhError(f"{path}: no MOTION section") from None
    header = [ln.split() for ln in lines[1:m]]
    head = [tok for t in header for tok in t]
    if head.count("{") != head.count("}") or head.count("{") == 0:
        raise BvhError(f"{path}: unbalanced braces in the HIERARCHY section")
    channels = 0
    for t in header:
        if t[0] == "CHANNELS":
            try:
                channels += int(t[1])
            except (IndexError, ValueError):
                raise BvhError(f"{path}: bad CHANNELS line {' '.join(t)!r}") from None
    tail = [ln.split() for ln in lines[m + 1:m + 3]]
    if len(tail) < 2 or tail[0][:1] != ["Frames:"] or tail[1][:2] != ["Frame", "Time:"] or len(tail[1]) < 3:
        raise BvhError(f"{path}: MOTION must be followed by 'Frames: N' and 'Frame Time: T'")
    try:
        frames = int(tail[0][1])
    except (IndexError, ValueError):
        raise BvhError(f"{path}: bad frame count {' '.join(tail[0])!r}") from None
    if frames < 1:
        raise BvhError(f"{path}: no frames (Frames: {frames})")
    data = lines[m + 3:m + 3 + frames]
    if len(data) < frames:
        raise BvhError(f"{path}: Frames: {frames} but only {len(data)} frame lines (truncated file?)")
    return _Sections(header, frames, tail[1][2], data, channels)


def _values(path: Path, sections: _Sections) -> np.ndarray:
    """[frames, channels] motion values (numpy's C parser: memory ~ the array, not the text)."""
    try:
        values = np.loadtxt(io.StringIO("\n".join(sections.data)), dtype=np.float64, ndmin=2)
    except ValueError:
        values = None
    if values is None or values.shape != (sections.frames, sections.channels):
        for k, line in enumerate(sections.data):
            tokens = line.split()
            if len(tokens) != sections.channels:
                raise BvhError(f"{path}: frame {k} has {len(tokens)} values, expected {sections.channels} "
                               "(one per channel)")
            try:
                [float(t) for t in tokens]
            except ValueError:
                raise BvhError(f"{path}: frame {k}: values must be numbers") from None
        raise BvhError(f"{path}: unreadable frame values")
    return values
