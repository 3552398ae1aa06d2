"""Procedural motion primitives as pure functions of phase or time (radians, metres, seconds).

Conventions of our humanoid (see `detach.character.body`): hinge `*_y` angles are rotations
about the body's +Y (the character's left). A positive hip/knee/shoulder `y` swings the limb
backwards (hip y < 0 is flexion, knee y > 0 is flexion, elbow y < 0 is flexion); a positive
ankle `y` points the toes down. Sagittal-plane geometry below uses (x forward, z up).
"""

from __future__ import annotations

import numpy as np


def smoothstep(u: np.ndarray) -> np.ndarray:
    """0 -> 1 with zero slope at both ends; u is clipped to [0, 1]."""
    u = np.clip(u, 0.0, 1.0)
    return u * u * (3.0 - 2.0 * u)


def ramp(t: np.ndarray, t0: float, t1: float) -> np.ndarray:
    """Smooth 0 -> 1 transition between times t0 and t1."""
    return smoothstep((np.asarray(t) - t0) / max(t1 - t0, 1e-9))


def hermite(p0: float, p1: float, m0: float, m1: float, u: np.ndarray) -> np.ndarray:
    """Cubic Hermite segment from p0 to p1 with end slopes m0, m1 (per unit of u in [0, 1])."""
    u2, u3 = u * u, u * u * u
    return ((2 * u3 - 3 * u2 + 1) * p0 + (u3 - 2 * u2 + u) * m0
            + (-2 * u3 + 3 * u2) * p1 + (u3 - u2) * m1)


def leg_cycle(phase: np.ndarray, duty: float, hip_front: float, hip_back: float, knee_stance: float,
              knee_load: float, knee_swing: float, hip_lift: float = 0.0,
              leg_length: float = 0.83, knee_early: float = 0.7) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Hip and knee pitch of one leg over a gait cycle; phase 0 = foot strike.

    Stance (phase < duty): the thigh goes from -hip_front (forward) to +hip_back such that the
    foot's horizontal offset from the hip, leg_length * sin(pitch), changes linearly: the
    planted foot sweeps back at a constant rate, so the pelvis moves at a near-constant speed.
    Swing: a cubic Hermite brings the thigh forward again with the stance rates at both ends
    (C1 continuous). The knee has a small loading flexion in stance and a large flexion early
    in swing (foot clearance), sin^2 bumps with zero slope at the joins; `hip_lift` adds hip
    flexion in mid-swing (stepping in place lifts the foot with it). knee_early < 1 moves the
    knee's peak flexion before mid-swing (0.7: at u ~ 0.37), 1 keeps it at mid-swing.
    Returns (hip_y, knee_y, swing_u) where swing_u in [0, 1] is the swing progress (0 in stance).
    """
    phase = np.mod(phase, 1.0)
    stance = phase < duty
    s = np.where(stance, phase / duty, 0.0)
    u = np.where(stance, 0.0, (phase - duty) / (1.0 - duty))
    xf, xb = leg_length * np.sin(hip_front), leg_length * np.sin(hip_back)
    hip_st = np.arcsin(np.clip((-xf + (xf + xb) * s) / leg_length, -1.0, 1.0))
    rate = lambda a: (xf + xb) / (leg_length * np.cos(a)) / duty  # noqa: E731 - d pitch / d phase
    m0, m1 = rate(hip_back) * (1.0 - duty), rate(hip_front) * (1.0 - duty)
    hip_sw = hermite(hip_back, -hip_front, m0, m1, u) - hip_lift * np.sin(np.pi * u) ** 2
    hip = np.where(stance, hip_st, hip_sw)
    early = np.sin(np.pi * np.clip(u, 0.0, 1.0) ** knee_early) ** 2
    knee = knee_stance + np.where(stance, knee_load * np.sin(np.pi * s) ** 2, knee_swing * early)
    return hip, knee, u


def stance_twist(t: np.ndarray, period: float, duty: float, offset: float, yaw_fn) -> np.ndarray:
    """Hip twist (`*_hip_z`) that keeps a planted foot's heading while the pelvis turns.

    A leg with phase t / period + offset is in stance while frac(phase) < duty; its foot keeps
    the heading the pelvis has at mid-stance (twist = yaw(t_mid) - yaw(t)); in swing the twist
    moves smoothly to the value it needs at the next foot strike. yaw_fn: t [s] -> yaw [rad].
    """
    ph = np.asarray(t, dtype=np.float64) / period + offset
    n = np.floor(ph)
    frac = ph - n
    t_of = lambda p: (p - offset) * period  # noqa: E731 - phase -> time
    mid = yaw_fn(t_of(n + duty / 2))
    stance_val = mid - yaw_fn(np.asarray(t, dtype=np.float64))
    v_end = mid - yaw_fn(t_of(n + duty))
    v_next = yaw_fn(t_of(n + 1 + duty / 2)) - yaw_fn(t_of(n + 1))
    swing_val = v_end + (v_next - v_end) * smoothstep((frac - duty) / (1.0 - duty))
    return np.where(frac < duty, stance_val, swing_val)


def two_link_ik(dx: np.ndarray, dz: np.ndarray, l1: float, l2: float) -> tuple[np.ndarray, np.ndarray]:
    """Sagittal leg IK: thigh pitch (world, about +Y) and knee flexion that put the ankle at
    (dx forward, dz up) from the hip joint; the knee bends forward (human-like).

    Targets out of reach are pulled in to 0.9999 of the leg length (leg straight).
    """
    dx, dz = np.asarray(dx, dtype=np.float64), np.asarray(dz, dtype=np.float64)
    d = np.clip(np.hypot(dx, dz), abs(l1 - l2) + 1e-6, (l1 + l2) * 0.9999)
    knee = np.arccos(np.clip((d * d - l1 * l1 - l2 * l2) / (2 * l1 * l2), -1.0, 1.0))
    line = np.arctan2(-dx, -dz)  # pitch of the hip->ankle line (0 = straight down)
    beta = np.arccos(np.clip((l1 * l1 + d * d - l2 * l2) / (2 * l1 * d), -1.0, 1.0))
    return line - beta, knee


def flat_foot_ankle(shin_mat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Ankle (x, y) hinge angles that keep the sole level, given the shin's world rotation.

    With the ankle's z hinge at 0 the foot rotation is S Rx(a) Ry(b); its +Z must be world up:
    Rx(a) Ry(b) e_z = S^T e_z, i.e. (sin b, -sin a cos b, cos a cos b) = u.
    """
    u = shin_mat[..., 2, :]  # S^T e_z = third row of S
    b = np.arcsin(np.clip(u[..., 0], -1.0, 1.0))
    a = np.arctan2(-u[..., 1], u[..., 2])
    return a, b


def pchip(key_t: np.ndarray, key_v: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Monotone piecewise-cubic interpolation (Fritsch-Carlson) of keys [K] or [K, D] at times t.

    Keyframed motions (step up, sit) use it: smooth velocities through the keys, no overshoot
    (a joint never leaves the range spanned by its neighbouring keys), constant outside.
    """
    key_t = np.asarray(key_t, dtype=np.float64)
    key_v = np.asarray(key_v, dtype=np.float64)
    squeeze = key_v.ndim == 1
    v = key_v[:, None] if squeeze else key_v
    h = np.diff(key_t)[:, None]
    delta = np.diff(v, axis=0) / h
    m = np.zeros_like(v)
    same = delta[:-1] * delta[1:] > 0
    w1 = 2 * h[1:] + h[:-1]
    w2 = h[1:] + 2 * h[:-1]
    with np.errstate(divide="ignore", invalid="ignore"):
        harm = (w1 + w2) / (w1 / delta[:-1] + w2 / delta[1:])
    m[1:-1] = np.where(same, harm, 0.0)
    t = np.clip(np.asarray(t, dtype=np.float64), key_t[0], key_t[-1])
    k = np.clip(np.searchsorted(key_t, t, side="right") - 1, 0, len(key_t) - 2)
    hk = h[k]
    u = ((t - key_t[k])[:, None]) / hk
    out = hermite(v[k], v[k + 1], m[k] * hk, m[k + 1] * hk, u)
    return out[:, 0] if squeeze else out
