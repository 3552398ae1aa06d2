"""Hinge angles that stay continuous over time, and what clipping them to joint ranges did.

Why: angles extracted frame by frame from rotations are only defined modulo 2 pi (and a
3-hinge joint has two Euler solutions). In a real sitting BVH a knee twist went 1.93 -> -4.36
rad between two frames (the same rotation, 2 pi apart); clipped to 0..2.79 rad it became a
straight leg, the foot dipped 0.25 m, and placing the lowest foot on the floor then lifted the
whole clip by 0.29 m. So, before clipping, every frame takes the equivalent of its angles
nearest to the previous frame's, and the first frame the one nearest to the joint's range.

Units: radians. Arrays are [F] per hinge or [F, 3] for x, y, z hinges composed as
Rx(a) Ry(b) Rz(c) (MuJoCo's nesting of three hinges, `detach.motion.rotations`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from detach.motion.rotations import euler_xyz_from_matrix

TWO_PI = 2.0 * np.pi
CLIP_TOL = 1e-3
"""rad: an angle beyond its range by less than this is not counted as clipped (float noise)."""
_GIMBAL_COS = 1e-3
"""cos(b) below which the Euler decomposition is at gimbal lock (only a +- c is defined)."""


def nearest_equivalent(angle: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """angle + 2 pi k (k integer, elementwise) closest to `reference`."""
    return angle - TWO_PI * np.round((angle - reference) / TWO_PI)


def nearest_to_range(angle: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """angle + 2 pi k closest to the interval [lo, hi] (inside it when any equivalent is):
    the equivalent nearest the range centre, clamped into the range, is the reference."""
    angle = np.asarray(angle, dtype=np.float64)
    centre = (np.asarray(lo, dtype=np.float64) + np.asarray(hi, dtype=np.float64)) / 2.0
    return nearest_equivalent(angle, np.clip(nearest_equivalent(angle, centre), lo, hi))


def continuous_track(angles: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """[F] one hinge over time: frame 0 nearest to [lo, hi], then each frame nearest to the
    previous one (np.unwrap's rule, anchored to the range instead of to the raw first value)."""
    angles = np.asarray(angles, dtype=np.float64)
    if len(angles) == 0:
        return angles.copy()
    out = np.unwrap(angles)
    return out + (nearest_to_range(out[:1], lo, hi)[0] - out[0])


def continuous_euler_xyz(mats: np.ndarray, ranges: np.ndarray) -> np.ndarray:
    """[F, 3] angles (a, b, c) with Rx(a) Ry(b) Rz(c) = mats[f], continuous over time.

    Each rotation has two Euler solutions, (a, b, c) and (a + pi, pi - b, c + pi), each
    defined modulo 2 pi per angle. Frame 0 takes the solution (and equivalents) that leaves
    its ranges [3, 2] the least; every later frame the one nearest the previous frame's
    angles (smallest largest-single-angle change). The two solutions differ by the same
    amounts between any two frames whichever one the previous frame took, so whether a frame
    switches solution is decided for all frames at once (vectorised: 12,000 frames in
    milliseconds); then each angle is unwrapped over time. At gimbal lock (|b| = pi/2) only
    a +- c is defined: c is kept from the previous frame and a follows from the rotation.
    """
    mats = np.asarray(mats, dtype=np.float64)
    ranges = np.asarray(ranges, dtype=np.float64)
    lo, hi = ranges[:, 0], ranges[:, 1]
    base = euler_xyz_from_matrix(mats, gimbal_eps=_GIMBAL_COS)
    other = base + np.array([np.pi, 0.0, np.pi])
    other[:, 1] = np.pi - base[:, 1]
    if len(base) == 0:
        return base
    first = nearest_to_range(np.stack([base[0], other[0]]), lo, hi)
    excess = (np.maximum(lo - first, 0.0) + np.maximum(first - hi, 0.0)).sum(axis=1)
    start = int(np.argmin(excess + 1e-9 * np.abs(first).sum(axis=1)))

    def step(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return np.abs(nearest_equivalent(a[1:] - b[:-1], 0.0)).max(axis=1)

    switch = step(base, other) < step(base, base)  # frame f takes the solution frame f-1 did not
    label = (start + np.concatenate([[0], np.cumsum(switch)])) % 2
    chosen = np.where(label[:, None] == 0, base, other)
    chosen[0] = first[start]
    lock = np.flatnonzero(np.cos(chosen[:, 1]) < _GIMBAL_COS)
    for f in lock[lock > 0]:
        chosen[f] = _at_gimbal_lock(mats[f], chosen[f, 1], chosen[f - 1, 2], chosen[f - 1])
    out = np.unwrap(chosen, axis=0)
    return out + (chosen[0] - out[0])


def _at_gimbal_lock(mat: np.ndarray, b: float, c: float, prev: np.ndarray) -> np.ndarray:
    """(a, b, c) with the given b and c: Rx(a) = mat Rz(-c) Ry(-b), a nearest prev[0]."""
    cb, sb, cc, sc = np.cos(b), np.sin(b), np.cos(c), np.sin(c)
    rz_inv = np.array([[cc, sc, 0.0], [-sc, cc, 0.0], [0.0, 0.0, 1.0]])
    ry_inv = np.array([[cb, 0.0, -sb], [0.0, 1.0, 0.0], [sb, 0.0, cb]])
    rx = mat @ rz_inv @ ry_inv
    a = np.arctan2(rx[2, 1], rx[1, 1])
    return np.array([nearest_equivalent(a, prev[0]), b, c])


@dataclass(frozen=True)
class ClipReport:
    """What clipping to the joint ranges did, per hinge (radians, fractions of frames)."""

    names: tuple[str, ...]
    frames_clipped: np.ndarray
    """[D] fraction of frames in which the hinge left its range (by more than 1e-3 rad)."""
    max_excess: np.ndarray
    """[D] largest amount (rad) by which the hinge left its range."""
    fraction: float
    """Fraction of all (frame, hinge) angles that were clipped."""

    def worst(self, count: int = 3) -> list[tuple[str, float, float]]:
        """Up to `count` clipped hinges as (name, fraction of frames, max excess rad), worst first."""
        order = np.lexsort((-self.max_excess, -self.frames_clipped))
        return [(self.names[i], float(self.frames_clipped[i]), float(self.max_excess[i]))
                for i in order[:count] if self.frames_clipped[i] > 0]

    def as_dict(self) -> dict[str, dict[str, float]]:
        """JSON-ready {hinge: {"frames": fraction, "max_excess_deg": degrees}} of clipped hinges."""
        return {self.names[i]: {"frames": round(float(self.frames_clipped[i]), 4),
                                "max_excess_deg": round(float(np.degrees(self.max_excess[i])), 2)}
                for i in range(len(self.names)) if self.frames_clipped[i] > 0}


def clip_to_ranges(dof: np.ndarray, ranges: np.ndarray, names: tuple[str, ...]) -> tuple[np.ndarray, ClipReport]:
    """(dof clipped to ranges [D, 2], report) for dof [F, D] in radians."""
    lo, hi = ranges[:, 0], ranges[:, 1]
    excess = np.maximum(lo - dof, 0.0) + np.maximum(dof - hi, 0.0)
    clipped = excess > CLIP_TOL
    frames = clipped.mean(axis=0) if len(dof) else np.zeros(dof.shape[1])
    report = ClipReport(tuple(names), frames, excess.max(axis=0) if len(dof) else np.zeros(dof.shape[1]),
                        float(clipped.mean()) if dof.size else 0.0)
    return np.clip(dof, lo, hi), report
