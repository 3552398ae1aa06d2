"""The dashboard with a real viser server and browsers without a browser (HeadlessClient):
per-connection state (issue 22 defect 3), the replay cleared for a run without episodes
(defect 4), incremental updates (defect 7), n and pooled runs in the tables (defect 6), a live
run streaming its newest episode, and malformed logs turned into notes."""

from __future__ import annotations

import json
import shutil
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from detach.character.body import BODY_NAMES
from detach.runfolder.messages import EpisodeFrame
from detach.runfolder.names import SCENE_TOPIC
from detach.runs.mcap_log import RunLogWriter
from detach.runfolder.log_tail import LogTail
from server.replay_panel import NO_RUNS
from tests.dashboard_fixtures import HeadlessClient, make_runs, start_dashboard


@pytest.fixture()
def runs(tmp_path: Path) -> Path:
    make_runs(tmp_path / "runs", broken=False, iterations=6, frames=12)
    return tmp_path / "runs"


def _session(dashboard):
    assert len(dashboard.sessions) == 1
    return next(iter(dashboard.sessions.values()))


def _connect(url: str, dashboard, count: int) -> HeadlessClient:
    client = HeadlessClient(url)
    client.wait_for(lambda: len(dashboard.sessions) == count, what="the session")
    client.wait_for(lambda: len(client.elements) > 30, what="the panels")
    # the panels are sent before the run list fills them: wait until it shows a run
    client.wait_for(lambda: client.value("Run") != NO_RUNS, what="the run list")
    return client


def test_two_browsers_keep_separate_selections(runs: Path) -> None:
    server, dashboard, url = start_dashboard(runs)
    a = _connect(url, dashboard, 1)
    b = _connect(url, dashboard, 2)
    try:
        ids = sorted(p.name for p in runs.iterdir())
        sa, sb = (dashboard.sessions[k] for k in sorted(dashboard.sessions))
        assert sa.selected == sb.selected == [ids[-1]], "each starts with the newest run"
        first_label = sa.labels[ids[0]]
        a.set(first_label, True)  # tick the other run in A's compare list
        a.wait_for(lambda: sa.selected == ids[-1:] + ids[:1], what="A's selection")
        a.set("Run", ids[0])  # and show it in A's replay
        a.wait_for(lambda: sa.replay.episode is not None and
                   a.value("Run") == ids[0], what="A's replay")
        time.sleep(0.5)
        assert sb.selected == [ids[-1]] and b.value(first_label) is False
        assert b.value("Run") == ids[-1], "B's dropdown did not follow A's"
        assert "2 run(s): <span" in a.text() and "1 run(s): <span" in b.text()
    finally:
        a.close()
        b.close()
        server.stop()


def test_controls_refuse_values_outside_their_options(runs: Path) -> None:
    server, dashboard, url = start_dashboard(runs)
    client = _connect(url, dashboard, 1)
    try:
        session = _session(dashboard)
        shown = client.value("Run")
        for label, value in (("Run", "../../etc"), ("Beside it", "nope"), ("Group by", "x"),
                             ("X axis", "epochs"), ("Pool", "everything"),
                             ("Speed", float("nan")), ("Frame", float("nan")),
                             ("Smoothing", float("nan")), ("Metric filter", "(a+)+$" * 50)):
            client.set(label, value)
        time.sleep(0.5)
        dashboard.poll()
        assert session.replay.episode is not None and client.value("Run") in (shown, "../../etc")
        assert session.replay.player.speed == 1.0 and np.isfinite(session.replay.player.t)
        client.set("Metric filter", "")  # the nested-repetition filter matched plain text
        client.wait_for(lambda: any(e["type"] == "GuiUplotMessage"
                                    for e in client.elements.values()), what="the charts")
        axes = [e["props"]["axes"][0]["label"] for e in client.elements.values()
                if e["type"] == "GuiUplotMessage"]
        assert axes and set(axes) == {"iteration"}, "an unknown x axis falls back to iteration"
    finally:
        client.close()
        server.stop()


def test_controls_refuse_bad_values_when_the_run_list_arrives_late(
        runs: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """CI once read the Run dropdown while it still showed its placeholder: the run list's
    update reached the client after the first 30 panels and after the test's own changes.
    Here it is held back until the client has changed a control."""
    applied, sent = HeadlessClient._apply, HeadlessClient.set
    changed = threading.Event()

    def set_and_tell(self, label, value, **props):
        sent(self, label, value, **props)
        changed.set()

    def late_run_list(self, m):
        if m.get("type") == "GuiUpdateMessage" and str(m["updates"].get("value", "")).startswith("2023"):
            self.lock.release()  # the client's other threads read on meanwhile
            changed.wait(timeout=3.0)
            self.lock.acquire()
        applied(self, m)

    monkeypatch.setattr(HeadlessClient, "_apply", late_run_list)
    monkeypatch.setattr(HeadlessClient, "set", set_and_tell)
    test_controls_refuse_values_outside_their_options(runs)


def test_a_slow_browser_reaches_controls_built_after_the_first_panels(
        runs: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """CI once set "Pool" (built after the first 30 elements) before its message arrived; a
    client that takes 20 ms per message must still reach it."""
    applied = HeadlessClient._apply

    def slowly(self, m):
        time.sleep(0.02)
        applied(self, m)

    monkeypatch.setattr(HeadlessClient, "_apply", slowly)
    server, dashboard, url = start_dashboard(runs)
    client = _connect(url, dashboard, 1)
    try:
        client.set("Pool", "everything")
        assert client.value("Pool") == "everything"
    finally:
        client.close()
        server.stop()


def _without_episodes(runs: Path) -> Path:
    """A copy of the first run whose log has the scene and metrics but no frames."""
    src = sorted(runs.iterdir())[0]
    dst = runs / (src.name.replace("-s0", "-s5") + "-x")
    shutil.copytree(src, dst)
    tail = LogTail(src / "log.mcap")
    tail.refresh()
    with RunLogWriter(dst / "log.mcap") as log:
        log.write(SCENE_TOPIC, tail.scene, 0)
        for m in tail.metrics:
            log.log_metrics(int(m["iteration"]), {k: v for k, v in m.items()
                                                   if k not in ("iteration", "stage")})
    return dst


def test_switching_to_a_run_without_episodes_clears_the_replay(runs: Path) -> None:
    empty = _without_episodes(runs)
    server, dashboard, url = start_dashboard(runs)
    client = _connect(url, dashboard, 1)
    try:
        session = _session(dashboard)
        ids = sorted(p.name for p in runs.iterdir())
        client.set("Run", ids[0])
        client.wait_for(lambda: session.replay.episode is not None
                        and "frame 1/12" in client.text() or "/12" in client.text(),
                        what="an episode of the first run")
        assert client.props("Frame")["disabled"] is False
        client.set("Run", empty.name)
        client.wait_for(lambda: "no episode recorded" in client.text(), what="the cleared replay")
        assert session.replay.episode is None and session.replay.episodes == {}
        assert client.props("Frame")["disabled"] is True and client.value("Frame") == 0
        assert client.props("Episode")["options"] == ["(none)"]
        assert "current subtask" not in client.text() and "/12" not in client.text()
        assert "unreadable" not in client.text(), "no episode is not an error"
    finally:
        client.close()
        server.stop()


def test_an_idle_dashboard_sends_nothing_and_a_new_iteration_only_the_charts_in_view(
        tmp_path: Path) -> None:
    make_runs(tmp_path / "runs", models=("mlp",), broken=False, iterations=5, frames=4)
    run = next((tmp_path / "runs").iterdir())
    tail = LogTail(run / "log.mcap")
    tail.refresh()
    status = json.loads((run / "status.json").read_text())
    (run / "status.json").write_text(json.dumps({**status, "state": "running"}))
    log = RunLogWriter(run / "log.mcap")
    log.write(SCENE_TOPIC, tail.scene, 0)
    keys = {f"{group}/k{i}": 0.0 for group in ("loss", "reward", "policy", "time") for i in range(8)}
    for it in range(5):
        log.log_metrics(it, {k: float(it + j) for j, k in enumerate(keys)})
    log.flush()
    server, dashboard, url = start_dashboard(tmp_path / "runs")
    client = _connect(url, dashboard, 1)
    try:
        client.wait_for(lambda: sum(e["type"] == "GuiUplotMessage"
                                    for e in client.elements.values()) == 8, what="8 charts")
        for _ in range(3):
            dashboard.poll()
        time.sleep(0.5)
        before, updates = client.bytes_received, len(client.updates)
        for _ in range(3):
            dashboard.poll()
            time.sleep(0.2)
        assert client.bytes_received == before, "an idle poll sends nothing (no 'N s ago')"
        log.log_metrics(5, {k: 5.0 + j for j, k in enumerate(keys)})
        log.flush()
        dashboard.poll()
        client.wait_for(lambda: len(client.updates) > updates, what="the new iteration")
        time.sleep(0.5)
        charts = {u for kind, u, props in client.updates[updates:] if kind == "GuiUplotMessage"}
        assert len(charts) == 8, "the 8 charts in view, not all 32 metrics"
        other = [(kind, props) for kind, _u, props in client.updates[updates:]
                 if kind not in ("GuiUplotMessage",)]
        assert all(kind != "GuiMarkdownMessage" or "runs" not in str(props) for kind, props in other)
    finally:
        log.close()
        client.close()
        server.stop()


def test_tables_show_n_and_which_runs_were_pooled(runs: Path) -> None:
    server, dashboard, url = start_dashboard(runs)
    client = _connect(url, dashboard, 1)
    try:
        client.wait_for(lambda: "Pooled runs" in client.text(), what="the tables")
        text = client.text()
        assert "mlp lh1 s0" in text and "detach lh1 s1" in text
        assert "paper: DETACH" in text and "white-space:nowrap" in text
        client.set("One row per run", True)
        client.wait_for(lambda: "↳ mlp lh1 s0" in client.text(), what="the per-run rows")
        assert "text-align:left'>n</th>" in client.text() and "40 (1 seed: s0)" in client.text()
    finally:
        client.close()
        server.stop()


def test_a_live_run_streams_its_newest_episode(tmp_path: Path) -> None:
    make_runs(tmp_path / "runs", models=("mlp",), broken=False, iterations=2, frames=5)
    run = next((tmp_path / "runs").iterdir())
    tail = LogTail(run / "log.mcap")
    tail.refresh()
    status = json.loads((run / "status.json").read_text())
    (run / "status.json").write_text(json.dumps({**status, "state": "running"}))
    log = RunLogWriter(run / "log.mcap", flush_every=5)
    log.write(SCENE_TOPIC, tail.scene, 0)
    log.flush()
    server, dashboard, url = start_dashboard(tmp_path / "runs")
    client = _connect(url, dashboard, 1)
    try:
        session = _session(dashboard)
        assert session.replay.episode is None
        lengths = []
        for ep, frames in ((0, 10), (0, 20), (1, 5)):
            start = 0 if not lengths or ep != 0 else lengths[-1][1]
            for f in range(start, frames):
                log.log_frame(EpisodeFrame(ep, f, f / 30, list(BODY_NAMES),
                                           np.zeros((15, 3)).tolist(),
                                           np.tile([1.0, 0, 0, 0], (15, 1)).tolist()))
            log.flush()
            dashboard.poll()
            lengths.append((session.replay.episode.number, session.replay.episode.num_frames))
        assert lengths == [(0, 10), (0, 20), (1, 5)]
        assert session.replay.player.hold_at_end, "a live episode waits for its next frames"
        assert not session.infos[run.name].unreadable
    finally:
        log.close()
        client.close()
        server.stop()


def test_garbage_scene_and_frames_become_notes_not_crashes(tmp_path: Path) -> None:
    make_runs(tmp_path / "runs", models=("mlp",), broken=False, iterations=2, frames=5)
    run = next((tmp_path / "runs").iterdir())
    with RunLogWriter(run / "log.mcap") as log:
        log.write(SCENE_TOPIC, {"objects": [{"name": "ok", "pos": [0, 0, 0.5], "bbox": [1, 1, 1]},
                                            "not an object", {"pos": "xyz"}],
                                "trajectories": {"0": [[0, 0], "bad"]}, "targets": 5,
                                "bodies": ["a", "b"], "body_geoms": [{"type": "capsule", "size": "x"}]}, 0)
        log.log_frame(EpisodeFrame(0, 0, 0.0, ["a", "b"], [[0, 0, 1], [0, 0, 1]], [[1, 0, 0, 0], [1, 0, 0, 0]]))
        log.log_frame(EpisodeFrame(0, 1, 0.1, ["a", "b"], [[0, 0, float("nan")], [0, 0, 1]],
                                   [[1, 0, 0, 0], [1, 0, 0, 0]]))
    server, dashboard, url = start_dashboard(tmp_path / "runs")
    client = _connect(url, dashboard, 1)
    try:
        client.wait_for(lambda: "object 1" in client.text(), what="the notes")
        text = client.text()
        assert "object 2" in text and "trajectory 0" in text and "body\\_geoms" in text  # Markdown-escaped
        assert "non-finite body poses" in text
        assert _session(dashboard).replay.episode is None, "non-finite poses are refused"
    finally:
        client.close()
        server.stop()


def test_a_replay_frame_costs_the_server_well_under_a_30_fps_budget(runs: Path) -> None:
    server, dashboard, url = start_dashboard(runs)
    client = _connect(url, dashboard, 1)
    try:
        replay = _session(dashboard).replay
        client.wait_for(lambda: replay.episode is not None, what="an episode")
        costs = []
        for i in range(60):  # CPU time of this thread: other processes' load does not count
            replay.player.seek(i % 12)
            t0 = time.thread_time()
            replay.redraw()
            costs.append(time.thread_time() - t0)
        assert np.median(costs) < 0.01, f"per-frame update {np.median(costs) * 1e3:.2f} ms"
    finally:
        client.close()
        server.stop()


def test_pins_enlarge_and_view_controls_of_the_curves(runs: Path) -> None:
    server, dashboard, url = start_dashboard(runs)
    client = _connect(url, dashboard, 1)
    try:
        def charts() -> list[str]:
            return [e["props"]["title"] for e in client.elements.values()
                    if e["type"] == "GuiUplotMessage"]

        client.wait_for(lambda: "Episode_Success/follow" in charts(), what="the success group")
        assert client.value("Show") == "episode_success (3)"
        pin = [u for u, e in client.elements.items() if e["type"] == "GuiButtonGroupMessage"
               and "☆ Pin" in e["props"]["options"]][0]
        client.send("GuiUpdateMessage", uuid=pin, updates={"value": "☆ Pin"})
        client.wait_for(lambda: any("★ Unpin" in e["props"].get("options", ())
                                    for e in client.elements.values()), what="the pin")
        client.set("Show", "pinned")
        client.wait_for(lambda: len(charts()) == 1, what="the pinned chart only")
        client.set("Show", "loss (4)")
        client.set("Metric filter", "value|amp")
        client.wait_for(lambda: sorted(charts()) == ["Loss/amp", "Loss/value"], what="the filter")
        client.set("Smoothing", 0.5)
        client.wait_for(lambda: any(len(e["props"]["series"]) == 3 for e in client.elements.values()
                                    if e["type"] == "GuiUplotMessage"), what="raw + smoothed")
        client.set("X axis", "samples")
        client.wait_for(lambda: {e["props"]["axes"][0]["label"] for e in client.elements.values()
                                 if e["type"] == "GuiUplotMessage"} == {"samples"}, what="samples")
        enlarge = [u for u, e in client.elements.items() if e["type"] == "GuiButtonGroupMessage"
                   and "⤢ Enlarge" in e["props"]["options"]][0]
        before = len(charts())
        client.send("GuiUpdateMessage", uuid=enlarge, updates={"value": "⤢ Enlarge"})
        client.wait_for(lambda: len(charts()) == before + 1 and any(
            e["props"].get("label") == "Close" for e in client.elements.values()),
            what="the enlarged chart")
        client.click("Close")
        client.wait_for(lambda: len(charts()) == before, what="the enlarged chart closed")
    finally:
        client.close()
        server.stop()


def test_run_details_diff_and_a_second_run_beside_the_first(runs: Path) -> None:
    server, dashboard, url = start_dashboard(runs)
    client = _connect(url, dashboard, 1)
    try:
        session = _session(dashboard)
        ids = sorted(p.name for p in runs.iterdir())
        client.set("Details of", ids[0])
        client.set("Diff with", ids[1])
        client.wait_for(lambda: "key(s) differ" in client.text(), what="the diff")
        text = client.text()
        assert "<code>seed</code> | 0 | 1" in text and "<code>model\\_name</code> | mlp | detach" in text
        assert "task_name: lh1" in text, "the config view"
        client.set("Filter", "detach")
        client.wait_for(lambda: "1 of 2 runs match the filter" in client.text(), what="the filter")
        client.set("Group by", "model")
        client.wait_for(lambda: "**model detach** (1 run)" in client.text(), what="the groups")
        client.set("Run", ids[0])
        client.set("Beside it", ids[1])
        client.wait_for(lambda: "b" in session.replay.episodes, what="run B's episode")
        view_b = session.replay.episodes["b"]
        assert view_b.num_frames == 12
        client.set("Camera follows", True)
        client.click("Step", "frame ▶")
        time.sleep(0.5)
        assert not session.replay.player.playing, "a step pauses"
    finally:
        client.close()
        server.stop()


def test_the_replay_lists_and_plays_each_trial_of_an_evaluation(runs: Path) -> None:
    """Issue 22 item 10: an evaluation records every trial as (episode, trial); the Episode
    dropdown lists each one and choosing a trial plays that trial, not trial 0 or another
    evaluation's episode."""
    run = sorted(runs.iterdir())[0]
    lengths = {0: 7, 1: 9, 2: 5}
    with RunLogWriter(run / "log.mcap", append=True) as log:
        for f in range(max(lengths.values())):  # all envs at once: trials interleave
            for trial, n in lengths.items():
                if f < n:
                    pos = np.full((15, 3), float(trial))
                    log.log_frame(EpisodeFrame(20, f, f / 30, list(BODY_NAMES), pos.tolist(),
                                               np.tile([1.0, 0, 0, 0], (15, 1)).tolist(),
                                               trial=trial))
    server, dashboard, url = start_dashboard(runs)
    client = _connect(url, dashboard, 1)
    try:
        replay = _session(dashboard).replay
        client.set("Run", run.name)
        client.wait_for(lambda: "20 · trial 2" in client.props("Episode")["options"],
                        what="the trials in the Episode dropdown")
        assert client.props("Episode")["options"] == [
            "newest", "0", "20 · trial 0", "20 · trial 1", "20 · trial 2"]
        for choice, trial in (("20 · trial 1", 1), ("20 · trial 0", 0), ("20 · trial 2", 2)):
            client.set("Episode", choice)
            client.wait_for(lambda: replay.episode is not None
                            and (replay.episode.number, replay.episode.trial) == (20, trial),
                            what=f"trial {trial}")
            assert replay.episode.num_frames == lengths[trial]
            assert np.allclose(replay.episode.pos, trial), "that trial's own frames"
        client.wait_for(lambda: f"episode 20, trial 2: {lengths[2]} frames" in client.text(),
                        what="the description")
        client.set("Episode", "0")
        client.wait_for(lambda: replay.episode.number == 0 and replay.episode.num_frames == 12,
                        what="the training episode")
    finally:
        client.close()
        server.stop()
