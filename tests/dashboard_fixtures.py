"""Fixture runs folders for the dashboard tests, written with the project's own writers.

`make_runs(root)` creates finished runs (one per model) with config.yaml (resolved LH1),
status.json, a log.mcap holding /metrics for every iteration, a /scene (box meshes written
next to the runs, one object whose mesh is missing, the LH1 trajectory and targets, the real
humanoid's 15 bodies and geoms) and an episode whose bodies come from MuJoCo forward
kinematics of a walking-like motion, and eval.json / eval_lh3.json from
detach.eval.report.summarize. Scenes differ between runs so that switching runs is visible.
"""

from __future__ import annotations

import math
import random
from pathlib import Path
from typing import Any, Sequence

import mujoco
import numpy as np
import trimesh

from detach.config import resolve
from detach.character import build_character_model
from detach.character.body import BODY_NAMES
from detach.eval.report import TrialOutcome, summarize
from detach.run_contract import EpisodeFrame, SceneMessage
from detach.runs.folder import RunFolder, atomic_write_json
from detach.runs.mcap_log import RunLogWriter

ROOT = Path(__file__).resolve().parents[1]
LH1_PLAN = ["follow", "carry", "climb", "sit"]
LH3_PLAN = ["follow", "carry", "follow", "climb", "sit"]
GEOM_TYPES = {int(mujoco.mjtGeom.mjGEOM_CAPSULE): "capsule",
              int(mujoco.mjtGeom.mjGEOM_SPHERE): "sphere", int(mujoco.mjtGeom.mjGEOM_BOX): "box"}


def mesh_name(path: Path) -> str:
    """A /scene mesh name: `<category>/<model_id>/mesh.obj` under the assets root."""
    return "/".join(path.parts[-3:])


def write_box_obj(path: Path, size: Sequence[float]) -> Path:
    """A closed box mesh.obj centred on the origin (the asset contract's object frame)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    trimesh.creation.box(extents=size).export(path)
    return path


def humanoid_geoms(model: mujoco.MjModel) -> list[dict[str, Any]]:
    """The /scene `body_geoms` of the project's humanoid (MuJoCo sizes, body frame)."""
    out = []
    for g in range(model.ngeom):
        body = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, int(model.geom_bodyid[g]))
        if body in BODY_NAMES:
            out.append({"body": body, "type": GEOM_TYPES.get(int(model.geom_type[g]), "sphere"),
                        "size": model.geom_size[g].round(5).tolist(),
                        "pos": model.geom_pos[g].round(5).tolist(),
                        "quat": model.geom_quat[g].round(5).tolist()})
    return out


def walk_frames(model: mujoco.MjModel, frames: int, start: Sequence[float],
                heading: float, speed: float = 1.0, fps: float = 30.0
                ) -> tuple[np.ndarray, np.ndarray]:
    """Body positions [F, 15, 3] and quaternions [F, 15, 4] of a swinging-limbs walk."""
    data = mujoco.MjData(model)
    ids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, b) for b in BODY_NAMES]
    hips = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, f"{s}_hip_y")
            for s in ("right", "left")]
    shoulders = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, f"{s}_shoulder_y")
                 for s in ("right", "left")]
    knees = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, f"{s}_knee_y")
             for s in ("right", "left")]
    pos, quat = np.zeros((frames, len(ids), 3)), np.zeros((frames, len(ids), 4))
    for f in range(frames):
        t = f / fps
        data.qpos[:] = 0.0
        data.qpos[0:3] = (start[0] + speed * t * math.cos(heading),
                          start[1] + speed * t * math.sin(heading), 0.94)
        data.qpos[3:7] = (math.cos(heading / 2), 0.0, 0.0, math.sin(heading / 2))
        phase = 2 * math.pi * 1.2 * t
        for side, sign in ((0, 1.0), (1, -1.0)):
            data.qpos[model.jnt_qposadr[hips[side]]] = -0.5 * sign * math.sin(phase)
            data.qpos[model.jnt_qposadr[shoulders[side]]] = 0.5 * sign * math.sin(phase)
            data.qpos[model.jnt_qposadr[knees[side]]] = 0.6 * max(0.0, sign * math.sin(phase))
        mujoco.mj_kinematics(model, data)
        pos[f], quat[f] = data.xpos[ids], data.xquat[ids]
    return pos, quat


def outcomes(rng: random.Random, plan: Sequence[str], p: float, trials: int = 40
             ) -> list[TrialOutcome]:
    out = []
    for _ in range(trials):
        scores, alive = [], True
        for _skill in plan:
            ok = alive and rng.random() < p
            scores.append(1.0 if ok else 0.0)
            alive = ok
        out.append(TrialOutcome(scores, [rng.uniform(5, 15) for _ in plan], all(scores),
                                rng.uniform(40, 80)))
    return out


def make_run(root: Path, model_name: str, seed: int, *, shift: float, now: float,
             assets: Path, iterations: int = 20, frames: int = 60,
             state: str = "finished") -> RunFolder:
    """One finished LH1 run; `shift` moves its objects so that scenes differ visibly."""
    cfg = resolve(ROOT / "configs/tasks/lh1.yaml", model_name, seed=seed)
    run = RunFolder.create(root, cfg, now=now)
    run.set_state("running", iteration=0)
    model = build_character_model()
    rng = random.Random(seed * 7 + len(model_name))
    objects = [
        {"name": "box", "category": "Box", "static": False, "bbox": [0.6, 0.6, 0.7],
         "mesh": mesh_name(write_box_obj(assets / "Box/box_a/mesh.obj", (0.6, 0.6, 0.7))),
         "pos": [4.5 - shift, -4.0 + shift, 0.35], "quat": [1, 0, 0, 0]},
        {"name": "platform", "category": "Obstacle", "static": True, "bbox": [5.0, 3.0, 1.0],
         "mesh": mesh_name(write_box_obj(assets / "Obstacle/platform_a/mesh.obj", (5.0, 3.0, 1.0))),
         "pos": [0.0, shift, 0.5], "quat": [1, 0, 0, 0]},
        {"name": "chair", "category": "chair", "static": True, "bbox": [0.55, 0.55, 0.92],
         "mesh": "chair/missing/mesh.obj",  # drawn as its bbox
         "pos": [0.0, shift, 1.46], "quat": [0.7071, 0, 0, -0.7071]},
        {"name": "wall", "category": "Obstacle", "static": True, "bbox": [0.3, 5.0, 3.0],
         "mesh": mesh_name(write_box_obj(assets / "Obstacle/wall_a/mesh.obj", (0.3, 5.0, 3.0))),
         "pos": [6.0 + shift, -3.25, 1.5], "quat": [1, 0, 0, 0]},
    ]
    scene = {"task": "lh1", "objects": objects,
             "trajectories": {"0": [[10.0, 4.0 - shift], [10.0, 2.0], [7.0, 0.0], [5.0, 0.0],
                                    [4.0, -1.0]]},
             "targets": [{"subtask": i, "skill": s, "pos": p} for i, (s, p) in enumerate(
                 zip(LH1_PLAN, [[4.0, -1.0, 0.0], [0.0, -1.8, 0.35], [4.5, -4.0, 0.7],
                                [0.0, shift, 1.5]]))],
             "bodies": list(BODY_NAMES), "body_geoms": humanoid_geoms(model)}
    heading = math.pi + 0.4 * shift
    start = (9.5, 3.0 - shift)
    pos, quat = walk_frames(model, frames, start, heading)
    with RunLogWriter(run.log_path) as log:
        log.log_scene(SceneMessage.from_json(scene))
        for it in range(iterations):
            stage = "skills" if it < iterations // 2 else "joint"
            x = (it + 1) / iterations
            metrics = {"reward/mean": x * (2 + seed) + 0.1 * rng.random(),
                       "loss/surrogate": -0.01 * x, "loss/value": 1.0 / (1 + it),
                       "loss/amp": 0.5 - 0.2 * x, "success/follow": min(1.0, 1.2 * x),
                       "success/carry": x * x, "fps": 900.0 + 50 * rng.random(),
                       "episode/length": 100 + 10 * it}
            log.log_metrics(it, metrics, stage=stage)
        for f in range(frames):
            ahead = pos[f, 0, :2] + 0.45 * np.array([math.cos(heading), math.sin(heading)])
            box = objects[0]["pos"] if f < frames // 2 else [*ahead, 1.0]  # carried in front
            subtask = 0 if f < frames // 2 else 1
            log.log_frame(EpisodeFrame(episode=0, frame=f, time=f / 30.0, bodies=list(BODY_NAMES),
                                       pos=pos[f].tolist(), quat=quat[f].tolist(),
                                       objects=[{"name": "box", "pos": list(box), "quat": [1, 0, 0, 0]}],
                                       subtask=subtask, skill=LH1_PLAN[subtask]))
    p = {"mlp": 0.55, "detach": 0.9}.get(model_name, 0.7)
    for task, plan, rate, path in (("lh1", LH1_PLAN, p, run.eval_path),
                                   ("lh3", LH3_PLAN, p - 0.1, run.path / "eval_lh3.json")):
        result = summarize(plan, outcomes(rng, plan, rate), task=task, model=model_name)
        result.trained_on, result.seed, result.checkpoint = "lh1", seed, f"checkpoints/model_{iterations}.pt"
        atomic_write_json(path, result.to_json())
    run.set_state(state, iteration=iterations - 1)
    return run


def make_runs(root: Path, models: Sequence[str] = ("mlp", "detach"), *, broken: bool = True,
              iterations: int = 20, frames: int = 60) -> list[RunFolder]:
    """The fixture runs folder `root`: one run per model (+ one broken folder if asked)."""
    assets = root.parent / "assets"  # beside the runs folder, where the dashboard looks
    runs = [make_run(root, m, seed=i, shift=1.5 * i, now=1_700_000_000 + 60 * i,
                     assets=assets, iterations=iterations, frames=frames)
            for i, m in enumerate(models)]
    if broken:
        bad = root / "20231114-230000-lh1-cml-s9"
        bad.mkdir(parents=True)
        (bad / "config.yaml").write_text("task_name: lh1\nmodel_name: cml\nseed: 9\n")
        (bad / "status.json").write_text('{"state": "runn')  # half-written
    return runs
