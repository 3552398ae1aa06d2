"""Dashboard without a browser: the incremental log reader, the run index and its
'unreadable' reasons, panel contents, the humanoid's batched geometry, the replay clock and
the dashboard wired to a real (browserless) viser server."""

from __future__ import annotations

import json
import random
import shutil
import time
from pathlib import Path

import mujoco
import numpy as np
import pytest

from detach.character import build_character_model
from detach.character.body import BODY_NAMES
from detach.eval.tables import TABLES
from detach.run_contract import SCENE_TOPIC, EpisodeFrame
from detach.runs.mcap_log import RunLogWriter, read_episodes, read_metrics
from server import log_tail
from server.cli import build_parser, main
from server.launch import _follow, launch_command
from server.log_tail import LogTail
from server.replay import Player
from server.run_index import RunIndex
from server.scene_view import find_mesh, humanoid_instances, instance_poses
from server.views import comparison_tables, curve_groups, overlay, runs_table, short_id
from tests.dashboard_fixtures import humanoid_geoms, make_runs

BODIES = ["pelvis", "torso"]


def _frame(log: RunLogWriter, episode: int, frame: int) -> None:
    log.log_frame(EpisodeFrame(episode=episode, frame=frame, time=frame / 30, bodies=BODIES,
                               pos=[[0.1 * frame, 0, 0.9], [0.1 * frame, 0, 1.2]],
                               quat=[[1, 0, 0, 0], [1, 0, 0, 0]],
                               objects=[{"name": "box", "pos": [episode, frame, 0.35], "quat": [1, 0, 0, 0]}],
                               subtask=frame // 10, skill="follow"))


def _write_log(path: Path, episodes: int = 3, frames: int = 25, flush_every: int = 7) -> None:
    with RunLogWriter(path, flush_every=flush_every) as log:
        log.write(SCENE_TOPIC, {"objects": [], "trajectories": {}, "targets": []}, 0)
        it = 0
        for ep in range(episodes):
            for f in range(frames):
                _frame(log, ep, f)
                if f % 9 == 0:  # metrics interleaved with frames, as during evaluation
                    log.log_metrics(it, {"reward/mean": it / 10, "loss/value": 1 / (1 + it)})
                    it += 1


def _same_episode(tail: LogTail, path: Path, number: int) -> None:
    ref = read_episodes(path)[number]
    ep = tail.load_episode(number)
    assert ep is not None and ep.num_frames == len(ref)
    np.testing.assert_allclose(ep.pos, [m["pos"] for m in ref])
    np.testing.assert_allclose(ep.quat, [m["quat"] for m in ref])
    np.testing.assert_allclose(ep.times, [m["time"] for m in ref])
    np.testing.assert_allclose(ep.objects["box"][0], [m["objects"][0]["pos"] for m in ref])
    assert list(ep.subtask) == [m["subtask"] for m in ref]


# --- log_tail ----------------------------------------------------------------------------
def test_tail_matches_the_reference_reader(tmp_path: Path) -> None:
    path = tmp_path / "log.mcap"
    _write_log(path)
    tail = LogTail(path)
    assert tail.refresh() and tail.complete and tail.problem is None
    assert tail.metrics == read_metrics(path)
    assert tail.scene == {"objects": [], "trajectories": {}, "targets": []}
    assert tail.episode_numbers() == [0, 1, 2] and tail.newest_episode() == 2
    for n in (0, 1, 2):
        _same_episode(tail, path, n)
    assert tail.load_episode().number == 2
    assert not tail.refresh(), "nothing new: nothing to do"


def test_tail_on_a_file_growing_in_random_pieces(tmp_path: Path) -> None:
    """Appending arbitrary byte ranges (records cut anywhere) never raises or loses data."""
    full = tmp_path / "full.mcap"
    _write_log(full)
    data = full.read_bytes()
    live = tmp_path / "live.mcap"
    live.write_bytes(b"")
    tail, rng, at, counts = LogTail(live), random.Random(0), 0, []
    while at < len(data):
        at = min(len(data), at + rng.randint(1, 900))
        live.write_bytes(data[:at])
        tail.refresh()
        assert tail.problem is None, tail.problem
        counts.append((len(tail.metrics), len(tail.episode_numbers())))
    assert counts == sorted(counts)
    assert tail.metrics == read_metrics(full) and tail.complete
    for n in (0, 1, 2):
        _same_episode(tail, live, n)


def test_tail_follows_a_live_writer(tmp_path: Path) -> None:
    path = tmp_path / "log.mcap"
    log = RunLogWriter(path, flush_every=5)
    tail = LogTail(path)
    log.log_metrics(0, {"fps": 100.0})
    tail.refresh()
    assert [m["fps"] for m in tail.metrics] == [100.0]
    for f in range(12):
        _frame(log, 0, f)
    log.log_metrics(1, {"fps": 120.0})  # flushes the frames too
    tail.refresh()
    assert [m["iteration"] for m in tail.metrics] == [0, 1]
    assert tail.load_episode().num_frames == 12
    for f in range(12, 20):
        _frame(log, 0, f)
    log.flush()
    assert tail.refresh()
    assert tail.load_episode().num_frames == 20, "the newest episode grows while it streams"
    assert not tail.complete
    log.close()
    tail.refresh()
    assert tail.complete and tail.problem is None


def test_tail_skips_frame_chunks_until_an_episode_is_needed(tmp_path: Path, monkeypatch) -> None:
    path = tmp_path / "log.mcap"
    _write_log(path, episodes=6, frames=40, flush_every=5)
    calls = []
    real = log_tail._decompress
    monkeypatch.setattr(log_tail, "_decompress", lambda *a: calls.append(1) or real(*a))
    tail = LogTail(path)
    tail.refresh()
    frame_chunks = len(tail.chunks)
    assert frame_chunks >= 40
    metric_calls = len(calls)
    assert metric_calls < frame_chunks / 2, "frame-only chunks were decompressed"
    calls.clear()
    assert tail.load_episode().num_frames == 40
    assert len(calls) <= frame_chunks / 6 + 2, "the newest episode needs only its own chunks"


def test_tail_follows_a_log_rewritten_on_resume_and_concatenated_streams(tmp_path: Path) -> None:
    path = tmp_path / "log.mcap"
    with RunLogWriter(path) as log:
        log.log_metrics(0, {"fps": 1.0})
        for f in range(8):
            _frame(log, 0, f)
    tail = LogTail(path)
    tail.refresh()
    with RunLogWriter(path, append=True) as log:  # replaces the file (a new inode)
        log.log_metrics(1, {"fps": 2.0})
        for f in range(5):  # a second evaluation records episode 0 again
            _frame(log, 0, f)
    assert tail.refresh()
    assert [m["fps"] for m in tail.metrics] == [1.0, 2.0]
    assert tail.complete and tail.problem is None
    assert tail.load_episode(0).num_frames == 5, "the latest recording of episode 0"
    both = tmp_path / "both.mcap"
    both.write_bytes(path.read_bytes() + path.read_bytes())
    twice = LogTail(both)
    twice.refresh()
    assert len(twice.metrics) == 4 and twice.problem is None


def test_tail_reports_garbage_and_bad_chunks_without_raising(tmp_path: Path) -> None:
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"this is not an mcap file at all")
    tail = LogTail(junk)
    tail.refresh()
    assert "not an MCAP file" in tail.problem
    path = tmp_path / "log.mcap"
    _write_log(path, episodes=1)
    data = bytearray(path.read_bytes())
    mid = len(data) // 2
    data[mid: mid + 64] = bytes(64)  # zeroes in the middle: a chunk or a record header
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    tail = LogTail(bad)
    tail.refresh()
    tail.load_episode()  # must not raise either
    assert tail.problem and "log.mcap" in tail.problem


# --- run index -----------------------------------------------------------------------------
@pytest.fixture()
def runs(tmp_path: Path) -> Path:
    make_runs(tmp_path / "runs", broken=False, iterations=6, frames=12)
    return tmp_path / "runs"


def _copy_run(runs: Path, name: str) -> Path:
    src = sorted(runs.iterdir())[0]
    dst = runs / name
    shutil.copytree(src, dst)
    return dst


def test_unreadable_runs_name_their_reason(runs: Path) -> None:
    bad_status = _copy_run(runs, "20990101-000001-lh1-mlp-s1")
    (bad_status / "status.json").write_text('{"state": "runn')
    no_config = _copy_run(runs, "20990101-000002-lh1-mlp-s2")
    (no_config / "config.yaml").unlink()
    truncated = _copy_run(runs, "20990101-000003-lh1-mlp-s3")
    log = (truncated / "log.mcap").read_bytes()
    (truncated / "log.mcap").write_bytes(log[: int(len(log) * 0.7)])
    junk_log = _copy_run(runs, "20990101-000004-lh1-mlp-s4")
    (junk_log / "log.mcap").write_bytes(b"\x00" * 100)
    bad_eval = _copy_run(runs, "20990101-000005-lh1-mlp-s5")
    (bad_eval / "eval.json").write_text("{")
    infos = {i.run_id: i for i in RunIndex(runs).refresh()}
    reasons = {k: " ".join(v.problems) for k, v in infos.items()}
    assert "status.json unreadable" in reasons[bad_status.name]
    assert "config.yaml missing" in reasons[no_config.name]
    assert "truncated" in reasons[truncated.name] and "partial record" in reasons[truncated.name]
    assert "not an MCAP file" in reasons[junk_log.name]
    assert "eval.json unreadable" in reasons[bad_eval.name]
    healthy = [i for i in infos.values() if not i.unreadable]
    assert len(healthy) == 2 and all(i.lh_sr is not None and i.iteration == 5 for i in healthy)
    assert all(i.shown_state == "unreadable" for i in infos.values() if i.problems)
    table = runs_table(list(infos.values()))
    assert table.count("**unreadable**") == 5 and "config.yaml missing" in table


def test_a_live_truncated_log_is_fine_and_a_finished_one_is_not(runs: Path) -> None:
    run = sorted(runs.iterdir())[0]
    data = (run / "log.mcap").read_bytes()
    (run / "log.mcap").write_bytes(data[: len(data) - 200])
    status = json.loads((run / "status.json").read_text())
    (run / "status.json").write_text(json.dumps({**status, "state": "running"}))
    index = RunIndex(runs)
    assert not index.refresh()[0].unreadable, "a running run's log may end mid-record"
    (run / "status.json").write_text(json.dumps({**status, "state": "finished"}))
    assert "truncated" in index.refresh()[0].problems[0]


def test_refresh_reparses_only_changed_files_and_tracks_new_runs(runs: Path) -> None:
    index = RunIndex(runs)
    first = index.refresh()
    reader = index.reader(first[0].run_id)
    counts = {n: reader.parse_count(n) for n in ("config.yaml", "status.json", "eval.json")}
    version = first[0].log_version
    index.refresh()
    assert {n: reader.parse_count(n) for n in counts} == counts
    assert index.refresh()[0].log_version == version
    status = json.loads((reader.path / "status.json").read_text())
    (reader.path / "status.json").write_text(json.dumps({**status, "iteration": 99}))
    assert index.refresh()[0].iteration == 99
    assert reader.parse_count("status.json") == counts["status.json"] + 1
    assert reader.parse_count("config.yaml") == counts["config.yaml"]
    new = _copy_run(runs, "20990101-000000-lh1-detach-s7")
    assert new.name in [i.run_id for i in index.refresh()]
    shutil.rmtree(new)
    assert new.name not in [i.run_id for i in index.refresh()]


def test_metrics_appended_while_reading_reach_the_series(tmp_path: Path) -> None:
    make_runs(tmp_path / "runs", models=("mlp",), broken=False, iterations=3, frames=5)
    run = next((tmp_path / "runs").iterdir())
    (run / "log.mcap").unlink()
    status = json.loads((run / "status.json").read_text())
    (run / "status.json").write_text(json.dumps({**status, "state": "running"}))
    index = RunIndex(tmp_path / "runs")
    log = RunLogWriter(run / "log.mcap")
    seen = []
    for it in range(8):
        log.log_metrics(it, {"reward/mean": float(it), **({"success/follow": 0.5} if it % 2 else {})})
        index.refresh()
        seen.append(len(index.reader(run.name).series().iterations))
    log.log_metrics(3, {"reward/mean": 30.0})  # a resumed run repeats an iteration
    index.refresh()
    series = index.reader(run.name).series()
    assert seen == list(range(1, 9))
    assert series.columns["reward/mean"][3] == 30.0
    assert np.isnan(series.columns["success/follow"][0]) and series.columns["success/follow"][1] == 0.5
    log.close()


# --- views -----------------------------------------------------------------------------------
def test_tables_are_the_ones_of_detach_eval_tables(runs: Path) -> None:
    index = RunIndex(runs)
    index.refresh()
    evals = index.evals()
    assert len(evals) == 4  # eval.json + eval_lh3.json of two runs
    tables, errors = comparison_tables(evals)
    assert not errors
    for name, build in TABLES.items():
        assert tables[name].to_markdown() == build(evals).to_markdown()
        assert tables[name].to_csv() == build(evals).to_csv()
    assert len(tables["skills"].rows) == 2 and len(tables["ablation"].rows) == 2
    _tables, errors = comparison_tables([{"task": "lh1"}])  # malformed: reported, not raised
    assert errors


def test_curves_group_by_prefix_and_overlay_on_the_union_of_iterations(runs: Path) -> None:
    index = RunIndex(runs)
    infos = index.refresh()
    series = {i.run_id: index.reader(i.run_id).series() for i in infos}
    groups = curve_groups(series)
    assert list(groups)[0] == "general" and groups["general"] == ["fps"]
    assert groups["loss"] == ["loss/amp", "loss/surrogate", "loss/value"]
    assert {"reward", "success", "episode"} <= set(groups)
    a, b = list(series)
    series[b].iterations = series[b].iterations[::2] + 100
    series[b].columns = {k: v[::2] for k, v in series[b].columns.items()}
    c = overlay("reward/mean", series, {})
    assert len(c.x) == 6 + 3 and len(c.ys) == 2
    assert np.isnan(c.ys[0][-1]) and np.isnan(c.ys[1][0]) and not np.isnan(c.ys[1][-1])
    long = overlay("reward/mean", series, {}, max_points=4)
    assert len(long.x) <= 5 and long.x[-1] == c.x[-1]
    assert short_id(infos[0]) == infos[0].run_id.split("-lh1-")[0]


# --- 3D geometry and replay clock -----------------------------------------------------------
def test_batched_primitives_sit_where_mujoco_puts_the_geoms() -> None:
    model = build_character_model()
    data = mujoco.MjData(model)
    rng = np.random.default_rng(0)
    data.qpos[7:] = rng.uniform(-0.5, 0.5, model.nq - 7)
    data.qpos[3:7] = (0.9, 0.1, 0.2, 0.3) / np.linalg.norm((0.9, 0.1, 0.2, 0.3))
    mujoco.mj_kinematics(model, data)
    ids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, b) for b in BODY_NAMES]
    geoms = humanoid_geoms(model)
    inst = humanoid_instances(geoms, BODY_NAMES)
    kinds = [g["type"] for g in geoms]
    assert len(inst["cylinder"].bodies) == kinds.count("capsule")
    assert len(inst["sphere"].bodies) == kinds.count("sphere") + 2 * kinds.count("capsule")
    assert len(inst["box"].bodies) == kinds.count("box") == 2
    index = {k: np.array([BODY_NAMES.index(b) for b in v.bodies]) for k, v in inst.items()}
    pos, quat = data.xpos[ids], data.xquat[ids]
    world = {k: instance_poses(v, index[k], pos, quat) for k, v in inst.items()}
    geom_of = {"capsule": "cylinder", "box": "box"}
    for kind, name in geom_of.items():
        gids = [g for g in range(model.ngeom) if model.geom_bodyid[g] in ids
                and GEOM_NAME.get(int(model.geom_type[g])) == kind]
        np.testing.assert_allclose(world[name][0], data.geom_xpos[gids], atol=2e-4)
        rot = np.array([_mat(q) for q in world[name][1]])
        np.testing.assert_allclose(rot, data.geom_xmat[gids].reshape(-1, 3, 3), atol=2e-4)


GEOM_NAME = {int(mujoco.mjtGeom.mjGEOM_CAPSULE): "capsule",
             int(mujoco.mjtGeom.mjGEOM_SPHERE): "sphere", int(mujoco.mjtGeom.mjGEOM_BOX): "box"}


def _mat(q: np.ndarray) -> np.ndarray:
    out = np.zeros(9)
    mujoco.mju_quat2Mat(out, q / np.linalg.norm(q))
    return out.reshape(3, 3)


def test_player_plays_loops_holds_and_seeks() -> None:
    p = Player()
    p.load(np.arange(10) / 10)  # 10 frames, 0.9 s
    assert p.advance(0.25) == 2
    p.speed = 2.0
    assert p.advance(0.2) == 6
    assert p.advance(0.35) == 4, "0.65 s + 0.7 s wraps past the end (0.9 s) to 0.45 s"
    p.hold_at_end = True
    assert p.advance(5.0) == 9 and p.advance(1.0) == 9
    p.playing = False
    p.seek(4)
    assert p.advance(1.0) == 4
    p.load(np.arange(20) / 10, keep_time=True)
    assert p.frame == 4, "a growing live episode keeps the current time"


def test_missing_meshes_are_found_under_the_assets_root(tmp_path: Path, monkeypatch) -> None:
    mesh = tmp_path / "assets" / "chair" / "chair_v0" / "mesh.obj"
    mesh.parent.mkdir(parents=True)
    mesh.write_text("v 0 0 0\n")
    monkeypatch.setenv("DETACH_ASSETS", str(tmp_path / "assets"))
    assert find_mesh("/elsewhere/assets/chair/chair_v0/mesh.obj", tmp_path) == mesh
    assert find_mesh("/elsewhere/assets/chair/nothing/mesh.obj", tmp_path) is None
    assert find_mesh(None, tmp_path) is None


# --- the dashboard with a real viser server, no browser ---------------------------------
def test_dashboard_panels_follow_the_runs_folder(runs: Path) -> None:
    import viser

    from server.app import Dashboard

    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    try:
        d = Dashboard(server, runs)
        d.poll()
        ids = sorted(p.name for p in runs.iterdir())
        assert d.selected == [ids[-1]], "the newest run is selected at first"
        assert d.replay.episode is not None and d.replay.episode.num_frames == 12
        costs = []
        for i in range(60):
            t0 = time.perf_counter()
            d._draw_frame(d.replay.episode, i % 12)
            costs.append(time.perf_counter() - t0)
        assert np.median(costs) < 0.005, f"per-frame update {np.median(costs) * 1e3:.2f} ms"
        d.set_selection(ids)
        new = _copy_run(runs, "20990101-000000-lh1-cml-s3")
        (new / "status.json").write_text("{")
        d.poll()
        assert new.name in d.infos and d.infos[new.name].unreadable
    finally:
        server.stop()


def test_a_live_run_streams_its_newest_episode(tmp_path: Path) -> None:
    import viser

    from server.app import Dashboard

    make_runs(tmp_path / "runs", models=("mlp",), broken=False, iterations=2, frames=5)
    run = next((tmp_path / "runs").iterdir())
    scene = json.loads(json.dumps(log_tail_scene(run)))
    status = json.loads((run / "status.json").read_text())
    (run / "status.json").write_text(json.dumps({**status, "state": "running"}))
    log = RunLogWriter(run / "log.mcap", flush_every=5)
    log.write(SCENE_TOPIC, scene, 0)
    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    try:
        d = Dashboard(server, tmp_path / "runs")
        d.poll()
        assert d.replay.episode is None
        lengths = []
        for ep, frames in ((0, 10), (0, 20), (1, 5)):
            start = 0 if not lengths or ep != 0 else lengths[-1][1]
            for f in range(start, frames):
                _frame(log, ep, f)
            log.flush()
            d.poll()
            lengths.append((d.replay.episode.number, d.replay.episode.num_frames))
        assert lengths == [(0, 10), (0, 20), (1, 5)]
        assert d.replay.player.hold_at_end, "a live episode waits for its next frames"
        assert not d.infos[run.name].unreadable
    finally:
        log.close()
        server.stop()


def log_tail_scene(run: Path) -> dict:
    tail = LogTail(run / "log.mcap")
    tail.refresh()
    return tail.scene


def test_garbage_scene_and_frames_become_notes_not_crashes(tmp_path: Path) -> None:
    import viser

    from server.app import Dashboard

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
    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    try:
        d = Dashboard(server, tmp_path / "runs")
        d.poll()  # must not raise
        notes = " ".join(d.view.notes)
        assert "object 1" in notes and "object 2" in notes and "trajectory 0" in notes
        assert "body_geoms" in notes
        assert d.replay.episode is None, "non-finite poses are refused, not drawn"
    finally:
        server.stop()


def test_cli_binds_to_loopback_unless_exposed(tmp_path: Path) -> None:
    args = build_parser().parse_args([])
    assert (args.host, args.port, args.expose, args.allow_launch) == ("127.0.0.1", 8080,
                                                                      False, False)
    assert build_parser().parse_args(["--expose"]).expose
    not_a_dir = tmp_path / "file"
    not_a_dir.write_text("x")
    assert main(["--runs", str(not_a_dir)]) == 2
    cmd = launch_command(Path("configs/tasks/lh1.yaml"), "detach", 3, tmp_path,
                         "train.max_iterations=5 'sim.num_envs=8'")
    assert cmd[1:] == ["-m", "detach.cli", "configs/tasks/lh1.yaml", "--model", "detach",
                       "--seed", "3", "--out", str(tmp_path), "train.max_iterations=5",
                       "sim.num_envs=8"]
    with pytest.raises(ValueError):
        launch_command(Path("x.yaml"), "mlp", 0, tmp_path, "--dry-run")


def test_launched_process_output_and_exit_code_are_shown(tmp_path: Path) -> None:
    import subprocess
    import sys
    from types import SimpleNamespace

    log_path = tmp_path / "console.log"
    with open(log_path, "w") as out:
        proc = subprocess.Popen([sys.executable, "-c", "print('hello'); raise SystemExit(3)"],
                                stdout=out, stderr=subprocess.STDOUT)
    shown = SimpleNamespace(content="")
    _follow(proc, log_path, shown, "python -c ...")
    assert "exited with code 3" in shown.content and "hello" in shown.content
