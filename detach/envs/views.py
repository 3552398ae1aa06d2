"""What people read of an env: its start-up summary and one env's state for drawing.

`describe(env)` is the table printed when an env is built (scene, plan, observation groups,
actions, reward terms); `snapshot(env, i)` is env i's bodies, objects, subtask, target and
Follow path now, which recordings and task markers draw (`detach.eval.task_markers`). Both
read an `LHEnv` (passed untyped: this module sits below it).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from detach.character.body import BODY_NAMES


@dataclass(frozen=True)
class EnvSnapshot:
    """One env's state for recording and drawing (world frame; quaternions wxyz)."""

    bodies: tuple[str, ...]
    body_pos: np.ndarray
    body_quat: np.ndarray
    objects: list[dict]
    """Dynamic objects: {"name", "pos", "quat"}."""
    subtask: int
    skill: str
    target: np.ndarray | None = None
    """[3] the current subtask's target (what the task markers draw)."""
    path: np.ndarray | None = None
    """[K, 2] the XY path of the current subtask where its skill follows one (Follow), else None."""
    path_index: float | None = None
    """Where the moving reference point is on `path` (fractional vertex index)."""


def describe(env) -> str:
    """Start-up summary of an `LHEnv`: scene, plan, observation groups and reward terms."""
    sources = env.cfg.task.sample_target_from
    lines = [f"LHEnv '{env.cfg.task.name}': {env.num_envs} envs, character {env.character.name}, "
             f"{len(env.scene.objects)} objects, dt {env.dt:.4f} s x {env.max_episode_length} steps, "
             f"{type(env.backend).__name__} on {env.device}",
             "Plan: " + " -> ".join(f"{s.skill}({sources[s.index]})" for s in env.plan),
             env.obs_spec.describe(), f"Actions: {env.num_actions}", env.rewards.table()]
    return "\n".join(lines)


def snapshot(env, i: int = 0) -> EnvSnapshot:
    """Env i's character bodies, dynamic objects, current subtask, its target and (Follow)
    its path with the reference point's place on it."""
    st, plan, tracker = env.state, env.plan, env.tracker
    objects = [{"name": env.scene.objects[o].name, "pos": st.obj_pos[i, o].tolist(),
                "quat": st.obj_quat[i, o].tolist()} for o in env.scene.dynamic]
    sub = int(tracker.subtask[i])
    ctx = getattr(env, "_ctx", None)
    target = None if ctx is None else ctx.target[i].detach().cpu().numpy().astype(np.float64)
    path = index = None
    if bool(tracker.follows_path[int(tracker.tensors.skill[min(sub, len(plan) - 1)])]):
        path, index = _path_of(env, i)
    return EnvSnapshot(BODY_NAMES, st.body_pos[i].cpu().numpy(), st.body_quat[i].cpu().numpy(), objects,
                       sub, plan[min(sub, len(plan) - 1)].skill, target, path, index)


def _path_of(env, i: int) -> tuple[np.ndarray, float]:
    """Env i's reference path without its padding (repeats of the last vertex) and where its
    reference point is now, as a fractional vertex index."""
    traj = env.services.trajectory
    verts = traj.verts[i].detach().cpu().numpy().astype(np.float64)
    moved = np.any(np.abs(verts - verts[-1]) > 1e-9, axis=1)
    last = int(np.nonzero(moved)[0][-1]) + 1 if moved.any() else 0
    verts = verts[: last + 1]
    t = float(env.steps[i] - traj.t0[i]) * env.dt
    return verts, float(np.clip(t / float(traj.vertex_dt[i]), 0.0, len(verts) - 1))
