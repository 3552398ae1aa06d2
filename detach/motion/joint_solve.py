"""Hinge angles inside the joint ranges that best reproduce a 3-hinge joint's rotation.

Why: a rotation has two Euler solutions (a, b, c) and (a + pi, pi - b, c + pi), and near
|b| = pi/2 (gimbal lock; for a hip, flexion y at 90 degrees: every seated frame) float noise
and mocap jitter swing a and c far along the direction in which only a +- c matters. The
continuous tracker (`angle_continuity.continuous_euler_xyz`) follows the previous frame, so a
real sitting recording whose hips flexed past 90 degrees ran the whole seated half on the other
branch: the left hip's x and z were 2.9 and 2.4 rad out of range, clipping them threw the
thigh sideways (a flailing leg) and the clip's feet left the floor.

So every frame whose continuous angles leave a range is solved again: bounded damped
Gauss-Newton on the rotation, started from both Euler branches (each taken nearest to the
ranges, and moved along the line a -+ c = const that is free at gimbal lock) and from the
clipped track, the best kept. The residual weighs the bone's own axis
(e.g. the thigh's z: where the knee goes) four times the others, so when no in-range solution
reproduces the rotation the bone direction wins over its twist. Frames that are in range are
not touched (their rotation is already exact).
"""

from __future__ import annotations

import numpy as np

from detach.motion.angle_continuity import CLIP_TOL, nearest_to_range
from detach.motion.rotations import euler_xyz_from_matrix

_ITERATIONS = 40
EXACT_DEG = 1.0
"""A solution within this rotation error (degrees, about mocap's own noise) reproduces the joint:
its hinges count as clipped only beyond it."""
_EXACT = 0.5 * np.deg2rad(EXACT_DEG) ** 2
"""The weighted squared residual is at least 0.5 theta^2 for a rotation error theta."""


def _axis_mats(angle: np.ndarray, axis: int) -> tuple[np.ndarray, np.ndarray]:
    """(R, dR/dangle) [N, 3, 3] of rotations about x/y/z."""
    c, s = np.cos(angle), np.sin(angle)
    n = len(angle)
    r, d = np.zeros((n, 3, 3)), np.zeros((n, 3, 3))
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    r[:, axis, axis] = 1.0
    r[:, i, i], r[:, i, j], r[:, j, i], r[:, j, j] = c, -s, s, c
    d[:, i, i], d[:, i, j], d[:, j, i], d[:, j, j] = -s, -c, c, -s
    return r, d


def _residual(theta: np.ndarray, target: np.ndarray, w: np.ndarray, jacobian: bool = True):
    """(r [N, 9], J [N, 9, 3] or None): weighted columns of Rx Ry Rz - target."""
    (rx, dx), (ry, dy), (rz, dz) = (_axis_mats(theta[:, k], k) for k in range(3))
    r = ((rx @ ry @ rz - target) * w).reshape(len(theta), 9)
    if not jacobian:
        return r, None
    jac = np.stack([(dx @ ry @ rz) * w, (rx @ dy @ rz) * w, (rx @ ry @ dz) * w], axis=-1)
    return r, jac.reshape(len(theta), 9, 3)


def _solve(target: np.ndarray, start: np.ndarray, lo: np.ndarray, hi: np.ndarray,
           w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(angles [N, 3] within [lo, hi], cost [N]) by projected Levenberg-Marquardt from `start`."""
    theta = np.clip(start, lo, hi)
    r, jac = _residual(theta, target, w)
    cost = (r * r).sum(axis=1)
    mu = np.full(len(theta), 1e-3)
    eye = np.eye(3)
    for _ in range(_ITERATIONS):
        jt = np.swapaxes(jac, 1, 2)
        step = np.linalg.solve(jt @ jac + mu[:, None, None] * eye, -(jt @ r[..., None]))[..., 0]
        trial = np.clip(theta + step, lo, hi)
        r_new, _ = _residual(trial, target, w, jacobian=False)
        new_cost = (r_new * r_new).sum(axis=1)
        better = new_cost < cost
        theta = np.where(better[:, None], trial, theta)
        cost = np.where(better, new_cost, cost)
        mu = np.where(better, mu * 0.3, mu * 10.0)
        r, jac = _residual(theta, target, w)
    return theta, cost


def _excess(angles: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    return np.maximum(lo - angles, 0.0) + np.maximum(angles - hi, 0.0)


def solve_in_range(target: np.ndarray, angles: np.ndarray, ranges: np.ndarray,
                   bone_axis: int) -> tuple[np.ndarray, np.ndarray]:
    """(angles inside `ranges` [F, 3], angles for the clipping report [F, 3]).

    `target` [F, 3, 3] local rotations, `angles` [F, 3] their continuous Euler xyz angles
    (unclipped), `ranges` [3, 2], `bone_axis` the body axis along the bone (weighted most).
    The report angles are the continuous ones, except in re-solved frames: the solution where
    it reproduces the rotation (nothing was clipped), else the Euler solution nearest to the
    ranges (what had to be clipped, and by how much)."""
    lo, hi = ranges[:, 0], ranges[:, 1]
    out_of_range = (_excess(angles, lo, hi) > CLIP_TOL).any(axis=1)
    solved, report = np.clip(angles, lo, hi), angles.copy()
    idx = np.flatnonzero(out_of_range)
    if len(idx) == 0:
        return solved, report
    w = np.full(3, 0.5)
    w[bone_axis] = 1.0  # sqrt of the weights 0.25 and 1
    t = target[idx]
    base = euler_xyz_from_matrix(t)
    other = base + np.array([np.pi, 0.0, np.pi])
    other[:, 1] = np.pi - base[:, 1]
    branches = [nearest_to_range(b, lo, hi) for b in (base, other)]
    starts = [*branches, angles[idx]]
    for branch in branches:  # near gimbal lock only a -+ c matters: also start along that line
        null = np.stack([np.ones(len(idx)), np.zeros(len(idx)), -np.sign(branch[:, 1])], axis=1)
        starts += [np.clip(branch, lo, hi) + delta * null for delta in (-0.6, -0.3, 0.3, 0.6)]
    best, best_cost = None, None
    for start in starts:
        theta, cost = _solve(t, start, lo, hi, w)
        if best is None:
            best, best_cost = theta, cost
        else:
            take = cost < best_cost - 1e-12
            best = np.where(take[:, None], theta, best)
            best_cost = np.where(take, cost, best_cost)
    solved[idx] = best
    nearest = np.where((_excess(branches[0], lo, hi).sum(axis=1) <= _excess(branches[1], lo, hi).sum(axis=1))[:, None],
                       branches[0], branches[1])
    report[idx] = np.where((best_cost < _EXACT)[:, None], best, nearest)
    return solved, report
