"""The /scene message of a run: objects, trajectories, subtask targets and the character's shape."""

from __future__ import annotations

import math

import mujoco
import numpy as np

from detach.character.body import BODY_NAMES
from detach.config.schema import RunConfig
from detach.runfolder.messages import BodyGeom, SceneMessage, SceneObject, SceneTarget
from detach.skills import skill_class

_GEOM_KINDS = {int(mujoco.mjtGeom.mjGEOM_CAPSULE): "capsule", int(mujoco.mjtGeom.mjGEOM_SPHERE): "sphere",
               int(mujoco.mjtGeom.mjGEOM_BOX): "box"}


def body_geoms(model: mujoco.MjModel, body_ids: np.ndarray, body_names: tuple[str, ...]) -> list[BodyGeom]:
    """The character's collision primitives in body frames (for drawing it)."""
    index = {int(b): name for b, name in zip(body_ids, body_names)}
    out = []
    for g in range(model.ngeom):
        body = int(model.geom_bodyid[g])
        kind = _GEOM_KINDS.get(int(model.geom_type[g]))
        if body in index and kind is not None:
            out.append(BodyGeom(index[body], kind, [float(v) for v in model.geom_size[g]],
                                [float(v) for v in model.geom_pos[g]], [float(v) for v in model.geom_quat[g]]))
    return out


def scene_message(env, cfg: RunConfig) -> SceneMessage:
    """The /scene message of an environment: what a viewer needs to draw the task.

    Meshes are named relative to the assets root (`<category>/<model_id>/mesh.obj`), never by
    a path of the machine that wrote the log. Each subtask with a drawable target gets it
    (`Skill.display_target`), coloured by its skill."""
    objects = []
    for obj, spec in zip(env.scene.objects, cfg.task.scene):
        h = obj.z_rot / 2
        objects.append(SceneObject(
            name=obj.name, category=obj.category, mesh=f"{spec.category}/{spec.model_id}/mesh.obj",
            pos=[float(v) for v in obj.pos], quat=[math.cos(h), 0.0, 0.0, math.sin(h)],
            bbox=[float(v) for v in obj.bbox], static=bool(obj.static)))
    targets = []
    for sub in env.plan:
        skill = skill_class(sub.skill)
        point = skill().display_target(sub, env.scene)
        if point is not None:
            targets.append(SceneTarget(sub.index, sub.skill, [float(v) for v in np.asarray(point).reshape(-1)[:3]],
                                       list(skill.color)))
    return SceneMessage(
        task=cfg.task_name, objects=objects,
        trajectories={str(k): np.asarray(v).tolist() for k, v in env.scene.trajectories.items()},
        targets=targets, bodies=list(BODY_NAMES),
        body_geoms=body_geoms(env.model, env.scene.body_ids, BODY_NAMES))
