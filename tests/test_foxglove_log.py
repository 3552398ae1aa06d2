"""log.mcap in Foxglove: wall-clock log times, evaluation trials one after another on the
timeline, SceneUpdate entities with embedded meshes (no paths of the writing machine)."""

from __future__ import annotations

import base64
import json
import time
from pathlib import Path

from mcap.reader import make_reader

from detach.runfolder.messages import BodyGeom, EpisodeFrame, SceneMessage, SceneObject, SceneTarget
from detach.runs.foxglove import SCENE_UPDATE_TOPIC
from detach.runs.mcap_log import RunLogWriter

GLB = b"glTF\x02\x00\x00\x00" + bytes(range(64))


def _scene() -> SceneMessage:
    return SceneMessage(
        task="lh1",
        objects=[SceneObject("chair_0", "chair", "chair/chair_v0/mesh.obj", [1.0, 2.0, 0.0], [1, 0, 0, 0],
                             [0.5, 0.5, 0.9], True),
                 SceneObject("box_0", "box", "box/box_v0/mesh.obj", [0.0, 1.0, 0.2], [1, 0, 0, 0],
                             [0.3, 0.3, 0.3], False)],
        trajectories={"0": [[0.0, 0.0], [1.0, 1.0], [2.0, 1.0]]},
        targets=[SceneTarget(0, "follow", [2.0, 1.0, 0.0], [40, 160, 70])],
        bodies=["pelvis", "torso"],
        body_geoms=[BodyGeom("pelvis", "sphere", [0.1], [0, 0, 0], [1, 0, 0, 0]),
                    BodyGeom("torso", "capsule", [0.07, 0.15], [0, 0, 0.1], [1, 0, 0, 0])])


def _frame(trial: int, k: int) -> EpisodeFrame:
    return EpisodeFrame(7, k, k / 30, ["pelvis", "torso"], [[0, 0, 1], [0, 0, 1.3]], [[1, 0, 0, 0]] * 2,
                        [{"name": "box_0", "pos": [0, 1, 0.2], "quat": [1, 0, 0, 0]}], 0, "follow", trial)


def _messages(path: Path) -> list[tuple[str, str, int, dict]]:
    with open(path, "rb") as f:
        return [(ch.topic, schema.name, m.log_time, json.loads(m.data))
                for schema, ch, m in make_reader(f).iter_messages(log_time_order=False)]


def test_foxglove_view_of_a_log(tmp_path: Path) -> None:
    assets = tmp_path / "assets"
    (assets / "chair/chair_v0/vis").mkdir(parents=True)
    (assets / "chair/chair_v0/vis/mesh.glb").write_bytes(GLB)  # the box has no mesh: drawn as its bbox
    path = tmp_path / "run" / "log.mcap"
    path.parent.mkdir()
    before = time.time_ns()
    with RunLogWriter(path, assets_root=assets) as log:
        log.log_metrics(0, {"Loss/value": 1.0})
        log.log_metrics(1, {"Loss/value": 0.5})
        log.log_scene(_scene())
        for k in range(3):  # two trials recorded at once, as parallel envs do
            log.log_frame(_frame(0, k))
            log.log_frame(_frame(1, k))
    after = time.time_ns()
    messages = _messages(path)  # mcap's standard reader: a closed log is a valid MCAP file

    metric_times = [t for topic, _s, t, _m in messages if topic == "/metrics"]
    assert len(metric_times) == 2 and before <= metric_times[0] <= metric_times[1] <= after

    frames = [(m["trial"], m["frame"], t) for topic, _s, t, m in messages if topic == "/episode/bodies"]
    end_0 = max(t for trial, _f, t in frames if trial == 0)
    start_1 = min(t for trial, _f, t in frames if trial == 1)
    assert start_1 > end_0 >= before  # trial 1 plays after trial 0, not at t = 0
    for trial, k, t in frames:
        same = [t2 for trial2, k2, t2 in frames if trial2 == trial and k2 == k + 1]
        assert not same or abs(same[0] - t - 1e9 / 30) < 1e3  # frames keep their spacing
    tf = [(t, m) for topic, _s, t, m in messages if topic == "/tf"]
    assert {x["child_frame_id"] for x in tf[0][1]["transforms"]} == {"pelvis", "torso", "box_0"}
    for t, m in tf:
        stamp = m["transforms"][0]["timestamp"]
        assert stamp["sec"] * 10**9 + stamp["nsec"] == t

    (schema, update), = [(s, m) for topic, s, _t, m in messages if topic == SCENE_UPDATE_TOPIC]
    assert schema == "foxglove.SceneUpdate"
    entities = {e["id"]: e for e in update["entities"]}
    chair = entities["scene/chair_0"]
    assert chair["frame_id"] == "world" and chair["models"][0]["media_type"] == "model/gltf-binary"
    assert base64.b64decode(chair["models"][0]["data"]) == GLB and chair["models"][0]["url"] == ""
    box = entities["scene/box_0"]
    assert box["frame_id"] == "box_0" and box["frame_locked"] and box["cubes"][0]["size"]["z"] == 0.3
    torso = entities["character/torso"]
    assert torso["frame_id"] == "torso" and len(torso["cylinders"]) == 1 and len(torso["spheres"]) == 2
    assert "trajectory/0" in entities and "target/0" in entities
    assert str(tmp_path).encode() not in path.read_bytes()  # no path of this machine in the log


def test_growing_log_fails_mcaps_standard_reader_not_ours(tmp_path: Path) -> None:
    """What docs/foxglove/README.md says about a run that is still writing."""
    import pytest

    from detach.runfolder.mcap_reader import iter_messages

    path = tmp_path / "log.mcap"
    log = RunLogWriter(path, assets_root=tmp_path)
    try:
        log.log_metrics(0, {"Loss/value": 1.0})
        log.log_metrics(1, {"Loss/value": 0.5})
        # McapError (RecordLengthLimitExceeded) here; the bytes of the partial tail decide which
        with open(path, "rb") as f, pytest.raises(Exception):
            list(make_reader(f).iter_messages())
        assert [m["iteration"] for topic, _t, m in iter_messages(path) if topic == "/metrics"] == [0, 1]
    finally:
        log.close()
