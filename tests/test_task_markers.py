"""Issue 61 item 2: one description of the task markers per frame (path done and ahead,
targets, caption, verdict), from what a run log carries, drawn by every view; here the
description itself, its reading of untrusted frames, and its Foxglove entities in log.mcap."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from mcap.reader import make_reader

from detach.eval.task_markers import (
    DONE_PATH_COLOR, FAILURE_COLOR, MAX_PATH_POINTS, PATH_COLOR, SUCCESS_COLOR, Disc, PathMemo, Polyline,
    Sphere, TaskState, Text, split_path, task_markers, task_state,
)
from detach.runfolder.messages import EpisodeFrame, SceneMessage, SceneTarget
from detach.runs.foxglove import TASK_UPDATE_TOPIC
from detach.runs.mcap_log import RunLogWriter

PATH = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [2.0, 1.0]])
SIT = SceneTarget(1, "sit", [3.0, 3.0, 0.5], [200, 80, 200])


def _by_name(markers: list) -> dict:
    return {m.name: m for m in markers}


def test_split_path_cuts_at_the_reference_point() -> None:
    done, ahead, ref = split_path(PATH, 1.5)
    np.testing.assert_allclose(ref, [1.5, 0.0])
    np.testing.assert_allclose(done, [[0, 0], [1, 0], [1.5, 0]])
    np.testing.assert_allclose(ahead, [[1.5, 0], [2, 0], [2, 1]])
    done, ahead, ref = split_path(PATH, 99.0)  # clamped to the end
    np.testing.assert_allclose(ref, [2.0, 1.0])
    assert len(ahead) == 1 and len(done) == len(PATH) + 1


def test_follow_frame_markers() -> None:
    state = TaskState(2.25, 0, "follow", np.array([1.2, 0.1, 0.9]), target=np.array([2.0, 1.0, 0.0]),
                      path=PATH, path_index=1.5)
    m = _by_name(task_markers([SIT], state))
    assert isinstance(m["path/done"], Polyline) and m["path/done"].color == DONE_PATH_COLOR
    assert isinstance(m["path/remaining"], Polyline) and m["path/remaining"].color == PATH_COLOR
    np.testing.assert_allclose(m["path/remaining"].points[0, :2], [1.5, 0.0])
    assert isinstance(m["target/0"], Sphere) and m["target/0"].color == (46, 160, 67)  # Follow's colour
    assert isinstance(m["target/ring"], Disc)
    np.testing.assert_allclose(m["target/ring"].pos, [2.0, 1.0, 0.0])
    assert m["target/1"].opacity == 1.0 and m["target/1"].radius < m["target/0"].radius  # a later subtask's
    assert isinstance(m["caption"], Text) and m["caption"].text == "subtask 0: Follow · t = 2.2 s"
    assert "verdict" not in m


def test_verdict_and_passed_targets() -> None:
    root = np.array([3.0, 3.0, 0.6])
    failed = _by_name(task_markers([SceneTarget(0, "follow", [1, 1, 0]), SIT],
                                   TaskState(9.0, 1, "sit", root, outcome="failure", scores=(1.0, 0.0))))
    assert failed["target/0"].opacity < 1.0, "a passed subtask's target is faded"
    assert failed["target/1"].radius > 0.1 and "target/ring" in failed  # the current one, from the scene
    assert failed["verdict"].text == "FAILURE (1/2 subtasks)" and failed["verdict"].color == FAILURE_COLOR
    assert failed["verdict/ring"].color == FAILURE_COLOR
    ok = _by_name(task_markers([], TaskState(9.0, 0, "follow", root, outcome="success")))
    assert ok["verdict"].text == "SUCCESS" and ok["verdict/ring"].color == SUCCESS_COLOR


def test_recorded_frames_are_checked_and_paths_carried() -> None:
    memo = PathMemo()
    f0 = {"frame": 0, "time": 0.0, "subtask": 0, "skill": "follow", "path": PATH.tolist(), "path_index": 0.0,
          "target": [2.0, 1.0, 0.0]}
    f1 = {"frame": 1, "time": 0.03, "subtask": 0, "skill": "follow", "path_index": 0.1}
    np.testing.assert_allclose(memo.update("a", f0), PATH)
    np.testing.assert_allclose(memo.update("a", f1), PATH)  # carried forward
    assert memo.update("a", {"frame": 2, "path": []}) is None  # a subtask without a path
    assert memo.update("b", {"frame": 0, "path": [[0, 0], [1, "x"]]}) is None  # malformed: dropped
    assert memo.update("c", {"frame": 0, "path": [[0, 0]] * (MAX_PATH_POINTS + 1)}) is None
    bad = {"time": float("inf"), "subtask": True, "skill": 7, "target": [0, float("nan"), 0], "path_index": "1",
           "outcome": "<b>won</b>", "scores": [1e400]}
    state = task_state(bad, [0.0, 0.0, 1.0], None)
    assert (state.time, state.subtask, state.skill, state.target, state.path_index, state.outcome, state.scores) == \
        (0.0, 0, "", None, None, "", ())
    good = task_state({**f1, "outcome": "success", "scores": [1.0]}, [1, 2, 3], PATH)
    assert good.outcome == "success" and good.scores == (1.0,) and good.path_index == 0.1


def test_log_mcap_carries_each_frames_markers_for_foxglove(tmp_path: Path) -> None:
    scene = SceneMessage("follow", [], {}, [SIT], ["pelvis"], [])
    path = tmp_path / "log.mcap"
    frames = [EpisodeFrame(3, 0, 0.0, ["pelvis"], [[0, 0, 0.9]], [[1, 0, 0, 0]], skill="follow",
                           target=[2.0, 1.0, 0.0], path=PATH.tolist(), path_index=0.0),
              EpisodeFrame(3, 1, 1 / 30, ["pelvis"], [[0.1, 0, 0.9]], [[1, 0, 0, 0]], skill="follow",
                           target=[2.0, 1.0, 0.0], path_index=2.5),
              EpisodeFrame(3, 2, 2 / 30, ["pelvis"], [[0.1, 0, 0.9]], [[1, 0, 0, 0]], skill="follow",
                           target=[2.0, 1.0, 0.0], path_index=2.5, outcome="failure", scores=[0.0])]
    with RunLogWriter(path, assets_root=tmp_path) as log:
        log.log_scene(scene)
        for f in frames:
            log.log_frame(f)
    with open(path, "rb") as f:
        updates = [(schema.name, m.log_time, json.loads(m.data))
                   for schema, ch, m in make_reader(f).iter_messages(log_time_order=False)
                   if ch.topic == TASK_UPDATE_TOPIC]
    assert len(updates) == 3 and all(name == "foxglove.SceneUpdate" for name, _t, _u in updates)
    for _name, t, update in updates:
        assert update["deletions"][0]["type"] == 1  # each frame replaces the previous one's
        assert all(e["frame_id"] == "world" and e["id"].startswith("task/") for e in update["entities"])
    second = {e["id"]: e for e in updates[1][2]["entities"]}
    done = [(p["x"], p["y"]) for p in second["task/path/done"]["lines"][0]["points"]]
    assert done == [(0, 0), (1, 0), (2, 0), (2, 0.5)], "the path came from frame 0, cut at frame 1's index"
    assert second["task/path/remaining"]["lines"][0]["color"]["b"] > 0.7
    assert second["task/caption"]["texts"][0]["text"] == "subtask 0: Follow · t = 0.0 s"
    assert {"task/target/0", "task/target/1", "task/target/ring"} <= set(second)
    last = {e["id"]: e for e in updates[2][2]["entities"]}
    assert last["task/verdict"]["texts"][0]["text"] == "FAILURE (0/1 subtasks)"
    assert "task/verdict" not in second


def _port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_dashboard_replay_draws_each_frames_markers(tmp_path: Path) -> None:
    """The replay's 3D view (viser) draws the markers of the frame shown: the path cut where
    that frame's reference point is, the live target, the caption; the closing frame's verdict;
    nothing once no episode is shown."""
    import viser

    from server.episode import episode_from_frames
    from server.scene_view import RunScene

    scene = SceneMessage("follow", [], {}, [SIT], ["pelvis"], [])
    frames = [EpisodeFrame(3, k, k / 30, ["pelvis"], [[0.1 * k, 0, 0.9]], [[1, 0, 0, 0]], skill="follow",
                           target=[2.0, 1.0, 0.0], path=PATH.tolist() if k == 0 else None, path_index=0.5 * k,
                           outcome="success" if k == 4 else "", scores=[1.0] if k == 4 else None)
              for k in range(5)]
    ep = episode_from_frames(3, frames, 0)
    server = viser.ViserServer(host="127.0.0.1", port=_port(), verbose=False)
    try:
        view = RunScene(server.scene, server.atomic, "a")
        view.show(scene, np.zeros(3))
        nodes = server.scene._handle_from_node_name
        view.set_markers(view.frame_markers(ep, 1))
        assert {"path/done", "path/remaining", "path/reference", "target/0", "target/1", "target/ring",
                "caption"} <= set(view.markers.names)
        remaining = nodes["/a/task/path_remaining"]
        np.testing.assert_allclose(remaining.points[0, 0], [0.5, 0.0, 0.05], atol=1e-6)
        assert not nodes["/a/targets/0"].visible, "the scene's plain target gives way to the markers"
        view.set_markers(view.frame_markers(ep, 3))
        np.testing.assert_allclose(remaining.points[0, 0], [1.5, 0.0, 0.05], atol=1e-6)  # updated in place
        assert nodes["/a/task/caption"].text == "subtask 0: Follow · t = 0.1 s"
        view.set_markers(view.frame_markers(ep, 4, "B · "))
        assert nodes["/a/task/verdict"].text == "B · SUCCESS (1/1 subtasks)"
        view.hide_character()
        assert view.markers.names == [] and not any(n.startswith("/a/task/") for n in nodes)
        assert nodes["/a/targets/0"].visible
    finally:
        server.stop()
