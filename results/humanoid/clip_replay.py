"""Replay a built-in clip through the humanoid's PD drives, open-loop, and measure how well the
drives reproduce it: with the root pinned to the clip (only the hinges' tracking) or free
under the balance assist's righting torque (does the body travel as the clip does?).

    python results/humanoid/clip_replay.py [CLIP] [--armature 0.01 0.08] [--lead 1 2 3]

CLIP defaults to walk_1p42. `--lead K`: the PD target of control step k is the clip's frame
k + K (K = 1 is the next frame, what `detach.train.clip_clone` fits). `--armature` replaces the
body's hinge armature (`detach.character.body.ARMATURE`). Prints, per setting, the hinges'
RMS error against the clip (rad; the knees' beside it), the control steps before a fall (the
pelvis below 0.5 m), the root's mean horizontal speed and the drives' mean |tau * qdot| (W).
"""

from __future__ import annotations

import argparse

import mujoco
import numpy as np

from detach import DOF_NAMES, MotionClip, build_character_model, builtin_clips

CONTROL_HZ = 30.0
ASSIST = (500.0, 15.0)
"""Righting torque (N m/rad) and damping (N m s/rad), `train.balance_assist`'s roll/pitch rule."""


def clip_at(clip: MotionClip, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Root position, root quaternion (wxyz) and hinge angles at time t, linearly interpolated."""
    f = t * clip.fps
    i = int(np.clip(np.floor(f), 0, clip.num_frames - 2))
    w = f - i
    q0, q1 = clip.root_quat[i], clip.root_quat[i + 1]
    q = (1 - w) * q0 + w * (q1 if np.dot(q0, q1) >= 0 else -q1)
    return ((1 - w) * clip.root_pos[i] + w * clip.root_pos[i + 1], q / np.linalg.norm(q),
            (1 - w) * clip.dof_pos[i] + w * clip.dof_pos[i + 1])


def righting_torque(m: mujoco.MjModel, d: mujoco.MjData, pelvis: int) -> np.ndarray:
    up = d.xmat[pelvis].reshape(3, 3)[:, 2]
    axis = np.cross(up, (0.0, 0.0, 1.0))
    sin = np.linalg.norm(axis)
    spin = d.cvel[pelvis][:3].copy()
    spin[2] = 0.0
    return ASSIST[0] * axis * (min(np.arctan2(sin, up[2]), 0.6) / max(sin, 1e-6)) - ASSIST[1] * spin


def replay(clip: MotionClip, armature: float, lead: int, pinned: bool) -> dict[str, float]:
    m = build_character_model("humanoid")
    m.dof_armature[6:] = armature
    d = mujoco.MjData(m)
    dt, pelvis = m.opt.timestep, m.body("pelvis").id
    substeps = int(round(1.0 / (CONTROL_HZ * dt)))
    d.qpos[:3], d.qpos[3:7], d.qpos[7:] = clip_at(clip, 0.0)
    p1, _, q1 = clip_at(clip, dt)
    d.qvel[:3], d.qvel[6:] = (p1 - d.qpos[:3]) / dt, (q1 - d.qpos[7:]) / dt
    mujoco.mj_forward(m, d)
    start, errors, power = d.qpos[:2].copy(), [], []
    for k in range(int((clip.num_frames - 3) / clip.fps * CONTROL_HZ)):
        d.ctrl[:] = clip_at(clip, (k + lead) / CONTROL_HZ)[2]
        for s in range(substeps):
            t = (k * substeps + s + 1) * dt
            if pinned:
                p, q, _ = clip_at(clip, t)
                d.qpos[:3], d.qpos[3:7] = p, q
                d.qvel[:3], d.qvel[3:6] = (clip_at(clip, t + dt)[0] - p) / dt, 0.0
            else:
                d.xfrc_applied[pelvis, 3:] = righting_torque(m, d, pelvis)
            mujoco.mj_step(m, d)
        errors.append(d.qpos[7:] - clip_at(clip, (k + 1) / CONTROL_HZ)[2])
        power.append(float(np.abs(d.actuator_force * d.qvel[6:]).sum()))
        if not pinned and d.qpos[2] < 0.5:
            break
    e = np.array(errors)
    knees = [i for i, n in enumerate(DOF_NAMES) if n in ("right_knee_y", "left_knee_y")]
    steps = len(errors)
    return {"rms": float(np.sqrt((e ** 2).mean())), "knee_rms": float(np.sqrt((e[:, knees] ** 2).mean())),
            "steps": steps, "speed": float(np.linalg.norm(d.qpos[:2] - start) / (steps / CONTROL_HZ)),
            "power": float(np.mean(power))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("clip", nargs="?", default="walk_1p42")
    ap.add_argument("--armature", type=float, nargs="+", default=[0.01, 0.08])
    ap.add_argument("--lead", type=int, nargs="+", default=[1, 2, 3])
    args = ap.parse_args()
    clip = {c.name: c for c in builtin_clips()}[args.clip]
    print(f"{args.clip}: {clip.num_frames} frames, {clip.num_frames / clip.fps:.1f} s; the clip's own root speed "
          f"{np.linalg.norm(clip.root_pos[-1, :2] - clip.root_pos[0, :2]) / (clip.num_frames / clip.fps):.2f} m/s")
    print("| root | armature | lead | hinge RMS (rad) | knees | control steps | speed (m/s) | power (W) |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    for pinned in (True, False):
        for arm in args.armature:
            for lead in args.lead:
                r = replay(clip, arm, lead, pinned)
                print(f"| {'pinned' if pinned else 'assisted'} | {arm:.2f} | {lead} | {r['rms']:.3f} | "
                      f"{r['knee_rms']:.3f} | {r['steps']} | {r['speed']:.2f} | {r['power']:.0f} |")


if __name__ == "__main__":
    main()
