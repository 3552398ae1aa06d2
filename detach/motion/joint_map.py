"""Joint maps: which joint of a source skeleton (BVH, ASF) drives which joint of our humanoid.

A map is a YAML file (shipped ones in `maps/`, format in docs/MOCAP.md, "Joint
maps"):

    scale: 0.056          # metres per source length unit, or `auto` (match our leg length)
    axes: [z, x, y]       # source axis that becomes our +X forward, +Y left, +Z up, or `auto`
    root: Hips            # source joint driving our pelvis
    detect: [LHipJoint]   # optional: joints typical of this skeleton (for `--map auto`)
    joints:               # our joint -> source joint, {bvh: NAME, aim: NAME}, or a list of
      abdomen: [Spine2, Spine1]   # candidate names (the first present in the file is used)
      left_knee: {bvh: LeftLeg, aim: LeftFoot}

A source name matches a file joint of the same name, or one that only adds a namespace prefix
(`mixamorig:Hips`, `mixamorig1:Hips` match `Hips`). `bind` resolves every name of a map against
one file and lists *every* missing joint in one line; `choose_map` picks the shipped map that
fits a file (all joints present, most `detect` joints present).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from detach.character.body import JOINT_GROUPS

MAPS_DIR = Path(__file__).parent / "maps"
MAP_FORMAT_DOC = "docs/MOCAP.md (joint maps)"
"""Where users read how to write a map (named in errors)."""
KEYS = ("scale", "axes", "root", "joints", "detect")
GROUPS = {g.name: g for g in JOINT_GROUPS}


class RetargetError(ValueError):
    """Bad map, or a map that does not fit the source file; one line naming the file."""


@dataclass(frozen=True)
class JointSpec:
    """One of our joints: candidate source joints driving it, and optional aim candidates."""

    source: tuple[str, ...]
    aim: tuple[str, ...] = ()


@dataclass(frozen=True)
class JointMap:
    name: str
    path: str
    scale: float | None
    """Metres per source unit; None = auto (our hip-to-ankle length / the source's)."""
    axes: np.ndarray | None
    """[3, 3] C with our_vector = C @ source_vector; None = auto (from the rest pose)."""
    root: tuple[str, ...]
    joints: dict[str, JointSpec]
    detect: tuple[str, ...] = ()


@dataclass(frozen=True)
class BoundMap:
    """A map resolved against one file: every name is a joint name of that file."""

    map: JointMap
    root: str
    joints: dict[str, tuple[str, str | None]]
    """our joint group -> (source joint, aim source joint or None)."""


def available_maps() -> list[str]:
    """Names of the shipped maps (maps/<name>.yaml)."""
    return sorted(p.stem for p in MAPS_DIR.glob("*.yaml"))


def load_map(name_or_path: str | os.PathLike) -> JointMap:
    """A shipped map by name (maps/<name>.yaml) or a YAML file path; RetargetError if invalid."""
    p = Path(name_or_path)
    if not (p.suffix in (".yaml", ".yml") and p.is_file()):
        p = MAPS_DIR / f"{name_or_path}.yaml"
        if not p.is_file():
            raise RetargetError(f"{name_or_path}: unknown joint map; shipped maps: {', '.join(available_maps())}, "
                                f"auto (or give a .yaml path; format: {MAP_FORMAT_DOC})")
    try:
        raw = yaml.safe_load(p.read_text())
    except yaml.YAMLError as e:
        raise RetargetError(f"{p}: invalid YAML ({str(e).splitlines()[0]})") from None
    if not isinstance(raw, dict):
        raise RetargetError(f"{p}: expected a mapping with keys scale, axes, root, joints (format: {MAP_FORMAT_DOC})")
    extra = set(raw) - set(KEYS)
    if extra:
        raise RetargetError(f"{p}: unknown key(s) {', '.join(sorted(extra))}; expected {', '.join(KEYS)}")
    missing = [k for k in ("scale", "axes", "root", "joints") if k not in raw]
    if missing:
        raise RetargetError(f"{p}: missing key(s) {', '.join(missing)} (format: {MAP_FORMAT_DOC})")
    scale = raw["scale"]
    if scale != "auto" and (isinstance(scale, bool) or not isinstance(scale, (int, float)) or not scale > 0):
        raise RetargetError(f"{p}: scale must be a positive number (metres per source unit) or auto, got {scale!r}")
    axes = None if raw["axes"] == "auto" else axes_matrix(raw["axes"], p)
    root = _names(raw["root"], p, "root")
    if not isinstance(raw["joints"], dict):
        raise RetargetError(f"{p}: joints must map our joint names to source joint names")
    joints = {}
    for ours, value in raw["joints"].items():
        if ours not in GROUPS:
            raise RetargetError(f"{p}: joints.{ours}: not a joint of the humanoid; expected one of {', '.join(GROUPS)}")
        if isinstance(value, dict):
            if not set(value) <= {"bvh", "aim"} or "bvh" not in value:
                raise RetargetError(f"{p}: joints.{ours}: expected a joint name, a list of names or "
                                    f"{{bvh: NAME, aim: NAME}}")
            aim = _names(value["aim"], p, f"joints.{ours}.aim") if value.get("aim") is not None else ()
            if aim and len(child_bodies(GROUPS[ours].body)) != 1:
                raise RetargetError(f"{p}: joints.{ours}.aim: {GROUPS[ours].body} has no single child body to aim at")
            joints[ours] = JointSpec(_names(value["bvh"], p, f"joints.{ours}.bvh"), aim)
        else:
            joints[ours] = JointSpec(_names(value, p, f"joints.{ours}"))
    detect = _names(raw["detect"], p, "detect") if raw.get("detect") is not None else ()
    return JointMap(p.stem, str(p), None if scale == "auto" else float(scale), axes, root, joints, detect)


def _names(value: object, p: Path, key: str) -> tuple[str, ...]:
    if isinstance(value, str) and value:
        return (value,)
    if isinstance(value, list) and value and all(isinstance(v, str) and v for v in value):
        return tuple(value)
    raise RetargetError(f"{p}: {key}: expected a source joint name or a list of names, got {value!r}")


def axes_matrix(axes: object, p: Path) -> np.ndarray:
    """C from three signed axis names (our x, y, z); RetargetError unless it is a rotation."""
    unit = {"x": 0, "y": 1, "z": 2}
    if not (isinstance(axes, list) and len(axes) == 3 and all(isinstance(a, str) for a in axes)):
        raise RetargetError(f"{p}: axes must be three source axes for our x, y, z, e.g. [z, x, y], or auto")
    c = np.zeros((3, 3))
    for row, a in enumerate(axes):
        sign = -1.0 if a.startswith("-") else 1.0
        key = a.lstrip("+-").lower()
        if key not in unit:
            raise RetargetError(f"{p}: axes: {a!r} is not one of x, y, z, -x, -y, -z")
        c[row, unit[key]] = sign
    if abs(np.linalg.det(c) - 1.0) > 1e-9:
        raise RetargetError(f"{p}: axes {axes} is not a rotation (a permutation with det +1 is required)")
    return c


def child_bodies(body: str) -> list[str]:
    """Names of our bodies whose parent is `body` (the rest bone of an `aim` runs to its only child)."""
    from detach.motion.kinematics import humanoid_fk

    m = humanoid_fk().model
    bid = m.body(body).id
    return [m.body(i).name for i in range(m.nbody) if m.body_parentid[i] == bid and i != bid]


def resolve(candidates: Sequence[str], file_names: Sequence[str]) -> str | None:
    """The file joint matching the first candidate that is present (exact name, else the same
    name behind a namespace prefix such as `mixamorig:`), or None."""
    by_bare: dict[str, str] = {}
    for n in file_names:
        by_bare.setdefault(n.rpartition(":")[2], n)
    for c in candidates:
        if c in file_names:
            return c
        if c in by_bare:
            return by_bare[c]
    return None


def bind(jmap: JointMap, file_names: Sequence[str], where: str) -> BoundMap:
    """Resolve every name of `jmap` against a file's joints; RetargetError listing all missing."""
    missing: dict[str, list[str]] = {}  # absent name (or candidates) -> roles needing it

    def find(cands: tuple[str, ...], role: str) -> str:
        found = resolve(cands, file_names)
        if found is None:
            missing.setdefault("|".join(cands), []).append(role)
        return found or ""

    root = find(jmap.root, "root")
    joints = {}
    for ours, spec in jmap.joints.items():
        src = find(spec.source, ours)
        aim = find(spec.aim, f"{ours} aim") if spec.aim else None
        joints[ours] = (src, aim)
    if missing:
        listed = ", ".join(f"{name} ({', '.join(roles)})" for name, roles in missing.items())
        raise RetargetError(f"{where}: map '{jmap.name}' needs {len(missing)} joint(s) the file does not have: "
                            f"{listed}; file joints: {', '.join(file_names)}; try --map auto, another "
                            f"shipped map ({', '.join(available_maps())}) or your own (format: {MAP_FORMAT_DOC})")
    return BoundMap(jmap, root, joints)


def detect_score(jmap: JointMap, file_names: Sequence[str]) -> int:
    """How many of the map's `detect` joints the file has."""
    return sum(resolve((d,), file_names) is not None for d in jmap.detect)


def choose_map(file_names: Sequence[str], where: str) -> BoundMap:
    """The shipped map that fits a file: every joint present, then most `detect` joints
    present, then the first by name. RetargetError listing each map's missing joints if none fits."""
    fits: list[tuple[int, str, BoundMap]] = []
    misses: list[str] = []
    for name in available_maps():
        jmap = load_map(name)
        try:
            bound = bind(jmap, file_names, where)
        except RetargetError:
            misses.append(f"{name} lacks {', '.join(_needed_names(jmap, file_names))}")
            continue
        fits.append((-detect_score(jmap, file_names), name, bound))
    if not fits:
        raise RetargetError(f"{where}: no shipped joint map fits this skeleton ({'; '.join(misses)}); file joints: "
                            f"{', '.join(file_names)}; write a map for it (format: {MAP_FORMAT_DOC}) and pass "
                            "--map FILE.yaml")
    return min(fits, key=lambda t: (t[0], t[1]))[2]


def _needed_names(jmap: JointMap, file_names: Sequence[str]) -> list[str]:
    """Candidate names of the map's joints that are absent from the file (for messages)."""
    out = []
    for cands in (jmap.root, *(c for spec in jmap.joints.values() for c in (spec.source, spec.aim) if c)):
        if resolve(cands, file_names) is None and "|".join(cands) not in out:
            out.append("|".join(cands))
    return out
