"""Retarget a BVH motion to our humanoid through a joint-name map (YAML, see maps/cmu.yaml).

Map keys: `scale` (metres per BVH unit), `axes` (which BVH axis becomes our +X forward, +Y
left, +Z up; "-" flips; must be a rotation), `root` (BVH joint -> our pelvis), `joints`
(our joint group -> BVH joint name, or {bvh: NAME, aim: NAME}).

Method, per frame (all rotations expressed in our axes via C, i.e. R' = C R C^T):
1. world rotation G_j of every BVH joint (product of local rotations; the BVH rest pose is
   all-identity);
2. world rotation of each of our bodies: R_body = G_bvh * Q, where Q is the rest-pose
   correction: identity, or with `aim` the smallest rotation taking our rest bone direction
   (body -> its child body) onto the BVH rest bone direction (bvh joint -> aim joint). So a
   T-pose arm maps onto our hanging arm; bodies of unmapped joints follow their parent;
3. our joint's local rotation L = R_parent^-1 R_body, turned into hinge angles: for joints
   whose hinges are x, y, z in this order (MuJoCo nests them as Rx Ry Rz), Euler xyz; for
   hinge-like joints (elbows, and knees whose x/z ranges are tiny) the twist about y;
4. angles are clipped to dof_ranges() (the fraction clipped is reported);
root position = C * hips position * scale; the source rate 1 / Frame Time is snapped to a whole
number when within 0.01% (files store 0.0333333 s); the clip is resampled to `fps` if given, body
positions come from MuJoCo FK, then the whole clip is shifted so that its first root position
is above the origin and the lowest foot point over the clip touches z = 0.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from detach.character.body import BODY_NAMES, JOINT_GROUPS, dof_ranges
from detach.motion.bvh_import import BvhData, read_bvh
from detach.motion.clip import MotionClip, clip_from_arrays
from detach.motion.kinematics import humanoid_fk
from detach.motion.rotations import (euler_xyz_from_matrix, min_rotation, quat_conj, quat_continuous,
                                     quat_mul, quat_to_matrix, slerp, twist_angle)

MAPS_DIR = Path(__file__).parent / "maps"
_GROUPS = {g.name: g for g in JOINT_GROUPS}
_HINGE_LIKE_RANGE = 0.2  # rad: a 3-DoF joint whose other two hinges span less than this is a hinge


class RetargetError(ValueError):
    """Bad map or a map that does not fit the BVH; one line naming the file."""


@dataclass
class JointMap:
    name: str
    path: str
    scale: float
    axes: np.ndarray
    """[3, 3] C with our_vector = C @ bvh_vector."""
    root: str
    joints: dict[str, tuple[str, str | None]]
    """our joint group -> (BVH joint, aim BVH joint or None)."""


def available_maps() -> list[str]:
    return sorted(p.stem for p in MAPS_DIR.glob("*.yaml"))


def load_map(name_or_path: str | os.PathLike) -> JointMap:
    """A shipped map by name (maps/<name>.yaml) or a YAML file path."""
    p = Path(name_or_path)
    if not (p.suffix in (".yaml", ".yml") and p.is_file()):
        p = MAPS_DIR / f"{name_or_path}.yaml"
        if not p.is_file():
            raise RetargetError(f"{name_or_path}: unknown joint map; shipped maps: {', '.join(available_maps())} "
                                "(or give a .yaml path)")
    try:
        raw = yaml.safe_load(p.read_text())
    except yaml.YAMLError as e:
        raise RetargetError(f"{p}: invalid YAML ({str(e).splitlines()[0]})") from None
    if not isinstance(raw, dict):
        raise RetargetError(f"{p}: expected a mapping with keys scale, axes, root, joints")
    extra = set(raw) - {"scale", "axes", "root", "joints"}
    if extra:
        raise RetargetError(f"{p}: unknown key(s) {', '.join(sorted(extra))}; expected scale, axes, root, joints")
    missing = [k for k in ("scale", "axes", "root", "joints") if k not in raw]
    if missing:
        raise RetargetError(f"{p}: missing key(s) {', '.join(missing)}")
    scale = raw["scale"]
    if not isinstance(scale, (int, float)) or not scale > 0:
        raise RetargetError(f"{p}: scale must be a positive number (metres per BVH unit), got {scale!r}")
    axes = _axes_matrix(raw["axes"], p)
    if not isinstance(raw["root"], str):
        raise RetargetError(f"{p}: root must be a BVH joint name, got {raw['root']!r}")
    if not isinstance(raw["joints"], dict):
        raise RetargetError(f"{p}: joints must map our joint names to BVH joint names")
    joints = {}
    for ours, v in raw["joints"].items():
        if ours not in _GROUPS:
            raise RetargetError(f"{p}: joints.{ours}: not a joint of the humanoid; "
                                f"expected one of {', '.join(_GROUPS)}")
        if isinstance(v, str):
            joints[ours] = (v, None)
        elif isinstance(v, dict) and isinstance(v.get("bvh"), str) and set(v) <= {"bvh", "aim"}:
            aim = v.get("aim")
            if aim is not None and not isinstance(aim, str):
                raise RetargetError(f"{p}: joints.{ours}.aim must be a BVH joint name")
            if aim is not None and len(_children(_GROUPS[ours].body)) != 1:
                raise RetargetError(f"{p}: joints.{ours}.aim: {_GROUPS[ours].body} has no single child body to aim at")
            joints[ours] = (v["bvh"], aim)
        else:
            raise RetargetError(f"{p}: joints.{ours}: expected a BVH joint name or {{bvh: NAME, aim: NAME}}")
    return JointMap(p.stem, str(p), float(scale), axes, raw["root"], joints)


def _axes_matrix(axes, p: Path) -> np.ndarray:
    unit = {"x": 0, "y": 1, "z": 2}
    if not (isinstance(axes, list) and len(axes) == 3 and all(isinstance(a, str) for a in axes)):
        raise RetargetError(f"{p}: axes must be three BVH axes for our x, y, z, e.g. [z, x, y]")
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


def _children(body: str) -> list[str]:
    m = humanoid_fk().model
    bid = m.body(body).id
    return [m.body(i).name for i in range(m.nbody) if m.body_parentid[i] == bid and i != bid]


def retarget(bvh: BvhData, jmap: JointMap, skill: str = "walk", name: str | None = None,
             scale: float | None = None, fps: float | None = None) -> tuple[MotionClip, float]:
    """(clip, fraction of hinge angles clipped to their ranges) for a parsed BVH."""
    where = bvh.path
    needed = [jmap.root] + [n for b, a in jmap.joints.values() for n in (b, a) if n]
    for n in needed:
        if n not in bvh.names:
            raise RetargetError(f"{where}: joint {n!r} of map {jmap.name!r} is not in the BVH "
                                f"(BVH joints: {', '.join(bvh.names)})")
    scale = jmap.scale if scale is None else float(scale)
    if not scale > 0:
        raise RetargetError(f"{where}: scale must be > 0, got {scale}")
    c = jmap.axes
    g = bvh.global_quat()  # [F, J, 4] file axes
    g = np.concatenate((g[..., :1], g[..., 1:] @ c.T), axis=-1)  # C R C^T as a quaternion
    rest = bvh.rest_positions() @ c.T
    ours_rest = humanoid_fk().rest_body_pos()
    bidx = {n: i for i, n in enumerate(BODY_NAMES)}

    f = bvh.num_frames
    world = {"pelvis": g[:, bvh.index(jmap.root)]}
    body_group = {grp.body: grp for grp in JOINT_GROUPS}
    m = humanoid_fk().model
    angles: dict[str, np.ndarray] = {}
    for body in BODY_NAMES[1:]:  # tree order: a parent's world rotation is known first
        parent = m.body(m.body_parentid[m.body(body).id]).name
        grp = body_group.get(body)
        if grp is not None and grp.name in jmap.joints:
            src, aim = jmap.joints[grp.name]
            q = np.array([1.0, 0.0, 0.0, 0.0])
            if aim:
                ours = ours_rest[bidx[_children(body)[0]]] - ours_rest[bidx[body]]
                theirs = rest[bvh.index(aim)] - rest[bvh.index(src)]
                q = min_rotation(ours, theirs)
            world[body] = quat_mul(g[:, bvh.index(src)], np.broadcast_to(q, (f, 4)))
        else:
            world[body] = world[parent]
        if grp is not None:
            local = quat_mul(quat_conj(world[parent]), world[body])
            angles[grp.name] = _angles(local, grp)
    dof = np.concatenate([angles[grp.name] for grp in JOINT_GROUPS], axis=1)  # DOF_NAMES order
    rng = dof_ranges()
    clipped = float(np.mean((dof < rng[:, 0] - 1e-3) | (dof > rng[:, 1] + 1e-3)))
    dof = np.clip(dof, rng[:, 0], rng[:, 1])
    root_quat = quat_continuous(world["pelvis"])
    root_pos = (bvh.root_pos @ c.T) * scale
    src_fps = _snap_fps(1.0 / bvh.frame_time)
    if fps is not None and abs(fps - src_fps) > 1e-9:
        root_pos, root_quat, dof = _resample(root_pos, root_quat, dof, src_fps, fps)
    out_fps = src_fps if fps is None else float(fps)
    fk = humanoid_fk().run(root_pos, root_quat, dof)
    shift = np.array([-root_pos[0, 0], -root_pos[0, 1], -fk.foot_bottom.min()])
    clip = clip_from_arrays(name or Path(bvh.path).stem, skill, out_fps, root_pos + shift, root_quat, dof,
                            fk.body_pos + shift, where=where,
                            meta={"source": str(bvh.path), "map": jmap.name, "scale": scale,
                                  "source_fps": src_fps, "clipped_fraction": clipped, "synthetic": False})
    return clip, clipped


def _angles(local: np.ndarray, grp) -> np.ndarray:
    """[F, len(axes)] hinge angles of one joint group from its local rotations [F, 4]."""
    if len(grp.axes) == 1:
        return twist_angle(local, "xyz".index(grp.axes))[:, None]
    spans = [hi - lo for lo, hi in grp.ranges]
    narrow = [i for i, s in enumerate(spans) if s < _HINGE_LIKE_RANGE]
    if grp.axes == "xyz" and len(narrow) == 2:
        out = np.zeros((len(local), 3))
        k = ({0, 1, 2} - set(narrow)).pop()
        out[:, k] = twist_angle(local, k)
        return out
    if grp.axes != "xyz":
        raise RetargetError(f"joint group {grp.name}: unsupported hinge axes {grp.axes!r}")
    return euler_xyz_from_matrix(quat_to_matrix(local), gimbal_eps=1e-5)


def _snap_fps(fps: float) -> float:
    """BVH frame times are rounded in the file (0.0333333 s): snap to a whole rate within 0.01%."""
    r = round(fps)
    return float(r) if r > 0 and abs(fps - r) <= 1e-4 * r else fps


def _resample(root_pos, root_quat, dof, src_fps: float, fps: float):
    if not fps > 0:
        raise RetargetError(f"fps must be > 0, got {fps}")
    n = root_pos.shape[0]
    duration = (n - 1) / src_fps
    t = np.arange(int(np.floor(duration * fps + 1e-4)) + 1) / fps
    ft = np.clip(t * src_fps, 0, n - 1)
    i0 = np.minimum(np.floor(ft).astype(int), max(n - 2, 0))
    i1 = np.minimum(i0 + 1, n - 1)
    w = (ft - i0)[:, None]
    lerp = lambda x: x[i0] + (x[i1] - x[i0]) * w  # noqa: E731
    return lerp(root_pos), slerp(root_quat[i0], root_quat[i1], w[:, 0]), lerp(dof)


def import_bvh(path: str | os.PathLike, map_name: str = "cmu", skill: str = "walk", name: str | None = None,
               scale: float | None = None, fps: float | None = None) -> tuple[MotionClip, float]:
    """Read, retarget and validate a BVH file: (clip, fraction of angles clipped)."""
    jmap = load_map(map_name)
    return retarget(read_bvh(path), jmap, skill=skill, name=name, scale=scale, fps=fps)
