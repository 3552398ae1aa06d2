"""Retarget a source motion (BVH, or ASF/AMC read into the same form) to our humanoid through
a joint map (`detach.motion.joint_map`; format in docs/MOCAP.md, "Joint maps").

Method, per frame (all rotations expressed in our axes via C, i.e. R' = C R C^T):
1. world rotation G_j of every source joint (product of local rotations; the rest pose is
   all-identity);
2. world rotation of each of our bodies: R_body = G_src * Q, where Q is the rest-pose
   correction: identity, or with `aim` the smallest rotation taking our rest bone direction
   (body -> its child body) onto the source rest bone direction (src joint -> aim joint). So a
   T-pose arm maps onto our hanging arm; bodies of unmapped joints follow their parent;
3. our joint's local rotation L = R_parent^-1 R_body, turned into hinge angles: for joints
   whose hinges are x, y, z in this order (MuJoCo nests them as Rx Ry Rz), Euler xyz; for
   hinge-like joints (elbows, and knees whose x/z ranges are tiny) the twist about y;
4. angles are made continuous over time (`detach.motion.angle_continuity`: each frame takes the
   2 pi-equivalent / Euler solution nearest the previous frame, the first frame the one nearest
   the joint range), then clipped to dof_ranges(); clipping is reported per hinge in
   `meta["clipping"]` and as the overall fraction;
root position = C * root position * scale; `scale: auto` matches the source's rest hip-to-ankle
length to ours, `axes: auto` reads up (root -> neck joint) and left (right hip -> left hip) off
the rest pose. The source rate 1 / frame time is snapped to a whole number when within 0.01%
(files store 0.0333333 s); the clip is resampled to `fps` if given, body positions come from
MuJoCo FK, then the whole clip is shifted so that its first root position is above the origin
and the lowest foot point over the clip touches z = 0.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from detach.character.body import BODY_NAMES, DOF_NAMES, JOINT_GROUPS, dof_ranges
from detach.motion.angle_continuity import CLIP_TOL, clip_to_ranges, continuous_euler_xyz, continuous_track
from detach.motion.bvh_import import BvhData, read_bvh
from detach.motion.clip import MotionClip, clip_from_arrays
from detach.motion.joint_map import (MAPS_DIR, BoundMap, JointMap, RetargetError, available_maps, bind,
                                     child_bodies, choose_map, load_map)
from detach.motion.joint_solve import solve_in_range
from detach.motion.kinematics import humanoid_fk
from detach.motion.plausibility import FLOAT_CLEARANCE
from detach.motion.retarget_check import bone_axis, bone_errors, make_check
from detach.motion.rotations import (matrix_from_euler_xyz, matrix_to_quat, min_rotation, quat_conj, quat_continuous,
                                     quat_from_axis_angle, quat_mul, quat_rotate, quat_to_matrix, slerp, twist_angle)

__all__ = ["MAPS_DIR", "RetargetError", "available_maps", "import_bvh", "load_map", "retarget", "source_axes",
           "source_scale"]

_HINGE_LIKE_RANGE = 0.2  # rad: a 3-DoF joint whose other two hinges span less than this is a hinge
_LEG = ("left_hip", "left_knee", "left_ankle")
"""Our joints whose source joints give the hip-to-ankle length (`scale: auto`)."""


def _bound(bvh: BvhData, jmap: JointMap | None) -> BoundMap:
    return choose_map(bvh.names, bvh.path) if jmap is None else bind(jmap, bvh.names, bvh.path)


def source_axes(bvh: BvhData, bound: BoundMap) -> np.ndarray:
    """C (our_vector = C @ source_vector): the map's axes, or read off the rest pose when the
    map says `auto`: up = root -> the neck's source joint, left = right hip -> left hip, both
    snapped to the nearest signed file axis, forward = left x up."""
    if bound.map.axes is not None:
        return bound.map.axes
    need = {"neck": "up", "left_hip": "left", "right_hip": "left"}
    absent = [ours for ours in need if ours not in bound.joints]
    if absent:
        raise RetargetError(f"{bvh.path}: map '{bound.map.name}' has axes: auto but no {', '.join(absent)} joint "
                            "to read the rest pose from; give axes explicitly")
    rest = bvh.rest_positions()
    up = rest[bvh.index(bound.joints["neck"][0])] - rest[bvh.index(bound.root)]
    left = rest[bvh.index(bound.joints["left_hip"][0])] - rest[bvh.index(bound.joints["right_hip"][0])]
    up_axis, left_axis = _snap(up), _snap(left)
    if up_axis is None or left_axis is None or abs(float(up_axis @ left_axis)) > 0.5:
        raise RetargetError(f"{bvh.path}: cannot read the axes off the rest pose (up {np.round(up, 3).tolist()}, "
                            f"left {np.round(left, 3).tolist()}); give axes in the map")
    return np.stack((np.cross(left_axis, up_axis), left_axis, up_axis))


def _snap(v: np.ndarray) -> np.ndarray | None:
    """The signed unit file axis nearest to v (None for a zero vector)."""
    n = float(np.linalg.norm(v))
    if n < 1e-12:
        return None
    k = int(np.argmax(np.abs(v)))
    out = np.zeros(3)
    out[k] = np.sign(v[k])
    return out


def source_scale(bvh: BvhData, bound: BoundMap) -> float:
    """Metres per source unit: the map's, or (`scale: auto`) our rest hip-to-ankle length over
    the source's (hip -> knee -> ankle joints of the left leg)."""
    if bound.map.scale is not None:
        return bound.map.scale
    absent = [ours for ours in _LEG if ours not in bound.joints]
    if absent:
        raise RetargetError(f"{bvh.path}: map '{bound.map.name}' has scale: auto but no {', '.join(absent)} joint "
                            "to measure the leg; give scale explicitly")
    rest = bvh.rest_positions()
    theirs = [rest[bvh.index(bound.joints[j][0])] for j in _LEG]
    ours_rest = humanoid_fk().rest_body_pos()
    ours = [ours_rest[BODY_NAMES.index(b)] for b in ("left_thigh", "left_shin", "left_foot")]
    length = np.linalg.norm(theirs[1] - theirs[0]) + np.linalg.norm(theirs[2] - theirs[1])
    if not length > 1e-9:
        raise RetargetError(f"{bvh.path}: scale: auto: the source leg has zero length; give scale explicitly")
    return float((np.linalg.norm(ours[1] - ours[0]) + np.linalg.norm(ours[2] - ours[1])) / length)


def retarget(bvh: BvhData, jmap: JointMap | None = None, skill: str = "walk", name: str | None = None,
             scale: float | None = None, fps: float | None = None) -> tuple[MotionClip, float]:
    """(clip, fraction of hinge angles clipped to their ranges) for a parsed source motion.

    `jmap` None picks the shipped map that fits the file's joint names (`choose_map`); `scale`
    overrides the map's metres per source unit. Per-hinge clipping is in `meta["clipping"]`.
    """
    where = bvh.path
    bound = _bound(bvh, jmap)
    scale = source_scale(bvh, bound) if scale is None else float(scale)
    if not scale > 0:
        raise RetargetError(f"{where}: scale must be > 0, got {scale}")
    c = source_axes(bvh, bound)
    g_file = bvh.global_quat()  # [F, J, 4] file axes
    g = np.concatenate((g_file[..., :1], g_file[..., 1:] @ c.T), axis=-1)  # C R C^T as a quaternion
    rest = bvh.rest_positions() @ c.T
    ours_rest = humanoid_fk().rest_body_pos()
    bidx = {n: i for i, n in enumerate(BODY_NAMES)}

    f = bvh.num_frames
    world = {"pelvis": g[:, bvh.index(bound.root)]}  # target world rotations of our bodies
    achieved = {"pelvis": world["pelvis"]}  # what our angles (inside the ranges) give
    body_group = {grp.body: grp for grp in JOINT_GROUPS}
    m = humanoid_fk().model
    angles: dict[str, np.ndarray] = {}
    report_angles: dict[str, np.ndarray] = {}
    rest_fix: dict[str, np.ndarray] = {}
    for body in BODY_NAMES[1:]:  # tree order: a parent's world rotation is known first
        parent = m.body(m.body_parentid[m.body(body).id]).name
        grp = body_group.get(body)
        if grp is not None and grp.name in bound.joints:
            src, aim = bound.joints[grp.name]
            q = np.array([1.0, 0.0, 0.0, 0.0])
            if aim:
                ours = ours_rest[bidx[child_bodies(body)[0]]] - ours_rest[bidx[body]]
                theirs = rest[bvh.index(aim)] - rest[bvh.index(src)]
                q = min_rotation(ours, theirs)
            rest_fix[grp.name] = q
            world[body] = quat_mul(g[:, bvh.index(src)], np.broadcast_to(q, (f, 4)))
        else:
            world[body] = achieved[parent]
        if grp is None:
            achieved[body] = achieved[parent]
            continue
        # relative to what the parent achieved: a parent held by its ranges is made up for below
        local = quat_mul(quat_conj(achieved[parent]), world[body])
        angles[grp.name], report_angles[grp.name] = _angles(local, grp)
        achieved[body] = quat_mul(achieved[parent], _joint_quat(angles[grp.name], grp))
    dof = np.concatenate([angles[grp.name] for grp in JOINT_GROUPS], axis=1)  # DOF_NAMES order
    report_dof = np.concatenate([report_angles[grp.name] for grp in JOINT_GROUPS], axis=1)
    _, report = clip_to_ranges(report_dof, dof_ranges(), tuple(DOF_NAMES))
    dof = np.clip(dof, dof_ranges()[:, 0], dof_ranges()[:, 1])
    root_quat = quat_continuous(world["pelvis"])
    root_pos = (_joint_path(bvh, bvh.index(bound.root), g_file) @ c.T) * scale
    fk_src = humanoid_fk().run(root_pos, root_quat, dof)
    errors = bone_errors(bvh, bound, c, g, rest_fix, fk_src.body_mat)
    src_fps = _snap_fps(1.0 / bvh.frame_time)
    resampled = fps is not None and abs(fps - src_fps) > 1e-9
    if resampled:
        root_pos, root_quat, dof = _resample(root_pos, root_quat, dof, src_fps, fps)
    out_fps = src_fps if fps is None else float(fps)
    fk = humanoid_fk().run(root_pos, root_quat, dof) if resampled else fk_src
    shift = np.array([-root_pos[0, 0], -root_pos[0, 1], -fk.foot_bottom.min()])
    grounded = float(((fk.foot_bottom + shift[2]).min(axis=1) <= FLOAT_CLEARANCE).mean())
    check = make_check(errors, _clipped_frames(report_dof), report.fraction, grounded)
    clip = clip_from_arrays(name or Path(bvh.path).stem, skill, out_fps, root_pos + shift, root_quat, dof,
                            fk.body_pos + shift, where=where,
                            meta={"source": str(bvh.path), "map": bound.map.name, "scale": scale,
                                  "source_fps": src_fps, "clipped_fraction": report.fraction,
                                  "clipping": report.as_dict(), "check": check.as_meta(), "synthetic": False})
    return clip, report.fraction


def _joint_path(bvh: BvhData, joint: int, global_quat: np.ndarray) -> np.ndarray:
    """[F, 3] world positions (file units and axes) of `joint`: the file root's positions, plus
    the offsets down the chain (per frame where the joint has position channels) when the
    map's root is below the file's ROOT (e.g. `Hips` under a `Reference` root)."""
    chain = []
    while joint > 0:
        chain.append(joint)
        joint = bvh.parents[joint]
    pos = bvh.root_pos.copy()
    for j in reversed(chain):
        offset = bvh.joint_pos.get(j, np.broadcast_to(bvh.offsets[j], pos.shape))
        pos += quat_rotate(global_quat[:, bvh.parents[j]], offset)
    return pos


def _angles(local: np.ndarray, grp) -> tuple[np.ndarray, np.ndarray]:
    """([F, len(axes)] hinge angles of one joint group from its local rotations [F, 4], the
    angles for the clipping report): hinge-like joints take the continuous twist (clipped
    later); 3-hinge joints the continuous Euler angles, re-solved inside the ranges where they
    leave them (`joint_solve`)."""
    if len(grp.axes) == 1:
        (lo, hi), = grp.ranges
        track = continuous_track(twist_angle(local, "xyz".index(grp.axes)), lo, hi)[:, None]
        return track, track
    spans = [hi - lo for lo, hi in grp.ranges]
    narrow = [i for i, s in enumerate(spans) if s < _HINGE_LIKE_RANGE]
    if grp.axes == "xyz" and len(narrow) == 2:
        out = np.zeros((len(local), 3))
        k = ({0, 1, 2} - set(narrow)).pop()
        out[:, k] = continuous_track(twist_angle(local, k), *grp.ranges[k])
        return out, out
    if grp.axes != "xyz":
        raise RetargetError(f"joint group {grp.name}: unsupported hinge axes {grp.axes!r}")
    ranges = np.asarray(grp.ranges, dtype=np.float64)
    mats = quat_to_matrix(local)
    return solve_in_range(mats, continuous_euler_xyz(mats, ranges), ranges, bone_axis(grp.body))


def _joint_quat(angles: np.ndarray, grp) -> np.ndarray:
    """[F, 4] local rotation of a joint group at its angles [F, len(axes)] (clipped to its ranges)."""
    ranges = np.asarray(grp.ranges, dtype=np.float64)
    a = np.clip(angles, ranges[:, 0], ranges[:, 1])
    if len(grp.axes) == 1:
        axis = np.zeros(3)
        axis["xyz".index(grp.axes)] = 1.0
        return quat_from_axis_angle(axis, a[:, 0])
    return matrix_to_quat(matrix_from_euler_xyz(a[:, 0], a[:, 1], a[:, 2]))


def _clipped_frames(report_dof: np.ndarray) -> dict[str, float]:
    """Share of frames in which any hinge of each joint group leaves its range ([F, 32] angles
    before clipping, as reported)."""
    ranges = dof_ranges()
    out = np.maximum(ranges[:, 0] - report_dof, 0.0) + np.maximum(report_dof - ranges[:, 1], 0.0) > CLIP_TOL
    shares, k = {}, 0
    for grp in JOINT_GROUPS:
        shares[grp.name] = float(out[:, k:k + len(grp.axes)].any(axis=1).mean()) if len(out) else 0.0
        k += len(grp.axes)
    return shares


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


def import_bvh(path: str | os.PathLike, map_name: str = "auto", skill: str = "walk", name: str | None = None,
               scale: float | None = None, fps: float | None = None) -> tuple[MotionClip, float]:
    """Read, retarget and validate a BVH file: (clip, fraction of angles clipped).
    `map_name` "auto" picks the shipped map that fits the file's joint names."""
    jmap = None if map_name == "auto" else load_map(map_name)
    return retarget(read_bvh(path), jmap, skill=skill, name=name, scale=scale, fps=fps)
