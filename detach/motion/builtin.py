"""Built-in SYNTHETIC reference motions, generated procedurally (no mocap, no download).

These clips are made by this module from gait functions (`detach.motion.gait`): phase
curves for hips/knees, arm swing and postures, keyframes solved by two-link leg IK for
stepping up and sitting, root headings; the root position then follows from the planted
foot (`detach.motion.placement`: no foot skating, the supporting foot rests on the floor or
the prop under it; the high-box climbs also plant the hands and a knee they declare as
supports) and body positions from MuJoCo forward kinematics. Ankles keep the soles
level. Generation is deterministic (no random numbers) and takes well under a second.

They are stand-ins that give AMP a plausible, labelled motion prior so the whole pipeline runs
on a laptop; they are not human motion capture. Import real clips with `detach-motion import`.

| clip | skill | what |
| --- | --- | --- |
| idle_breathe, idle_shift | idle | standing: breathing, ankle sway, head turns / slow weight shift |
| walk_1p42, walk_1p48 | walk | straight walking at 1.42 and 1.48 m/s (task range 1.4-1.5 m/s) |
| walk_1p90 | walk | brisk walking at 1.9 m/s, longer strides (catching up with a trajectory) |
| turn_left_90, turn_right_90 | turn | stepping in place while turning 90 degrees |
| walk_turn_left, walk_turn_right | turn | walking 1.2 m/s on a curve (0.5 rad/s) |
| step_up_0p30, _0p45, _0p50 | step_up | stepping onto a 0.30 / 0.45 / 0.50 m high step (prop in meta) |
| climb_0p70, climb_0p86 | step_up | climbing onto a 0.70 / 0.86 m box (LH1's, LH3's): hands and a knee on its top |
| sit_down, sit_stand_up | sit | sitting onto a 0.45 m seat (prop in meta) / standing back up |
| sit_down_0p35, sit_stand_up_0p35 | sit | the same onto a 0.35 m seat (LH2's sofa) |
| sit_down_0p25, sit_stand_up_0p25 | sit | the same onto a 0.25 m seat (LH3's bed, 0.25 m above the loft's platform) |
| carry_walk, carry_stand | carry | both arms forward holding an imaginary box, walking 1.0 m/s / standing |
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from detach.character.body import BODY_NAMES, DOF_NAMES, FLOOR_TO_SOLE, dof_ranges
from detach.motion.clip import MotionClip, clip_from_arrays
from detach.motion.gait import flat_foot_ankle, leg_cycle, pchip, stance_twist, two_link_ik
from detach.motion.kinematics import humanoid_fk
from detach.motion.placement import Terrain, pose_clip_arrays
from detach.motion.rotations import quat_from_yaw_pitch

FPS = 30.0
BUILTIN_VERSION = 4
_IDX = {n: i for i, n in enumerate(DOF_NAMES)}
_SIDES = ("left", "right")


class _Tracks:
    """Joint-angle tracks [F, 32] addressed by hinge name (`q["left_knee_y"] = ...`)."""

    def __init__(self, frames: int) -> None:
        self.q = np.zeros((frames, len(DOF_NAMES)))

    def __setitem__(self, name: str, value) -> None:
        self.q[:, _IDX[name]] = value

    def __getitem__(self, name: str) -> np.ndarray:
        return self.q[:, _IDX[name]]


@dataclass(frozen=True)
class _Leg:
    """Sagittal leg geometry of the humanoid at the default pose, metres."""

    hip_y: float   # lateral offset of the hip joints from the pelvis origin
    hip_z: float   # hip joint height relative to the pelvis origin (negative: below)
    thigh: float
    shin: float
    ankle: float   # ankle (foot body origin) height above the sole


@lru_cache(maxsize=1)
def _leg() -> _Leg:
    rest = humanoid_fk().rest_body_pos()
    b = {n: rest[i] for i, n in enumerate(BODY_NAMES)}
    thigh = float(np.linalg.norm(b["left_shin"] - b["left_thigh"]))
    shin = float(np.linalg.norm(b["left_foot"] - b["left_shin"]))
    hip_z = float(b["left_thigh"][2] - b["pelvis"][2])
    return _Leg(float(b["left_thigh"][1]), hip_z, thigh, shin, FLOOR_TO_SOLE + hip_z - thigh - shin)


def _arms(q: _Tracks, left_y, right_y, left_elbow, right_elbow, abduct=0.12) -> None:
    """Arm posture: shoulder pitch (>0 back), elbow (<0 flexed), abduction away from the body."""
    q["left_shoulder_x"], q["right_shoulder_x"] = abduct, -np.asarray(abduct)
    q["left_shoulder_y"], q["right_shoulder_y"] = left_y, right_y
    q["left_elbow_y"], q["right_elbow_y"] = left_elbow, right_elbow


def _carry_arms(q: _Tracks, t: np.ndarray, bob: float = 0.0) -> None:
    """Both arms forward, forearms level: hands ~0.4 m in front of the chest, box-width apart."""
    wob = bob * np.sin(2 * np.pi * t * 1.7)
    _arms(q, -0.75 + wob, -0.75 + wob, -1.35 - wob, -1.35 - wob, abduct=0.05)
    q["left_shoulder_z"], q["right_shoulder_z"] = -0.15, 0.15


def _finish(name: str, skill: str, q: _Tracks, yaw: np.ndarray, pitch: np.ndarray,
            terrain: Terrain | None = None, notes: str = "",
            toe_down: dict[str, np.ndarray] | None = None, start_xy=(0.0, 0.0),
            supports: tuple[str, ...] = ()) -> MotionClip:
    """Level the soles (plus `toe_down` rad of ankle pitch per side, e.g. at toe-off), clip to
    joint ranges, ground the root (on the feet and the `supports` bodies), run FK, wrap as a
    clip."""
    terrain = terrain or Terrain()
    quat = quat_from_yaw_pitch(yaw, pitch)
    fk = humanoid_fk()
    for s in _SIDES:
        for a in "xyz":
            q[f"{s}_ankle_{a}"] = 0.0
    rel = fk.run(np.zeros((len(yaw), 3)), quat, q.q)
    for s in _SIDES:
        ax, ay = flat_foot_ankle(rel.body_mat[:, BODY_NAMES.index(f"{s}_shin")])
        q[f"{s}_ankle_x"], q[f"{s}_ankle_y"] = ax, ay + (toe_down or {}).get(s, 0.0)
    rng = dof_ranges()
    dof = np.clip(q.q, rng[:, 0], rng[:, 1])
    root, body = pose_clip_arrays(quat, dof, terrain, start_xy, supports)
    meta = {"synthetic": True, "source": f"detach.motion.builtin v{BUILTIN_VERSION}",
            "props": terrain.to_meta(), "notes": notes}
    if supports:
        meta["supports"] = list(supports)
    return clip_from_arrays(name, skill, FPS, root, quat, dof, body, meta, where=f"builtin:{name}")


# --- locomotion ------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Gait:
    duty: float = 0.56          # stance fraction of the cycle per leg
    hip_front: float = 0.52     # thigh pitch at foot strike (flexion), rad
    hip_back: float = 0.42      # thigh pitch at toe-off (extension), rad
    hip_lift: float = 0.12      # extra hip flexion in mid-swing, rad
    knee_stance: float = 0.06
    knee_load: float = 0.05
    knee_swing: float = 1.05
    knee_early: float = 0.85    # < 1: peak knee flexion before mid-swing
    toe_off: float = 0.35       # ankle plantarflexion early in swing, rad
    pitch: float = 0.04         # forward lean of the pelvis, rad
    arm_gain: float = 0.55      # shoulder pitch per hip pitch of the opposite leg
    carry: bool = False


def _gait_tracks(t: np.ndarray, period: float, g: _Gait, yaw_fn):
    """Joint tracks, yaw, pitch and toe-off ankle offsets of a gait with the given period (s)."""
    q = _Tracks(len(t))
    hips, toe = {}, {}
    leg = _leg()
    for s, off in (("left", 0.0), ("right", 0.5)):
        hip, knee, u = leg_cycle(t / period + off, g.duty, g.hip_front, g.hip_back, g.knee_stance,
                                 g.knee_load, g.knee_swing, g.hip_lift, leg.thigh + leg.shin, g.knee_early)
        q[f"{s}_hip_y"], q[f"{s}_knee_y"] = hip, knee
        q[f"{s}_hip_z"] = stance_twist(t, period, g.duty, off, yaw_fn)
        hips[s] = hip
        toe[s] = g.toe_off * np.sin(np.pi * np.clip(u / 0.5, 0.0, 1.0)) ** 2
    mid = 0.5 * (g.hip_back - g.hip_front)
    if g.carry:
        _carry_arms(q, t, bob=0.03)
    else:  # each arm swings with the opposite leg
        _arms(q, g.arm_gain * (hips["right"] - mid) + 0.05, g.arm_gain * (hips["left"] - mid) + 0.05,
              -0.25 + 0.3 * g.arm_gain * (hips["right"] - mid), -0.25 + 0.3 * g.arm_gain * (hips["left"] - mid))
    q["abdomen_y"] = 0.04
    q["abdomen_z"] = -0.12 * (hips["left"] - hips["right"]) / 2.0
    q["neck_z"] = -q["abdomen_z"]
    yaw = yaw_fn(t)
    return q, yaw, np.full(len(t), g.pitch), toe


def _stride(g: _Gait) -> float:
    """Root travel (m) over one gait cycle of straight walking (independent of the period)."""
    t = np.linspace(0.0, 1.0, 61)
    q, yaw, pitch, toe = _gait_tracks(t, 1.0, g, lambda x: np.zeros_like(np.asarray(x, dtype=np.float64)))
    clip = _finish("probe", "walk", q, yaw, pitch, toe_down=toe)
    return float(clip.root_pos[-1, 0] - clip.root_pos[0, 0])


def _walk(name: str, skill: str, speed: float, cycles: int, g: _Gait = _Gait(),
          yaw_rate: float = 0.0, notes: str = "") -> MotionClip:
    """Walking at `speed` m/s: the cycle period is set so that stride / period = speed."""
    period = _stride(g) / speed
    frames = int(round(cycles * period * FPS)) + 1
    t = np.arange(frames) / FPS
    c = (g.duty - 0.5) / 2  # phase of the middle of a double-support period

    def yaw_fn(x):  # mean rate yaw_rate, zero rate in double support (both feet planted)
        x = np.asarray(x, dtype=np.float64)
        return yaw_rate * (x - period / (4 * np.pi) * (np.sin(4 * np.pi * (x / period - c)) + np.sin(4 * np.pi * c)))

    q, yaw, pitch, toe = _gait_tracks(t, period, g, yaw_fn)
    return _finish(name, skill, q, yaw, pitch, notes=notes or f"{speed:.2f} m/s, period {period:.3f} s",
                   toe_down=toe)


def _turn_in_place(name: str, angle: float, duration: float = 3.0) -> MotionClip:
    """Stepping in place (hip/knee lift) while the heading turns by `angle` rad."""
    g = _Gait(duty=0.5, hip_front=0.0, hip_back=0.0, hip_lift=0.3, knee_stance=0.06, knee_load=0.0,
              knee_swing=0.6, knee_early=1.0, toe_off=0.0, arm_gain=0.0)
    period = 1.0
    t = np.arange(int(round(duration * FPS)) + 1) / FPS
    t0, t1 = 0.2, duration - 0.3

    def yaw_fn(x):
        u = np.clip((np.asarray(x, dtype=np.float64) - t0) / (t1 - t0), 0.0, 1.0)
        return angle * u * u * (3 - 2 * u)

    q, yaw, pitch, _ = _gait_tracks(t, period, g, yaw_fn)
    _arms(q, 0.05, 0.05, -0.3, -0.3, abduct=0.14)
    return _finish(name, "turn", q, yaw, pitch, notes=f"turn {np.degrees(angle):+.0f} deg in place")


def _idle(name: str, skill: str = "idle", duration: float = 6.0, shift: float = 0.0,
          carry: bool = False) -> MotionClip:
    """Quiet standing: ankle sway, breathing, head turns; `shift` rad of slow lateral weight shift."""
    t = np.arange(int(round(duration * FPS)) + 1) / FPS
    q = _Tracks(len(t))
    breath = np.sin(2 * np.pi * t / 4.0)
    lateral = 0.012 * np.sin(2 * np.pi * t / 6.0 + 0.7) + shift * np.sin(2 * np.pi * t / duration)
    for s in _SIDES:
        q[f"{s}_hip_x"] = lateral  # both legs lean together: the pelvis sways over the feet
        relax = np.clip(shift * 3.0 * np.sin(2 * np.pi * t / duration) * (1 if s == "right" else -1), 0.0, None)
        q[f"{s}_hip_y"], q[f"{s}_knee_y"] = -0.03 - relax / 2, 0.06 + relax
    q["abdomen_y"] = 0.03 + 0.012 * breath
    q["neck_y"] = -0.01 * breath
    q["neck_z"] = 0.2 * np.sin(2 * np.pi * t / duration)  # a slow look to the left, then right
    if carry:
        _carry_arms(q, t)
    else:
        _arms(q, 0.03 + 0.02 * breath, 0.03 + 0.02 * breath, -0.15, -0.15, abduct=0.1 + 0.015 * breath)
    pitch = 0.015 * np.sin(2 * np.pi * t / 5.0)  # sway about the ankles
    return _finish(name, skill, q, np.zeros(len(t)), pitch, notes="quiet standing")


# --- keyframed interactions (leg IK) --------------------------------------------------------


def _key_legs(keys: list[dict], t: np.ndarray) -> tuple[_Tracks, np.ndarray]:
    """Keyframes of pelvis (x, z, pitch) and ankle (x, z) per leg, world sagittal plane ->
    interpolated joint tracks. Leg angles come from two-link IK at each key, then monotone
    cubic interpolation between keys (the root itself is re-derived from the planted foot)."""
    leg = _leg()
    kt = np.array([k["t"] for k in keys])
    cols = {}
    for s in _SIDES:
        hip, knee = [], []
        for k in keys:
            px, pz, p = k["pelvis"]
            hx, hz = px - (-leg.hip_z) * np.sin(p), pz + leg.hip_z * np.cos(p)
            ax, az = k[s]
            th, kn = two_link_ik(ax - hx, az - hz, leg.thigh, leg.shin)
            hip.append(float(th) - p)
            knee.append(float(kn))
        cols[f"{s}_hip_y"], cols[f"{s}_knee_y"] = pchip(kt, hip, t), pchip(kt, knee, t)
    q = _Tracks(len(t))
    for n, v in cols.items():
        q[n] = v
    pitch = pchip(kt, [k["pelvis"][2] for k in keys], t)
    return q, pitch


def _step_up(name: str, height: float, reach: float = 0.45, lean: float = 0.0) -> MotionClip:
    """Left foot onto a step of `height` m (edge 0.28 m ahead of the ankles, the foot `reach` m
    ahead), push up, bring the right foot alongside. The step is a box prop recorded in
    meta["props"]. `reach` and `lean` (< 0: the pelvis leans back while the foot goes up) are
    there for higher steps; this recipe stays plausible (`detach.motion.plausibility`) up to
    0.50 m: from 0.60 m the lifted shin cuts the step's edge and the support foot slides (2 m/s
    at 0.70 m, LH1's box), and a one-leg step onto 0.86 m (LH3's) would need the hip 60 degrees
    past its range. Those boxes are climbed with hands and a knee instead (`_climb`)."""
    a0, top = _leg().ankle, height + _leg().ankle
    edge = 0.28
    stand = 0.93
    keys = [
        dict(t=0.0, pelvis=(0.0, stand, 0.0), left=(0.0, a0), right=(0.0, a0)),
        dict(t=0.35, pelvis=(0.0, stand, 0.02), left=(0.0, a0), right=(0.0, a0)),
        dict(t=0.75, pelvis=(0.0, stand - 0.01, 0.12 + lean), left=(edge - 0.18, top + 0.06), right=(0.0, a0)),
        dict(t=1.05, pelvis=(0.03, stand - 0.02, 0.18 + lean), left=(reach - 0.03, top + 0.03), right=(0.0, a0)),
        dict(t=1.30, pelvis=(0.06, stand - 0.03, 0.22 + lean), left=(reach, top), right=(0.0, a0)),
        dict(t=2.00, pelvis=(reach - 0.05, stand + height - 0.03, 0.15), left=(reach, top),
             right=(edge - 0.2, top + 0.06)),
        dict(t=2.45, pelvis=(reach, stand + height - 0.01, 0.08), left=(reach, top), right=(reach, top + 0.06)),
        dict(t=2.80, pelvis=(reach, stand + height, 0.03), left=(reach, top), right=(reach, top)),
        dict(t=3.20, pelvis=(reach, stand + height, 0.02), left=(reach, top), right=(reach, top)),
    ]
    t = np.arange(int(round(keys[-1]["t"] * FPS)) + 1) / FPS
    q, pitch = _key_legs(keys, t)
    _arms(q, 0.4 * (q["right_hip_y"] - q["left_hip_y"]) / 2 + 0.05,
          0.4 * (q["left_hip_y"] - q["right_hip_y"]) / 2 + 0.05, -0.35, -0.35, abduct=0.14)
    q["abdomen_y"] = 0.05
    terrain = Terrain([((edge + 0.6, 0.0, height / 2), (0.6, 0.6, height / 2))])
    return _finish(name, "step_up", q, np.zeros(len(t)), pitch, terrain, notes=f"step {height:.2f} m")


# --- climbing a high box: hands and a knee on it ------------------------------------------


_HAND_R, _SHIN_R = 0.04, 0.05  # hand sphere and shin capsule radii (`detach.character.body`)
_CLIMB_ABDUCT = 0.12           # shoulder abduction while climbing: hands beside the thighs


@dataclass(frozen=True)
class _Arm:
    """Sagittal arm geometry at the default pose, metres."""

    torso_z: float        # torso origin above the pelvis origin
    shoulder_x: float     # shoulder joint in the torso frame (x forward, z up)
    shoulder_z: float
    upper: float          # shoulder -> elbow
    lower: float          # elbow -> hand centre


@lru_cache(maxsize=1)
def _arm() -> _Arm:
    rest = humanoid_fk().rest_body_pos()
    b = {n: rest[i] for i, n in enumerate(BODY_NAMES)}
    sh = b["left_upper_arm"] - b["torso"]
    return _Arm(float(b["torso"][2] - b["pelvis"][2]), float(sh[0]), float(sh[2]),
                float(np.linalg.norm(b["left_lower_arm"] - b["left_upper_arm"])),
                float(np.linalg.norm(b["left_hand"] - b["left_lower_arm"])))


def _rot_xz(x, z, angle):
    """(x, z) rotated by a pitch `angle` about +Y (> 0 tips +Z towards +X)."""
    c, s = np.cos(angle), np.sin(angle)
    return x * c + z * s, -x * s + z * c


def _hip_xz(pelvis: np.ndarray) -> np.ndarray:
    """[F, 2] hip joint (x, z) of pelvis rows (x, z, pitch)."""
    dx, dz = _rot_xz(0.0, _leg().hip_z, pelvis[:, 2])
    return pelvis[:, :2] + np.stack([dx, dz], axis=1)


def _shoulder_xz(pelvis: np.ndarray, abdomen: np.ndarray) -> np.ndarray:
    """[F, 2] shoulder joint (x, z) for pelvis rows (x, z, pitch) and abdomen pitch."""
    arm = _arm()
    tx, tz = _rot_xz(0.0, arm.torso_z, pelvis[:, 2])
    sx, sz = _rot_xz(arm.shoulder_x, arm.shoulder_z, pelvis[:, 2] + abdomen)
    return pelvis[:, :2] + np.stack([tx + sx, tz + sz], axis=1)


def _arm_ik(shoulder: np.ndarray, torso_pitch: np.ndarray, hand: np.ndarray,
            abduct: float) -> tuple[np.ndarray, np.ndarray]:
    """Shoulder pitch and elbow that put the hand centre at world (x, z) `hand` [F, 2] (its
    lateral place follows from the fixed abduction). The shoulder's x hinge comes before y, so
    the arm moves in the torso's x-z plane tilted by `abduct`; the elbow points back."""
    dx, dz = (hand - shoulder).T
    c, s = np.cos(torso_pitch), np.sin(torso_pitch)
    u, w = c * dx - s * dz, (s * dx + c * dz) / np.cos(abduct)
    upper, elbow = two_link_ik(-u, w, _arm().upper, _arm().lower)  # mirrored: the elbow behind
    return -upper, -elbow


def _keys(rows: list[tuple], t: np.ndarray) -> np.ndarray:
    """Rows (time, v1, v2, ...) -> [F, V] monotone cubic interpolation at times t."""
    a = np.asarray(rows, dtype=np.float64)
    return pchip(a[:, 0], a[:, 1:], t)


@dataclass(frozen=True)
class _Box:
    """A box to climb: its top height and its extent in x and y (m); its near face is at x = face."""

    height: float
    size: float
    face: float = 0.45


def _ankle_for_knee(hip: np.ndarray, knee_z: float, flex: float) -> tuple[float, float]:
    """Ankle (x, z) that puts the knee at height `knee_z` in front of `hip`, flexed by `flex` rad."""
    leg = _leg()
    up = np.arcsin(np.clip((knee_z - hip[1]) / leg.thigh, -1.0, 1.0))
    knee = hip + leg.thigh * np.array([np.cos(up), np.sin(up)])
    shin = flex - np.pi / 2 - up  # world pitch of the shin: the thigh's plus the flexion
    ankle = knee - leg.shin * np.array([np.sin(shin), np.cos(shin)])
    return float(ankle[0]), float(ankle[1])


def _kneel(box: _Box) -> tuple[np.ndarray, np.ndarray, tuple[float, float, float]]:
    """Left knee resting on the top (its shin flat on it), the hip 30 degrees up the thigh
    behind it (knee flexion 150 of 160 degrees) and the pelvis (x, z, pitch) over that hip."""
    leg = _leg()
    knee = np.array([box.face + 0.22, box.height + _SHIN_R])
    a = np.radians(30.0)
    hip = knee + leg.thigh * np.array([-np.cos(a), np.sin(a)])
    pitch = 0.2
    kx, kz = _rot_xz(0.0, -leg.hip_z, pitch)
    return knee, hip, (hip[0] + kx, hip[1] + kz, pitch)


def _climb_body(box: _Box) -> tuple[list[tuple], list[tuple]]:
    """Pelvis (time, x, z, pitch) and abdomen (time, pitch) keys: lean to the box, back a little
    while the knee goes up, kneel (bent over the hands), rise over the feet on the top."""
    top, face = box.height, box.face
    _, _, kneel = _kneel(box)
    bend = 0.45 - 1.25 * (top - 0.70)    # less lean towards a higher top
    lift_z = 0.86 + 0.25 * (top - 0.70)  # pelvis height as the knee goes over the edge
    hover = (kneel[0], kneel[1] + 0.02, kneel[2])  # the knee 2 cm over its place
    step = face + _STEP_IN
    pelvis = [(0.0, 0.0, 0.93, 0.0), (0.2, 0.0, 0.93, 0.02), (0.9, 0.0, 0.86, bend),
              (1.3, -0.05, 0.86, bend + 0.05), (1.6, -0.05, lift_z, bend), (2.2, *hover), (2.45, *kneel),
              (3.4, *kneel), (4.2, face - 0.10, top + 0.55, 0.40), (4.8, step - 0.05, top + 0.82, 0.20),
              (5.3, step - 0.01, top + 0.92, 0.05), (5.8, step, top + 0.93, 0.02)]
    abdomen = [(0.0, 0.03), (0.2, 0.05), (0.9, bend), (1.3, 0.55), (1.6, 0.6), (2.2, 1.0), (3.4, 1.0),
               (4.2, 0.5), (4.8, 0.15), (5.3, 0.05), (5.8, 0.03)]
    return pelvis, abdomen


_STEP_IN = 0.10
"""Both ankles end this far (m) behind the box's near face, on its top."""


def _climb_plan(box: _Box) -> dict[str, list[tuple]]:
    """Keyframes (time, ...) of a climb onto `box`, world sagittal plane: pelvis (x, z, pitch),
    abdomen pitch, ankle (x, z) per leg and hand centres (x, z).

    Hands go onto the top and the left knee is raised over its edge; a push on the hands lifts
    the right foot off the floor as the left knee lands on the top (shin flat on it); the left
    foot swings forward under the hip onto the top, the body rises over it (hands off) and the
    right leg, once the hip is high enough for its knee to pass over the edge, steps up beside.
    A contact is a fixed world point held between equal keys."""
    leg, top, face = _leg(), box.height, box.face
    a0, step = leg.ankle, face + _STEP_IN
    knee, hip, _ = _kneel(box)
    pelvis, abdomen = _climb_body(box)
    hip_at = lambda t: _hip_xz(_keys(pelvis, np.array([t])))[0]
    hang = lambda t: (t, *(hip_at(t) + np.array([-0.18, -0.79])))  # the right leg hangs at the face
    shin_flat = (knee[0] - leg.shin, knee[1])
    left = [(0.0, 0.0, a0), (0.9, 0.0, a0), (1.25, -0.02, 0.30),
            (1.6, *_ankle_for_knee(hip_at(1.6), top + 0.16, np.radians(140.0))),
            (1.95, *_ankle_for_knee(hip_at(1.95), top + 0.15, np.radians(150.0))),
            (2.2, shin_flat[0], shin_flat[1] + 0.02), (2.45, *shin_flat), (2.7, *shin_flat),
            (3.0, hip[0], top + 0.11), (3.15, step, top + 0.10), (3.35, step, top + a0), (5.8, step, top + a0)]
    right = [(0.0, 0.0, a0), (1.7, 0.0, a0), *[hang(k) for k in (2.45, 3.4, 3.6, 3.8, 4.0)],
             (4.3, face - 0.2, top - 0.05), (4.55, face - 0.18, top + 0.16), (4.8, step, top + 0.14),
             (5.05, step, top + a0), (5.8, step, top + a0)]
    hand = (face + 0.10, top + _HAND_R)
    hands = [(0.0, "rest"), (0.2, "rest"), (0.6, hand[0], hand[1] + 0.08), (0.9, *hand), (3.6, *hand),
             (3.9, "lift"), (4.7, "rest"), (5.8, "rest")]
    return dict(pelvis=pelvis, abdomen=abdomen, left=left, right=right, hands=hands)


def _hand_keys(rows: list[tuple], pelvis: np.ndarray, abdomen: np.ndarray, kt: np.ndarray) -> list[tuple]:
    """Hand key rows with "rest" (hanging beside the body) / "lift" (off the top, in front)
    resolved against the shoulder at that key's time."""
    out = []
    for row in rows:
        if isinstance(row[1], str):
            i = int(np.argmin(np.abs(kt - row[0])))
            sh = _shoulder_xz(pelvis[i:i + 1], abdomen[i:i + 1])[0]
            off = (0.02, -0.48) if row[1] == "rest" else (0.15, -0.42)
            row = (row[0], sh[0] + off[0], sh[1] + off[1])
        out.append(row)
    return out


def _climb(name: str, box: _Box) -> MotionClip:
    """Climb onto a box too high to step onto (`_step_up`): hands and the left knee on its top
    carry the weight in between (declared as supports, `detach.motion.plausibility`)."""
    plan = _climb_plan(box)
    end = plan["pelvis"][-1][0]
    t = np.arange(int(round(end * FPS)) + 1) / FPS
    pelvis, abdomen = _keys(plan["pelvis"], t), _keys(plan["abdomen"], t)[:, 0]
    q = _Tracks(len(t))
    hip = _hip_xz(pelvis)
    for s in _SIDES:
        th, kn = two_link_ik(*(_keys(plan[s], t) - hip).T, _leg().thigh, _leg().shin)
        q[f"{s}_hip_y"], q[f"{s}_knee_y"] = th - pelvis[:, 2], kn
    hand = _keys(_hand_keys(plan["hands"], pelvis, abdomen, t), t)
    shoulder_y, elbow = _arm_ik(_shoulder_xz(pelvis, abdomen), pelvis[:, 2] + abdomen, hand, _CLIMB_ABDUCT)
    _arms(q, shoulder_y, shoulder_y, elbow, elbow, abduct=_CLIMB_ABDUCT)
    q["abdomen_y"] = abdomen
    q["neck_y"] = -0.5 * abdomen  # keep looking ahead while bent over the box
    half = box.size / 2
    terrain = Terrain([((box.face + half, 0.0, box.height / 2), (half, half, box.height / 2))])
    return _finish(name, "step_up", q, np.zeros(len(t)), pelvis[:, 2], terrain,
                   notes=f"climb onto a {box.height:.2f} m box: hands and a knee on it",
                   start_xy=(pelvis[0, 0], 0.0), supports=("left_hand", "right_hand", "left_shin"))


SEAT_HEIGHT = 0.45
"""The seat of the `sit_down` / `sit_stand_up` clips (LH1's and the sit task's chair)."""


def _sit_keys(down: bool, seat: float) -> list[dict]:
    """Pelvis keys (x, z, pitch) of sitting onto a `seat` m high seat behind the feet: the
    pelvis goes back and down through the same two intermediate poses, scaled to the seat."""
    a0 = _leg().ankle
    feet = dict(left=(0.0, a0), right=(0.0, a0))
    seat_z = seat + 0.10  # pelvis 0.1 m above the seat (the sit target); capsule r = 0.09
    d = SEAT_HEIGHT - seat  # > 0: a lower seat, reached further back, lower and more bent
    back = 0.40 + 0.5 * d
    standing = [(0.0, 0.93, 0.0), (0.0, 0.93, 0.02)]
    lowering = [(-0.10, 0.80 - 0.5 * d, 0.45 + 0.5 * d), (-0.32 - 0.4 * d, 0.62 - d, 0.40 + 0.5 * d),
                (-back, seat_z + 0.01, 0.18)]
    seated = [(-back, seat_z, 0.12), (-back, seat_z, 0.10)]
    if down:
        poses, times = standing + lowering + seated, [0.0, 0.4, 1.0, 1.6, 1.9, 2.3, 3.2]
    else:
        rise = [(-back + 0.06, seat_z + 0.02, 0.55 + 0.5 * d), (-0.12, 0.76 - 0.5 * d, 0.48 + 0.5 * d),
                (0.0, 0.91, 0.10)]
        poses = seated + rise + standing[::-1]
        times = [0.0, 0.4, 1.0, 1.6, 2.2, 2.6, 3.0]
    return [dict(t=tt, pelvis=p, **feet) for tt, p in zip(times, poses)]


def _sit(name: str, down: bool, seat: float = SEAT_HEIGHT) -> MotionClip:
    """Sit down onto (or stand up from) a `seat` m high seat behind the character; feet stay
    planted."""
    keys = _sit_keys(down, seat)
    t = np.arange(int(round(keys[-1]["t"] * FPS)) + 1) / FPS
    q, pitch = _key_legs(keys, t)
    flex = np.clip(-q["left_hip_y"] / 1.5, 0.0, 1.0)  # 0 standing .. 1 seated
    shoulder, elbow = 0.05 - 0.45 * flex, -0.15 - 0.75 * flex  # hands move onto the lap
    _arms(q, shoulder, shoulder, elbow, elbow, abduct=0.12 + 0.08 * flex)
    q["abdomen_y"] = 0.04 + 0.1 * flex
    q["neck_y"] = -0.1 * flex
    # seat 0.5 m deep whose front edge is 0.1 m ahead of the seated pelvis
    x_seat = keys[-1]["pelvis"][0] if down else keys[0]["pelvis"][0]
    terrain = Terrain([((x_seat - 0.15, 0.0, seat / 2), (0.25, 0.24, seat / 2))])
    return _finish(name, "sit", q, np.zeros(len(t)), pitch, terrain, start_xy=(keys[0]["pelvis"][0], 0.0),
                   notes=f"seat {seat:.2f} m high behind the character")


_RECIPES = (
    lambda: _idle("idle_breathe"),
    lambda: _idle("idle_shift", shift=0.05, duration=8.0),
    lambda: _walk("walk_1p42", "walk", 1.42, cycles=4),
    lambda: _walk("walk_1p48", "walk", 1.48, cycles=4),
    lambda: _walk("walk_1p90", "walk", 1.9, cycles=5, g=_Gait(hip_front=0.66, hip_back=0.52, pitch=0.07),
                  notes="1.90 m/s brisk walk"),
    lambda: _turn_in_place("turn_left_90", np.pi / 2),
    lambda: _turn_in_place("turn_right_90", -np.pi / 2),
    lambda: _walk("walk_turn_left", "turn", 1.2, cycles=4, yaw_rate=0.5, notes="1.2 m/s, +0.5 rad/s"),
    lambda: _walk("walk_turn_right", "turn", 1.2, cycles=4, yaw_rate=-0.5, notes="1.2 m/s, -0.5 rad/s"),
    lambda: _step_up("step_up_0p30", 0.30),
    lambda: _step_up("step_up_0p45", 0.45),
    lambda: _step_up("step_up_0p50", 0.50),                        # the climb task's platform
    lambda: _climb("climb_0p70", _Box(0.70, 0.6)),                 # LH1's box
    lambda: _climb("climb_0p86", _Box(0.86, 0.8)),                 # LH3's static step box
    lambda: _sit("sit_down", down=True),
    lambda: _sit("sit_stand_up", down=False),
    lambda: _sit("sit_down_0p35", down=True, seat=0.35),          # LH2's sofa
    lambda: _sit("sit_stand_up_0p35", down=False, seat=0.35),
    lambda: _sit("sit_down_0p25", down=True, seat=0.25),          # LH3's bed, above the loft's platform
    lambda: _sit("sit_stand_up_0p25", down=False, seat=0.25),
    lambda: _walk("carry_walk", "carry", 1.0, cycles=4, g=_Gait(hip_front=0.34, hip_back=0.26, pitch=0.02, carry=True),
                  notes="carrying an imaginary box, 1.0 m/s"),
    lambda: _idle("carry_stand", skill="carry", duration=4.0, carry=True),
)


@lru_cache(maxsize=1)
def _builtin() -> tuple[MotionClip, ...]:
    return tuple(recipe() for recipe in _RECIPES)


def builtin_clips() -> list[MotionClip]:
    """The synthetic clips (generated once per process, then cached; treat as read-only)."""
    return list(_builtin())


def default_motion_lib(device="cpu", skill_weights: dict[str, float] | None = None):
    """A MotionLib of the built-in clips on `device` (skill weights uniform unless given)."""
    from detach.motion.library import MotionLib

    return MotionLib(builtin_clips(), device=device, skill_weights=skill_weights)
