"""Running evaluation episodes of a policy in an env, and what they leave in the run log.

Unbiased trial counting: stopping at "the first `trials` finished episodes" over parallel envs
would favour short (often failed) episodes, so every env gets a fixed quota of episodes and
only those count. Env 0's first episode is recorded frame by frame to `/episode/bodies`.
"""

from __future__ import annotations

from typing import Any, Callable

import numpy as np
import torch
from tensordict import TensorDict
from tqdm import tqdm

from detach.config_schema import RunConfig
from detach.eval.report import TrialOutcome, summarize
from detach.runs.mcap_log import RunLogWriter

Policy = Callable[[TensorDict], torch.Tensor]


def body_geoms(model, body_ids: np.ndarray, body_names: tuple[str, ...]) -> list[dict[str, Any]]:
    """The character's collision primitives in body frames (for drawing it)."""
    import mujoco

    kinds = {int(mujoco.mjtGeom.mjGEOM_CAPSULE): "capsule",
             int(mujoco.mjtGeom.mjGEOM_SPHERE): "sphere", int(mujoco.mjtGeom.mjGEOM_BOX): "box"}
    index = {int(b): name for b, name in zip(body_ids, body_names)}
    out = []
    for g in range(model.ngeom):
        body = int(model.geom_bodyid[g])
        kind = kinds.get(int(model.geom_type[g]))
        if body in index and kind is not None:
            out.append({"body": index[body], "type": kind,
                        "size": [float(v) for v in model.geom_size[g]],
                        "pos": [float(v) for v in model.geom_pos[g]],
                        "quat": [float(v) for v in model.geom_quat[g]]})
    return out


def record_scene(env, cfg: RunConfig) -> dict[str, Any]:
    """The /scene message of a run (see detach.runs.mcap_log)."""
    from detach.envs.humanoid import BODY_NAMES
    from scene_builder.assets import default_assets_root
    from scene_builder.scene import yaw_quat

    root = default_assets_root().resolve()
    objects = []
    for obj, spec in zip(env.scene.objects, cfg.task.scene):
        objects.append({"name": obj.name, "category": obj.category,
                        "mesh": str(root / spec.category / spec.model_id / "mesh.obj"),
                        "pos": [float(v) for v in obj.pos], "quat": [float(v) for v in yaw_quat(obj.z_rot)],
                        "bbox": [float(v) for v in obj.bbox], "static": bool(obj.static)})
    targets = []
    for i, sub in enumerate(env.plan):
        target = sub.fixed_target
        if target is None and sub.obj >= 0 and sub.skill in ("climb", "sit"):
            obj = env.scene.objects[sub.obj]
            target = obj.to_world(obj.tar_sit_local if sub.skill == "sit" else obj.tar_climb_local)
        if target is not None:
            targets.append({"subtask": i, "skill": sub.skill,
                            "pos": [float(v) for v in np.asarray(target).reshape(-1)[:3]]})
    return {"task": cfg.task_name, "objects": objects,
            "trajectories": {str(k): np.asarray(v).tolist()
                             for k, v in env.scene.trajectories.items()},
            "targets": targets, "bodies": list(BODY_NAMES),
            "body_geoms": body_geoms(env.model, env.scene.body_ids, BODY_NAMES)}


def _frame(env, plan_skills: list[str]) -> dict[str, Any]:
    xpos = env.backend.xpos[0]
    xquat = env.backend.xquat[0]
    body = env.ix.body
    objects = [{"name": env.scene.objects[i].name,
                "pos": xpos[env.ix.obj_body[i]].tolist(), "quat": xquat[env.ix.obj_body[i]].tolist()}
               for i in env.ix.dyn.tolist()]
    sub = int(env.subtask[0])
    return {"pos": xpos[body].tolist(), "quat": xquat[body].tolist(), "objects": objects,
            "subtask": sub, "skill": plan_skills[min(sub, len(plan_skills) - 1)]}


def run_evaluation(env, policy: Policy, trials: int, cfg: RunConfig,
                   log: RunLogWriter | None = None, progress: bool = True,
                   episode_id: int = 0) -> dict[str, Any]:
    """Roll out `trials` episodes (quota per env) and summarise them as eval.json data.

    With a `log`, env 0's first episode is recorded as /episode/bodies episode `episode_id`
    (the checkpoint's iteration, so evaluations of successive checkpoints stay apart)."""
    from detach.envs.humanoid import BODY_NAMES

    n = env.num_envs
    quota = [trials // n + (1 if i < trials % n else 0) for i in range(n)]
    counted = [0] * n
    outcomes: list[TrialOutcome] = []
    plan_skills = [s.skill for s in env.plan]
    recording = log is not None
    frame = 0
    if recording:
        log.log_scene(record_scene(env, cfg))
    obs = env.get_observations()
    bar = tqdm(total=trials, desc=f"eval {cfg.task_name}", disable=not progress, unit="ep")
    with torch.inference_mode():
        while len(outcomes) < trials:
            if recording:
                f = _frame(env, plan_skills)
                log.log_frame(episode_id, frame, frame * env.dt, BODY_NAMES, f["pos"], f["quat"],
                              f["objects"], f["subtask"], f["skill"])
                frame += 1
            obs, _rew, dones, extras = env.step(policy(obs))
            progress_data = extras.get("episode_progress")
            for i in dones.nonzero().flatten().tolist():
                if i == 0 and recording:
                    recording = False
                    log.flush()
                if counted[i] >= quota[i] or progress_data is None:
                    continue
                counted[i] += 1
                outcomes.append(_outcome(progress_data, i, env.dt))
                bar.update(1)
    bar.close()
    return summarize(plan_skills, outcomes, cfg.eval.confidence)


def _outcome(prog: dict[str, torch.Tensor], i: int, dt: float) -> TrialOutcome:
    scores = prog["score"][i].float().tolist()
    times = prog["exec_time"][i].float().tolist()
    return TrialOutcome(scores=scores, times=times, completed=bool(prog["lh_success"][i]),
                        total_time=float(prog["length"][i]) * dt)

