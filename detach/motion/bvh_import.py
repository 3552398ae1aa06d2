"""Read a BVH file (with bvhio) into plain numpy arrays of the source skeleton.

BVH semantics used here: every joint's rest frame has the world axes (no rest rotation);
OFFSET is the joint's position in its parent's frame; a frame's rotation channels give the
joint's rotation relative to that rest frame, composed intrinsically in channel order (bvhio
does this: "Zrotation Xrotation Yrotation" -> Rz Rx Ry). So the world rotation of a joint is
the product of local rotations from the root, and the rest pose is all-identity.

bvhio loops forever on some truncated files (it reads past the end of file), so the text is
checked first (header, balanced braces, MOTION section, frame count and values per frame);
every problem is a `BvhError` with one line naming the file.
"""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from detach.motion.rotations import quat_mul


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
    _precheck(path)
    with warnings.catch_warnings():  # bvhio's `import glm` triggers a PyGLM deprecation notice
        warnings.simplefilter("ignore", PendingDeprecationWarning)
        import bvhio  # imported lazily: pulls in PyGLM

    try:
        container = bvhio.readAsBvh(str(path))
    except Exception as e:  # bvhio raises SyntaxError/ValueError/IndexError with tuples attached
        msg = e.args[0] if isinstance(e, SyntaxError) and e.args else str(e)
        raise BvhError(f"{path}: not a valid BVH ({type(e).__name__}: {msg})") from None
    names, parents, offsets, joints = [], [], [], []

    def walk(j, parent: int) -> None:
        idx = len(names)
        names.append(j.Name)
        parents.append(parent)
        offsets.append([float(v) for v in j.Offset])
        joints.append(j)
        for child in j.Children:
            walk(child, idx)

    walk(container.Root, -1)
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise BvhError(f"{path}: duplicate joint name(s) {', '.join(dup)}")
    f = len(container.Root.Keyframes)
    quat = np.empty((f, len(joints), 4))
    for k, j in enumerate(joints):
        quat[:, k] = [list(kf.Rotation) for kf in j.Keyframes]  # glm.quat iterates as w, x, y, z
    root_pos = np.array([list(kf.Position) for kf in container.Root.Keyframes], dtype=np.float64)
    quat /= np.linalg.norm(quat, axis=-1, keepdims=True)
    if not (np.all(np.isfinite(quat)) and np.all(np.isfinite(root_pos))):
        raise BvhError(f"{path}: motion data contains NaN or inf")
    if not container.FrameTime > 0:
        raise BvhError(f"{path}: Frame Time must be > 0, got {container.FrameTime}")
    return BvhData(str(path), names, parents, np.array(offsets), float(container.FrameTime), quat, root_pos)


def _precheck(path: Path) -> None:
    """Cheap structural checks so that bvhio never reads past the end of the file."""
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
