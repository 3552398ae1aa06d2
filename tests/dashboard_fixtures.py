"""Fixture runs folders for the dashboard tests, written with the project's own writers.

`make_runs(root)` creates finished runs (one per model) with config.yaml (resolved LH1),
status.json, a log.mcap holding /metrics for every iteration (and `Success/late` from the
middle on, as metrics logged from the first evaluation are), a /scene (box meshes written
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
from detach.runfolder.messages import EpisodeFrame, SceneMessage
from detach.runfolder.atomic import atomic_write_json
from detach.runfolder.folder import RunFolder
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
            metrics = {"Train/mean_reward": x * (2 + seed) + 0.1 * rng.random(),
                       "Loss/surrogate": -0.01 * x, "Loss/value": 1.0 / (1 + it),
                       "Loss/amp": 0.5 - 0.2 * x, "Episode_Success/follow": min(1.0, 1.2 * x),
                       "Episode_Success/carry": x * x, "Perf/total_fps": 900.0 + 50 * rng.random(),
                       "Train/mean_episode_length": 100 + 10 * it, "Loss/learning_rate": 1e-3 * 0.9 ** it}
            if it >= iterations // 2:  # logged from the first evaluation on, as success fractions are
                metrics["Episode_Success/late"] = 0.2 + 0.6 * x
            log.log_metrics(it, metrics, stage=stage)
        for f in range(frames):  # frames=0: a run that recorded no episode
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


# --- a browser without a browser ----------------------------------------------------------
class HeadlessClient:
    """A viser client in Python: it connects like a browser (same subprotocol, a camera
    message to count as connected), records every GUI element the server creates for it and
    every update, counts the bytes it receives, and sends GUI updates as a browser would, or
    as an attacker would (any value, any property)."""

    def __init__(self, url: str, origin: str | None = "auto",
                 headers: dict[str, str] | None = None) -> None:
        import threading

        import viser
        from websockets.sync.client import connect

        ws_url = url.replace("http://", "ws://", 1)
        if origin == "auto":
            origin = url.split("/?")[0].rstrip("/")
        self.ws = connect(ws_url, origin=origin, subprotocols=[f"viser-v{viser.__version__}"],
                          additional_headers=headers or {}, max_size=None, open_timeout=20)
        self.elements: dict[str, dict[str, Any]] = {}
        self.bytes_received = 0
        self.messages_received = 0
        self.updates: list[tuple[str, str, tuple[str, ...]]] = []
        """(element type, uuid, updated properties) of every GuiUpdateMessage received."""
        self.lock = threading.RLock()
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()
        self.send("ViewerCameraMessage", wxyz=(1.0, 0.0, 0.0, 0.0), position=(0.0, -5.0, 3.0),
                  fov=1.0, near=0.01, far=100.0, image_height=800, image_width=1200,
                  look_at=(0.0, 0.0, 0.0), up_direction=(0.0, 0.0, 1.0))

    def send(self, message_type: str, **fields: Any) -> None:
        import msgspec

        self.ws.send(msgspec.msgpack.encode({"type": message_type, **fields}))

    def _read(self) -> None:
        import msgspec
        import zstandard

        zstd = zstandard.ZstdDecompressor()
        try:
            while True:
                frame = self.ws.recv()
                size = int.from_bytes(frame[:8], "little")
                compressed = int.from_bytes(frame[8:16], "little")
                inner = msgspec.msgpack.decode(zstd.decompress(frame[16:16 + compressed],
                                                               max_output_size=size))
                with self.lock:
                    self.bytes_received += len(frame)
                for m in inner["messages"]:  # one at a time, as a browser shows them
                    with self.lock:
                        self.messages_received += 1
                        self._apply(m)
        except Exception:  # noqa: BLE001 - the connection closed
            return

    def _apply(self, m: dict[str, Any]) -> None:
        kind, uuid = m.get("type", ""), m.get("uuid")
        if kind == "GuiRemoveMessage":
            self.elements.pop(uuid, None)
        elif kind == "GuiUpdateMessage" and uuid in self.elements:
            element = self.elements[uuid]
            self.updates.append((element["type"], uuid, tuple(m["updates"])))
            for key, value in m["updates"].items():
                if key == "value":
                    element["value"] = value
                else:
                    element["props"][key] = value
        elif kind.startswith("Gui") and kind.endswith("Message") and "props" in m and uuid:
            self.elements[uuid] = {"type": kind, "props": dict(m["props"]),
                                   "value": m.get("value")}

    # --- looking -------------------------------------------------------------------------
    def _labelled(self, label: str, kind: str | None) -> list[str]:
        with self.lock:
            return [u for u, e in self.elements.items() if e["props"].get("label") == label
                    and (kind is None or e["type"] == kind)]

    def find(self, label: str, kind: str | None = None, timeout: float = 20.0) -> str:
        """uuid of the (last created) element with this label (and message type), waiting up
        to `timeout` s for it: the server's messages arrive in several frames, so a panel
        built late (the tables' "Pool") may not have reached this client yet."""
        try:
            self.wait_for(lambda: self._labelled(label, kind), timeout, what=f"{label!r}")
        except AssertionError:
            raise KeyError(f"no GUI element labelled {label!r}") from None
        return self._labelled(label, kind)[-1]

    def value(self, label: str) -> Any:
        uuid = self.find(label)  # outside the lock: the reader adds it
        with self.lock:
            return self.elements[uuid]["value"]

    def props(self, label: str) -> dict[str, Any]:
        uuid = self.find(label)  # outside the lock: the reader adds it
        with self.lock:
            return dict(self.elements[uuid]["props"])

    def text(self) -> str:
        """Every markdown and HTML text currently shown to this client."""
        with self.lock:
            return "\n".join(str(e["props"].get("_markdown", e["props"].get("content", "")))
                             for e in self.elements.values()
                             if e["type"] in ("GuiMarkdownMessage", "GuiHtmlMessage"))

    def wait_for(self, predicate, timeout: float = 20.0, what: str = "condition") -> None:
        import time

        deadline = time.monotonic() + timeout
        while not predicate():  # checked at least once, so a timeout of 0 only looks
            if time.monotonic() >= deadline:
                raise AssertionError(f"timed out after {timeout} s waiting for {what}")
            time.sleep(0.05)

    # --- acting ---------------------------------------------------------------------------
    def set(self, label: str, value: Any, **props: Any) -> None:
        """What a browser sends when the user changes a control (plus any property); like a
        browser, the client shows its own value at once."""
        uuid = self.find(label)
        with self.lock:
            if self.elements[uuid]["type"] not in ("GuiButtonMessage", "GuiButtonGroupMessage"):
                self.elements[uuid]["value"] = value
        self.send("GuiUpdateMessage", uuid=uuid, updates={"value": value, **props})

    def click(self, label: str, value: Any = True) -> None:
        self.set(label, value)

    def close(self) -> None:
        self.ws.close()


def start_dashboard(runs: Path, **kwargs: Any):
    """(server, dashboard, url) of a dashboard on a free loopback port, not polling by itself
    (tests call `dashboard.poll()`); stop with `server.stop()`."""
    from server.access import AccessPolicy, serve
    from server.app import Dashboard

    policy = kwargs.pop("policy", AccessPolicy())
    server = serve("127.0.0.1", 0, policy)
    dashboard = Dashboard(server, runs, **kwargs)
    dashboard.poll()
    return server, dashboard, f"http://127.0.0.1:{server.get_port()}"
