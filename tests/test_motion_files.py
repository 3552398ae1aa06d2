"""Synthetic mocap files for the import tests: one human skeleton written as BVH in several
common naming families (CMU, Mixamo, Hips/Chest, Daz, Biovision), Y up or Z up, any unit, and
as a CMU ASF/AMC pair. Real datasets cannot be downloaded here; these files keep the
properties that matter (names, hierarchy, units, axes, rest T-pose, Euler channels).

The human (Y up, facing +Z, its left is +X, centimetres): hips 95 cm above the floor, a
36 cm spine, T-pose arms (upper arm 28, forearm 25), legs of 42 + 41 cm with the toe 6 cm down
and 14 cm forward of the ankle. A motion gives per frame: the root position (cm, Y-up axes),
the left knee's bend (deg about +X, the left axis) and the arms lowered by `arms` deg (so the
default 90 makes them hang like ours).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

# (family name of our semantic joint) for each family; None = not in that family
FAMILIES: dict[str, dict[str, str]] = {
    "cmu": dict(hips="Hips", spine=["LowerBack", "Spine", "Spine1"], neck=["Neck", "Neck1"], head="Head",
                l_collar="LeftShoulder", l_upper_arm="LeftArm", l_forearm="LeftForeArm", l_hand="LeftHand",
                r_collar="RightShoulder", r_upper_arm="RightArm", r_forearm="RightForeArm", r_hand="RightHand",
                l_hip_joint="LHipJoint", l_thigh="LeftUpLeg", l_shin="LeftLeg", l_foot="LeftFoot", l_toe="LeftToeBase",
                r_hip_joint="RHipJoint", r_thigh="RightUpLeg", r_shin="RightLeg", r_foot="RightFoot",
                r_toe="RightToeBase"),
    "mixamo": dict(hips="Hips", spine=["Spine", "Spine1", "Spine2"], neck=["Neck"], head="Head",
                   l_collar="LeftShoulder", l_upper_arm="LeftArm", l_forearm="LeftForeArm", l_hand="LeftHand",
                   r_collar="RightShoulder", r_upper_arm="RightArm", r_forearm="RightForeArm", r_hand="RightHand",
                   l_thigh="LeftUpLeg", l_shin="LeftLeg", l_foot="LeftFoot", l_toe="LeftToeBase",
                   r_thigh="RightUpLeg", r_shin="RightLeg", r_foot="RightFoot", r_toe="RightToeBase"),
    "hips_chest": dict(hips="Hips", spine=["Chest", "Chest2"], neck=["Neck"], head="Head",
                       l_collar="LeftCollar", l_upper_arm="LeftShoulder", l_forearm="LeftElbow", l_hand="LeftWrist",
                       r_collar="RightCollar", r_upper_arm="RightShoulder", r_forearm="RightElbow",
                       r_hand="RightWrist", l_thigh="LeftHip", l_shin="LeftKnee", l_foot="LeftAnkle", l_toe="LeftToe",
                       r_thigh="RightHip", r_shin="RightKnee", r_foot="RightAnkle", r_toe="RightToe"),
    "cmu_daz": dict(hips="hip", spine=["abdomen", "chest"], neck=["neck"], head="head",
                    l_collar="lCollar", l_upper_arm="lShldr", l_forearm="lForeArm", l_hand="lHand",
                    r_collar="rCollar", r_upper_arm="rShldr", r_forearm="rForeArm", r_hand="rHand",
                    l_hip_joint="lButtock", l_thigh="lThigh", l_shin="lShin", l_foot="lFoot",
                    r_hip_joint="rButtock", r_thigh="rThigh", r_shin="rShin", r_foot="rFoot"),
    "biovision": dict(hips="Hips", spine=["Chest"], neck=["Neck"], head="Head",
                      l_collar="LeftCollar", l_upper_arm="LeftUpArm", l_forearm="LeftLowArm", l_hand="LeftHand",
                      r_collar="RightCollar", r_upper_arm="RightUpArm", r_forearm="RightLowArm", r_hand="RightHand",
                      l_thigh="LeftUpLeg", l_shin="LeftLowLeg", l_foot="LeftFoot",
                      r_thigh="RightUpLeg", r_shin="RightLowLeg", r_foot="RightFoot"),
}

SPINE_CM = 36.0
HIPS_CM = 95.0
THIGH_CM, SHIN_CM = 42.0, 41.0
UPPER_ARM_CM, FOREARM_CM = 28.0, 25.0


@dataclass
class Joint:
    name: str
    parent: int
    offset: np.ndarray
    """cm, Y-up axes, in the parent's rest frame."""


def skeleton(family: str, prefix: str = "") -> list[Joint]:
    """The human in one naming family, joints in depth-first order (index 0 = root)."""
    names = FAMILIES[family]
    joints: list[Joint] = []

    def add(name: str, parent: int, offset) -> int:
        joints.append(Joint(prefix + name, parent, np.asarray(offset, dtype=np.float64)))
        return len(joints) - 1

    root = add(names["hips"], -1, (0, 0, 0))
    spine = names["spine"]
    top = root  # the first spine joint 6 cm above the hips, the last at SPINE_CM
    for k, n in enumerate(spine):
        rise = SPINE_CM if len(spine) == 1 else 6.0 if k == 0 else (SPINE_CM - 6.0) / (len(spine) - 1)
        top = add(n, top, (0, rise, 0))
    neck = top
    for n in names["neck"]:
        neck = add(n, neck, (0, 12.0 / len(names["neck"]), 0))
    add(names["head"], neck, (0, 10, 0))
    for side, sign in (("l", 1.0), ("r", -1.0)):
        collar = add(names[f"{side}_collar"], top, (sign * 3, 0, 0))
        upper = add(names[f"{side}_upper_arm"], collar, (sign * 14, 0, 0))
        fore = add(names[f"{side}_forearm"], upper, (sign * UPPER_ARM_CM, 0, 0))
        add(names[f"{side}_hand"], fore, (sign * FOREARM_CM, 0, 0))
    for side, sign in (("l", 1.0), ("r", -1.0)):
        parent = root
        if f"{side}_hip_joint" in names:
            parent = add(names[f"{side}_hip_joint"], root, (0, 0, 0))
        thigh = add(names[f"{side}_thigh"], parent, (sign * 9, -6, 0))
        shin = add(names[f"{side}_shin"], thigh, (0, -THIGH_CM, 0))
        foot = add(names[f"{side}_foot"], shin, (0, -SHIN_CM, 0))
        if f"{side}_toe" in names:
            add(names[f"{side}_toe"], foot, (0, -6, 14))
    return joints


Y_UP_TO_Z_UP = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])
"""(x, y, z) -> (x, -z, y): the same human Z up, facing -Y, left still +X."""


def write_bvh(path: Path, family: str, root_cm: np.ndarray, knee_deg: np.ndarray, arms_deg: float = 90.0,
              unit: float = 1.0, z_up: bool = False, prefix: str = "", fps: float = 30.0,
              knee_branch: np.ndarray | None = None, channels: dict[str, np.ndarray] | None = None) -> Path:
    """Write the human in `family` doing the motion; lengths in `unit` cm (100: metres).

    Channels are "Zrotation Xrotation Yrotation" (R = Rz Rx Ry). `knee_branch[f]` True writes
    frame f's knee bend on the other Euler branch (Z 180, X 180 - bend, Y 180: the same
    rotation), as real exporters sometimes do. `channels[semantic joint]` ([F, 3] Z, X, Y deg,
    Y-up files only) sets any other joint, e.g. {"r_shin": ...}."""
    joints = skeleton(family, prefix)
    names = FAMILIES[family]
    convert = Y_UP_TO_Z_UP if z_up else np.eye(3)
    frames = len(root_cm)
    values = np.zeros((frames, len(joints), 3))  # Z, X, Y degrees per joint
    knee = [j.name for j in joints].index(prefix + names["l_shin"])
    for side, sign in ((names["l_upper_arm"], -1.0), (names["r_upper_arm"], 1.0)):
        k = [j.name for j in joints].index(prefix + side)
        if z_up:  # a rotation about the old +Z is one about the new -Y
            values[:, k, 2] = -sign * arms_deg
        else:
            values[:, k, 0] = sign * arms_deg
    values[:, knee, 1] = knee_deg
    for semantic, zxy in (channels or {}).items():
        values[:, [j.name for j in joints].index(prefix + names[semantic])] = zxy
    if knee_branch is not None:
        values[knee_branch, knee] = np.stack([np.full(knee_branch.sum(), 180.0), 180.0 - knee_deg[knee_branch],
                                              np.full(knee_branch.sum(), 180.0)], axis=-1)
    lines = ["HIERARCHY"]
    children = {i: [c for c, j in enumerate(joints) if j.parent == i] for i in range(len(joints))}

    def emit(i: int, depth: int) -> None:
        pad = "  " * depth
        j = joints[i]
        lines.append(f"{pad}{'ROOT' if j.parent < 0 else 'JOINT'} {j.name}")
        lines.append(f"{pad}{{")
        off = convert @ j.offset / unit
        lines.append(f"{pad}  OFFSET {off[0]:.6f} {off[1]:.6f} {off[2]:.6f}")
        pos = "Xposition Yposition Zposition " if j.parent < 0 else ""
        lines.append(f"{pad}  CHANNELS {6 if j.parent < 0 else 3} {pos}Zrotation Xrotation Yrotation")
        for c in children[i]:
            emit(c, depth + 1)
        if not children[i]:
            lines.extend([f"{pad}  End Site", f"{pad}  {{", f"{pad}    OFFSET 0 {-3 / unit:.6f} 0", f"{pad}  }}"])
        lines.append(f"{pad}}}")

    emit(0, 0)
    lines += ["MOTION", f"Frames: {frames}", f"Frame Time: {1.0 / fps:.7f}"]
    root = (np.asarray(root_cm, dtype=np.float64) + [0, HIPS_CM, 0]) @ convert.T / unit
    for f in range(frames):
        row = [*root[f]]
        for j in range(len(joints)):  # a rotation about +X (the knee) is unchanged by the axis change
            row += [*values[f, j]]
        lines.append(" ".join(f"{v:.6f}" for v in row))
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")
    return path


# ---- CMU ASF/AMC -------------------------------------------------------------------------------

ASF_UNIT_M = 0.0254 / 0.45
"""Metres per ASF length unit with `:units length 0.45` (CMU)."""

_ASF_BONES = (  # name, parent, direction (Y up, facing +Z, left +X), length cm, dofs
    ("lhipjoint", "root", (9, -6, 0), None, ""),
    ("lfemur", "lhipjoint", (0, -1, 0), THIGH_CM, "rx ry rz"),
    ("ltibia", "lfemur", (0, -1, 0), SHIN_CM, "rx"),
    ("lfoot", "ltibia", (0, -6, 14), None, "rx rz"),
    ("rhipjoint", "root", (-9, -6, 0), None, ""),
    ("rfemur", "rhipjoint", (0, -1, 0), THIGH_CM, "rx ry rz"),
    ("rtibia", "rfemur", (0, -1, 0), SHIN_CM, "rx"),
    ("rfoot", "rtibia", (0, -6, 14), None, "rx rz"),
    ("lowerback", "root", (0, 1, 0), 12.0, "rx ry rz"),
    ("upperback", "lowerback", (0, 1, 0), 12.0, "rx ry rz"),
    ("thorax", "upperback", (0, 1, 0), 12.0, "rx ry rz"),
    ("lowerneck", "thorax", (0, 1, 0), 6.0, "rx ry rz"),
    ("upperneck", "lowerneck", (0, 1, 0), 6.0, "rx ry rz"),
    ("head", "upperneck", (0, 1, 0), 10.0, "rx ry rz"),
    ("lclavicle", "thorax", (1, 0, 0), 17.0, "ry rz"),
    ("lhumerus", "lclavicle", (1, 0, 0), UPPER_ARM_CM, "rx ry rz"),
    ("lradius", "lhumerus", (1, 0, 0), FOREARM_CM, "rx"),
    ("lwrist", "lradius", (1, 0, 0), 8.0, "ry"),
    ("rclavicle", "thorax", (-1, 0, 0), 17.0, "ry rz"),
    ("rhumerus", "rclavicle", (-1, 0, 0), UPPER_ARM_CM, "rx ry rz"),
    ("rradius", "rhumerus", (-1, 0, 0), FOREARM_CM, "rx"),
    ("rwrist", "rradius", (-1, 0, 0), 8.0, "ry"),
)


def write_asf(path: Path, axis_deg: dict[str, tuple[float, float, float]] | None = None) -> Path:
    """A CMU-style ASF of the human (`:units length 0.45`, degrees). `axis_deg` sets bones'
    `axis` (default 0 0 0)."""
    axis_deg = axis_deg or {}
    lines = ["# synthetic CMU-style skeleton", ":version 1.10", ":name VICON", ":units", "  mass 1.0",
             "  length 0.45", "  angle deg", ":documentation", "  test file", ":root", "   order TX TY TZ RX RY RZ",
             "   axis XYZ", "   position 0 0 0", "   orientation 0 0 0", ":bonedata"]
    for i, (name, _parent, direction, length_cm, dofs) in enumerate(_ASF_BONES, 1):
        d = np.asarray(direction, dtype=np.float64)
        length = float(np.linalg.norm(d)) if length_cm is None else length_cm
        d = d / np.linalg.norm(d)
        ax = axis_deg.get(name, (0.0, 0.0, 0.0))
        lines += ["  begin", f"     id {i}", f"     name {name}", f"     direction {d[0]:.6f} {d[1]:.6f} {d[2]:.6f}",
                  f"     length {length / 100 / ASF_UNIT_M:.6f}", f"     axis {ax[0]:g} {ax[1]:g} {ax[2]:g}   XYZ"]
        if dofs:
            lines.append(f"    dof {dofs}")
            lines.append("    limits " + "\n           ".join("(-180.0 180.0)" for _ in dofs.split()))
        lines.append("  end")
    lines += [":hierarchy", "  begin"]
    children: dict[str, list[str]] = {}
    for name, parent, *_ in _ASF_BONES:
        children.setdefault(parent, []).append(name)
    lines += [f"    {parent} {' '.join(kids)}" for parent, kids in children.items()]
    lines += ["  end"]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")
    return path


def write_amc(path: Path, root_cm: np.ndarray, knee_deg: np.ndarray, arms_deg: float = 90.0,
              extra: dict[str, np.ndarray] | None = None) -> Path:
    """An AMC of the motion for `write_asf`'s skeleton (degrees; root in ASF units).
    `extra[bone]` [F, n] overrides that bone's values."""
    extra = extra or {}
    root = (np.asarray(root_cm, dtype=np.float64) + [0, HIPS_CM, 0]) / 100 / ASF_UNIT_M
    lines = ["#!OML:ASF test.asf", ":FULLY-SPECIFIED", ":DEGREES"]
    for f in range(len(root)):
        lines.append(str(f + 1))
        lines.append("root " + " ".join(f"{v:.6f}" for v in (*root[f], 0.0, 0.0, 0.0)))
        for name, _parent, _d, _l, dofs in _ASF_BONES:
            if not dofs:
                continue
            vals = np.zeros(len(dofs.split()))
            if name == "ltibia":
                vals[0] = knee_deg[f]
            if name in ("lhumerus", "rhumerus"):
                vals[2] = (-arms_deg if name == "lhumerus" else arms_deg)
            if name in extra:
                vals = np.asarray(extra[name][f], dtype=np.float64)
            lines.append(f"{name} " + " ".join(f"{v:.6f}" for v in vals))
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")
    return path


def write_cmu_bvh_like_asf(path: Path, root_cm: np.ndarray, knee_deg: np.ndarray, arms_deg: float = 90.0) -> Path:
    """The ASF human as a CMU-style BVH in ASF units (joints at bone starts, CMU BVH names), for
    comparing the ASF/AMC path with the BVH path."""
    names = {"root": "Hips", "lhipjoint": "LHipJoint", "lfemur": "LeftUpLeg", "ltibia": "LeftLeg",
             "lfoot": "LeftFoot", "rhipjoint": "RHipJoint", "rfemur": "RightUpLeg", "rtibia": "RightLeg",
             "rfoot": "RightFoot", "lowerback": "LowerBack", "upperback": "Spine", "thorax": "Spine1",
             "lowerneck": "Neck", "upperneck": "Neck1", "head": "Head", "lclavicle": "LeftShoulder",
             "lhumerus": "LeftArm", "lradius": "LeftForeArm", "lwrist": "LeftHand", "rclavicle": "RightShoulder",
             "rhumerus": "RightArm", "rradius": "RightForeArm", "rwrist": "RightHand"}
    vec = {"root": np.zeros(3)}
    for name, _parent, direction, length_cm, _dofs in _ASF_BONES:
        d = np.asarray(direction, dtype=np.float64)
        length = float(np.linalg.norm(d)) if length_cm is None else length_cm
        vec[name] = d / np.linalg.norm(d) * length / 100 / ASF_UNIT_M
    parent_of = {name: parent for name, parent, *_ in _ASF_BONES}
    order = ["root", *[b[0] for b in _ASF_BONES]]
    children = {n: [c for c in order if parent_of.get(c) == n] for n in order}
    lines = ["HIERARCHY"]

    def emit(n: str, depth: int) -> None:
        pad = "  " * depth
        off = np.zeros(3) if n == "root" or parent_of[n] == "root" else vec[parent_of[n]]
        lines.append(f"{pad}{'ROOT' if n == 'root' else 'JOINT'} {names[n]}")
        lines.append(f"{pad}{{")
        lines.append(f"{pad}  OFFSET {off[0]:.6f} {off[1]:.6f} {off[2]:.6f}")
        pos = "Xposition Yposition Zposition " if n == "root" else ""
        lines.append(f"{pad}  CHANNELS {6 if n == 'root' else 3} {pos}Zrotation Xrotation Yrotation")
        for c in children[n]:
            emit(c, depth + 1)
        if not children[n]:
            v = vec[n]
            lines.extend([f"{pad}  End Site", f"{pad}  {{", f"{pad}    OFFSET {v[0]:.6f} {v[1]:.6f} {v[2]:.6f}",
                          f"{pad}  }}"])
        lines.append(f"{pad}}}")

    emit("root", 0)
    root = (np.asarray(root_cm, dtype=np.float64) + [0, HIPS_CM, 0]) / 100 / ASF_UNIT_M
    lines += ["MOTION", f"Frames: {len(root)}", "Frame Time: 0.0083333"]
    for f in range(len(root)):
        row = [*root[f]]
        for n in order:
            z, x, y = 0.0, 0.0, 0.0
            if n == "ltibia":
                x = knee_deg[f]
            if n == "lhumerus":
                z = -arms_deg
            if n == "rhumerus":
                z = arms_deg
            row += [z, x, y]
        lines.append(" ".join(f"{v:.6f}" for v in row))
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")
    return path


def test_skeletons_are_well_formed():
    """Every family has the same leg and arm lengths (what scale: auto measures)."""
    for family in FAMILIES:
        joints = skeleton(family)
        names = [j.name for j in joints]
        assert len(set(names)) == len(names), family
        pos = np.zeros((len(joints), 3))
        for i, j in enumerate(joints):
            pos[i] = (pos[j.parent] if j.parent >= 0 else 0) + j.offset
        f = FAMILIES[family]
        leg = np.linalg.norm(pos[names.index(f["l_foot"])] - pos[names.index(f["l_thigh"])])
        assert leg == np.float64(THIGH_CM + SHIN_CM), family
