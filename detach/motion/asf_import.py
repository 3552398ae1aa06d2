"""Read Acclaim ASF (skeleton) + AMC (motion) files, CMU's own mocap format, into `BvhData`, so
that they go through the same retargeting as BVH files (`detach.motion.retarget`).

Hand-written because no maintained package on PyPI reads ASF/AMC into plain arrays (the
known readers are unpackaged scripts); the format is small and is documented in the Acclaim
spec and CMU's mocap pages. Conventions used (those of the CMU database):
- Units: `:units length L` means the file's lengths are inches times L, so one unit is
  0.0254 / L metres (CMU: L = 0.45, 0.0564 m); lengths and root translations are converted to
  metres here. `angle deg|rad` (also `:DEGREES` / `:RADIANS` in the AMC) gives angle units.
- A bone's `axis ax ay az XYZ` is its local frame C = Rz(az) Ry(ay) Rx(ax) (composition order
  from the letters, the first letter applied first); its AMC values, one per `dof` in the
  listed order, form the rotation E applied in that order (rx ry rz -> Rz Ry Rx). World
  rotation: G_bone = G_parent C E C^-1 (the root: C_root E_root C_root^-1, with `order` giving
  its channels and `axis` its rotation order).
- At rest every G is the identity and a bone runs from its parent's end along `direction`
  times `length`, in the ASF world frame (Y up for CMU).
As BVH data: every bone becomes a joint at its start point (its parent's end; the root's
children start at the root), with offset = the parent bone's vector and local rotation
C E C^-1. So a joint's rotation turns the bone that starts at it, exactly as in CMU's BVH
conversions (lfemur = LeftUpLeg, ltibia = LeftLeg, ...).
AMC files carry no frame rate: CMU captured at 120 fps (the default `fps`).
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from detach.motion.bvh_import import BvhData, BvhError
from detach.motion.rotations import matrix_to_quat

INCH = 0.0254
"""Metres per inch (ASF lengths are inches times the `length` unit)."""
CMU_FPS = 120.0
"""Frame rate of the CMU captures (AMC files do not store one)."""
_AXES = {"x": 0, "y": 1, "z": 2}


class AsfError(BvhError):
    """An ASF or AMC file is missing or malformed; the message names the file (and line)."""


@dataclass
class _Bone:
    name: str
    direction: np.ndarray = field(default_factory=lambda: np.zeros(3))
    length: float = 0.0
    axis_angles: np.ndarray = field(default_factory=lambda: np.zeros(3))
    """`axis` angles about x, y, z (file angle units until converted)."""
    axis_order: list[str] = field(default_factory=lambda: ["x", "y", "z"])
    frame: np.ndarray = field(default_factory=lambda: np.eye(3))
    """C: the bone's local frame in world axes (from axis_angles / axis_order)."""
    dofs: list[str] = field(default_factory=list)
    """Rotation channels in AMC order, e.g. ['rx', 'ry', 'rz'] (translations are not supported
    for bones, as in CMU's files)."""


@dataclass
class Skeleton:
    """An ASF skeleton: bones in hierarchy order (index 0 is the root), lengths in metres."""

    path: str
    bones: list[_Bone]
    parents: list[int]
    root_order: list[str]
    """AMC channel names of the root, e.g. ['tx', 'ty', 'tz', 'rx', 'ry', 'rz']."""
    metres_per_unit: float
    degrees: bool

    def index(self, name: str) -> int:
        return [b.name for b in self.bones].index(name)


def _rotation(axis: str, angle: np.ndarray) -> np.ndarray:
    """[..., 3, 3] rotation about x/y/z by `angle` radians."""
    c, s = np.cos(angle), np.sin(angle)
    o, z = np.ones_like(angle), np.zeros_like(angle)
    rows = {"x": ((o, z, z), (z, c, -s), (z, s, c)),
            "y": ((c, z, s), (z, o, z), (-s, z, c)),
            "z": ((c, -s, z), (s, c, z), (z, z, o))}[axis]
    return np.stack([np.stack(r, -1) for r in rows], -2)


def _compose(axes: list[str], angles: np.ndarray) -> np.ndarray:
    """R = R_last ... R_first for angles [..., len(axes)] (the first axis applied first)."""
    out = np.broadcast_to(np.eye(3), (*angles.shape[:-1], 3, 3)).copy()
    for k, a in enumerate(axes):
        out = _rotation(a, angles[..., k]) @ out
    return out


def _lines(path: Path, kind: str) -> list[tuple[int, list[str]]]:
    """(line number, tokens) of the non-empty, non-comment lines of a text file."""
    if not path.is_file():
        raise AsfError(f"{path}: no such file")
    try:
        text = path.read_text(encoding="utf-8", errors="strict")
    except (UnicodeDecodeError, OSError) as e:
        raise AsfError(f"{path}: not an {kind} text file ({type(e).__name__})") from None
    out = []
    for i, line in enumerate(text.splitlines(), 1):
        line = line.split("#", 1)[0].strip()
        if line:
            out.append((i, line.split()))
    return out


def _floats(path: Path, number: int, tokens: list[str], count: int, what: str) -> np.ndarray:
    try:
        values = np.array([float(t) for t in tokens], dtype=np.float64)
    except ValueError:
        raise AsfError(f"{path}:{number}: {what}: expected numbers, got {' '.join(tokens)!r}") from None
    if len(values) != count:
        raise AsfError(f"{path}:{number}: {what}: expected {count} numbers, got {len(values)}")
    if not np.all(np.isfinite(values)):
        raise AsfError(f"{path}:{number}: {what}: NaN or inf")
    return values


def _axis_order(path: Path, number: int, text: str) -> list[str]:
    order = [c.lower() for c in text]
    if sorted(order) != ["x", "y", "z"]:
        raise AsfError(f"{path}:{number}: axis order {text!r}: expected a permutation of XYZ")
    return order


def read_asf(path: str | os.PathLike) -> Skeleton:
    """Parse an ASF skeleton; AsfError (one line naming file and line) if malformed."""
    path = Path(path)
    lines = _lines(path, "ASF")
    if not any(t[0] == ":bonedata" for _, t in lines):
        raise AsfError(f"{path}: not an ASF file (no :bonedata section)")
    length_unit, degrees = 1.0, True
    root = _Bone("root")
    root_order = ["tx", "ty", "tz", "rx", "ry", "rz"]
    bones: dict[str, _Bone] = {}
    children: dict[str, list[str]] = {}
    section, current = "", None
    for number, tokens in lines:
        head = tokens[0].lower()
        if head.startswith(":"):
            section = head
            continue
        if section == ":units":
            if head == "length":
                length_unit = float(_floats(path, number, tokens[1:2], 1, "units length")[0])
                if not length_unit > 0:
                    raise AsfError(f"{path}:{number}: units length must be > 0")
            elif head == "angle":
                degrees = tokens[1].lower().startswith("deg") if len(tokens) > 1 else True
        elif section == ":root":
            if head == "order":
                root_order = [t.lower() for t in tokens[1:]]
            elif head == "axis":
                root.axis_order = _axis_order(path, number, tokens[1] if len(tokens) > 1 else "XYZ")
            elif head == "orientation":
                root.axis_angles = _floats(path, number, tokens[1:], 3, "root orientation")
        elif section == ":bonedata":
            if head == "begin":
                current = _Bone("")
            elif head == "end":
                if current is None or not current.name:
                    raise AsfError(f"{path}:{number}: bone without a name")
                if current.name in bones or current.name == "root":
                    raise AsfError(f"{path}:{number}: duplicate bone {current.name!r}")
                bones[current.name] = current
                current = None
            elif current is None:
                raise AsfError(f"{path}:{number}: {tokens[0]!r} outside begin/end")
            elif head == "name":
                current.name = tokens[1] if len(tokens) > 1 else ""
            elif head == "direction":
                current.direction = _floats(path, number, tokens[1:], 3, f"{current.name} direction")
            elif head == "length":
                current.length = float(_floats(path, number, tokens[1:], 1, f"{current.name} length")[0])
            elif head == "axis":
                current.axis_angles = _floats(path, number, tokens[1:4], 3, f"{current.name} axis")
                current.axis_order = _axis_order(path, number, tokens[4] if len(tokens) > 4 else "XYZ")
            elif head == "dof":
                current.dofs = [t.lower() for t in tokens[1:]]
                bad = [d for d in current.dofs if d not in ("rx", "ry", "rz")]
                if bad:
                    raise AsfError(f"{path}:{number}: {current.name}: unsupported dof {bad[0]!r} (rx ry rz only)")
        elif section == ":hierarchy" and head not in ("begin", "end"):
            children.setdefault(tokens[0], []).extend(tokens[1:])
    if current is not None:
        raise AsfError(f"{path}: bone {current.name or '?'} has no 'end' (truncated file?)")
    if not bones:
        raise AsfError(f"{path}: no bones in :bonedata")
    unit = INCH / length_unit
    to_rad = np.pi / 180.0 if degrees else 1.0
    for bone in (root, *bones.values()):
        order = bone.axis_order
        bone.frame = _compose(order, np.array([bone.axis_angles[_AXES[a]] for a in order]) * to_rad)
        bone.length *= unit
        norm = np.linalg.norm(bone.direction)
        bone.direction = bone.direction / norm if norm > 0 else bone.direction
    ordered, parents = [root], [-1]
    todo = [("root", 0)]
    while todo:
        name, parent_index = todo.pop(0)
        for child in children.get(name, []):
            if child not in bones:
                raise AsfError(f"{path}: :hierarchy names unknown bone {child!r}")
            if any(b.name == child for b in ordered):
                raise AsfError(f"{path}: :hierarchy lists bone {child!r} twice")
            ordered.append(bones[child])
            parents.append(parent_index)
            todo.append((child, len(ordered) - 1))
    unused = sorted(set(bones) - {b.name for b in ordered})
    if unused:
        raise AsfError(f"{path}: bone(s) not in :hierarchy: {', '.join(unused)}")
    axes = ("tx", "ty", "tz", "rx", "ry", "rz")
    if not {"tx", "ty", "tz"} <= set(root_order) or any(o not in axes for o in root_order):
        raise AsfError(f"{path}: root order {' '.join(root_order)!r}: expected TX TY TZ and rotations")
    return Skeleton(str(path), ordered, parents, root_order, unit, degrees)


def read_amc(path: str | os.PathLike, skeleton: Skeleton, fps: float = CMU_FPS) -> BvhData:
    """Parse an AMC motion of `skeleton` into BvhData (metres, the ASF's axes)."""
    path = Path(path)
    if not fps > 0:
        raise AsfError(f"{path}: frame rate must be > 0, got {fps}")
    lines = _lines(path, "AMC")
    degrees = skeleton.degrees
    frames: list[dict[str, np.ndarray]] = []
    counts = {b.name: len(b.dofs) for b in skeleton.bones}
    counts["root"] = len(skeleton.root_order)
    for number, tokens in lines:
        head = tokens[0]
        if head.startswith(":"):
            if head.upper() == ":RADIANS":
                degrees = False
            elif head.upper() == ":DEGREES":
                degrees = True
            continue
        if len(tokens) == 1 and re.fullmatch(r"\d+", head):
            frames.append({})
            continue
        if not frames:
            raise AsfError(f"{path}:{number}: data before the first frame number (not an AMC file?)")
        if head not in counts:
            raise AsfError(f"{path}:{number}: bone {head!r} is not in the skeleton {skeleton.path}")
        frames[-1][head] = _floats(path, number, tokens[1:], counts[head], head)
    if not frames:
        raise AsfError(f"{path}: no frames")
    needed = [b.name for b in skeleton.bones if counts[b.name]]
    for k, frame in enumerate(frames):
        absent = [n for n in needed if n not in frame]
        if absent:
            raise AsfError(f"{path}: frame {k + 1} lacks {', '.join(absent[:5])} (truncated file?)")
    return _to_bvh(path, skeleton, frames, degrees, fps)


def _to_bvh(path: Path, skeleton: Skeleton, frames: list[dict[str, np.ndarray]], degrees: bool,
            fps: float) -> BvhData:
    f, bones = len(frames), skeleton.bones
    to_rad = np.pi / 180.0 if degrees else 1.0
    local = np.empty((f, len(bones), 3, 3))
    root = np.stack([frame["root"] for frame in frames])
    order = skeleton.root_order
    root_pos = root[:, [order.index(t) for t in ("tx", "ty", "tz")]] * skeleton.metres_per_unit
    rot_channels = [c for c in order if c.startswith("r")]
    root_rot = root[:, [order.index(c) for c in rot_channels]] * to_rad
    c_root = bones[0].frame
    local[:, 0] = c_root @ _compose([c[1] for c in rot_channels], root_rot) @ c_root.T
    for j, bone in enumerate(bones[1:], 1):
        if bone.dofs:
            values = np.stack([frame[bone.name] for frame in frames]) * to_rad
            local[:, j] = bone.frame @ _compose([d[1] for d in bone.dofs], values) @ bone.frame.T
        else:
            local[:, j] = np.eye(3)
    offsets = np.zeros((len(bones), 3))
    for j, p in enumerate(skeleton.parents):
        if p > 0:
            offsets[j] = bones[p].direction * bones[p].length
    quat = matrix_to_quat(local)
    return BvhData(str(path), [b.name for b in bones], list(skeleton.parents), offsets, 1.0 / fps, quat, root_pos)


def read_asf_amc(asf: str | os.PathLike, amc: str | os.PathLike, fps: float = CMU_FPS) -> BvhData:
    """Skeleton `asf` + motion `amc` as BvhData (metres, ASF axes; `fps`: the capture rate)."""
    return read_amc(amc, read_asf(asf), fps)
