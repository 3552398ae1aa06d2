"""Built-in SYNTHETIC reference motions, generated procedurally (no mocap, no download).

These clips are made by this module from gait functions (`detach.motion.gait`): phase
curves for hips/knees, arm swing and postures, keyframes solved by two-link leg IK for
stepping up and sitting, root headings; the root position then follows from the planted
foot (`detach.motion.placement`: no foot skating, the supporting foot rests on the floor or
the prop under it) and body positions from MuJoCo forward kinematics. Ankles keep the soles
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
BUILTIN_VERSION = 3
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
            toe_down: dict[str, np.ndarray] | None = None, start_xy=(0.0, 0.0)) -> MotionClip:
    """Level the soles (plus `toe_down` rad of ankle pitch per side, e.g. at toe-off), clip to
    joint ranges, ground the root, run FK, wrap as a clip."""
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
    root, body = pose_clip_arrays(quat, dof, terrain, start_xy)
    meta = {"synthetic": True, "source": f"detach.motion.builtin v{BUILTIN_VERSION}",
            "props": terrain.to_meta(), "notes": notes}
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
    past its range."""
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
