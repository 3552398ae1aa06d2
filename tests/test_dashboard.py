"""Dashboard without a browser: the incremental log reader, the run index (its 'unreadable'
reasons, lazy logs, round-robin re-checks), the humanoid's batched geometry, the replay clock
and the command line. Panels with a real viser server: tests/test_dashboard_sessions.py."""

from __future__ import annotations

import json
import random
import shutil
from pathlib import Path

import mujoco
import numpy as np
import pytest

from detach.character import build_character_model
from detach.character.body import BODY_NAMES
from detach.runfolder import log_tail
from detach.runfolder.log_tail import LogTail, closed_cleanly
from detach.runfolder.mcap_reader import read_episodes, read_metrics
from detach.runfolder.messages import BodyGeom, EpisodeFrame
from detach.runfolder.names import SCENE_TOPIC
from detach.runs.mcap_log import RunLogWriter
from server.cli import build_parser, main
from server.episode import load_episode
from server.launch import Launched, follow_output, launch_command
from server.replay import Player, Replay
from server.run_index import RunIndex
from server.run_views import runs_table
from server.scene_geometry import humanoid_instances, instance_poses
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
                    log.log_metrics(it, {"Train/mean_reward": it / 10, "Loss/value": 1 / (1 + it)})
                    it += 1


def _same_episode(tail: LogTail, path: Path, number: int) -> None:
    ref = read_episodes(path)[number]
    ep = load_episode(tail, number)
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
    assert tail.episode_numbers() == [0, 1, 2] and tail.newest_episode() == (2, 0)
    assert tail.episode_keys() == [(0, 0), (1, 0), (2, 0)]
    for n in (0, 1, 2):
        _same_episode(tail, path, n)
    assert load_episode(tail).number == 2
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
    log.log_metrics(0, {"Perf/total_fps": 100.0})
    tail.refresh()
    assert [m["Perf/total_fps"] for m in tail.metrics] == [100.0]
    for f in range(12):
        _frame(log, 0, f)
    log.log_metrics(1, {"Perf/total_fps": 120.0})  # flushes the frames too
    tail.refresh()
    assert [m["iteration"] for m in tail.metrics] == [0, 1]
    assert load_episode(tail).num_frames == 12
    for f in range(12, 20):
        _frame(log, 0, f)
    log.flush()
    assert tail.refresh()
    assert load_episode(tail).num_frames == 20, "the newest episode grows while it streams"
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
    assert load_episode(tail).num_frames == 40
    assert len(calls) <= frame_chunks / 6 + 2, "the newest episode needs only its own chunks"


def test_trials_recorded_side_by_side_are_episodes_of_their_own(tmp_path: Path) -> None:
    """An evaluation records all its envs at once: frames of several trials interleave and a
    chunk may hold no frame of one of them (cut between envs); the newest trial still loads
    whole, from its frame 0, and every trial is listed."""
    path = tmp_path / "log.mcap"
    lengths = {0: 9, 1: 14, 2: 5, 3: 11}
    with RunLogWriter(path, flush_every=3) as log:  # tiny chunks: many cut between envs
        for f in range(14):
            for trial, n in lengths.items():
                if f < n:
                    log.log_frame(EpisodeFrame(300, f, f / 30, BODIES, [[0.1 * f, trial, 0.9]] * 2,
                                               [[1, 0, 0, 0]] * 2, trial=trial))
    tail = LogTail(path)
    tail.refresh()
    assert tail.episode_keys() == [(300, t) for t in range(4)] and tail.episode_numbers() == [300]
    assert tail.newest_episode() == (300, 1)
    newest = load_episode(tail)
    assert (newest.number, newest.trial, newest.num_frames) == (300, 1, 14)
    np.testing.assert_allclose(newest.pos[:, 0, 1], 1.0)
    for trial, n in lengths.items():
        ep = load_episode(tail, (300, trial))
        assert ep.num_frames == n and np.allclose(ep.pos[:, 0, 1], trial)
    assert load_episode(tail, 300).trial == 0, "a number alone is its trial 0"


def test_tail_follows_a_log_rewritten_on_resume_and_concatenated_streams(tmp_path: Path) -> None:
    path = tmp_path / "log.mcap"
    with RunLogWriter(path) as log:
        log.log_metrics(0, {"Perf/total_fps": 1.0})
        for f in range(8):
            _frame(log, 0, f)
    tail = LogTail(path)
    tail.refresh()
    with RunLogWriter(path, append=True) as log:  # replaces the file (a new inode)
        log.log_metrics(1, {"Perf/total_fps": 2.0})
        for f in range(5):  # a second evaluation records episode 0 again
            _frame(log, 0, f)
    assert tail.refresh()
    assert [m["Perf/total_fps"] for m in tail.metrics] == [1.0, 2.0]
    assert tail.complete and tail.problem is None
    assert load_episode(tail, 0).num_frames == 5, "the latest recording of episode 0"
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
    data_end = data.rfind(b"\x0f" + (4).to_bytes(8, "little"))  # the DataEnd record
    assert data_end > 0
    mid = data_end // 2  # the data section's middle (the summary after it is not read)
    data[mid: mid + 64] = bytes(64)  # zeroes in the middle: a chunk or a record header
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    tail = LogTail(bad)
    tail.refresh()
    load_episode(tail)  # must not raise either
    assert tail.problem and tail.problem.startswith("bad.mcap: "), "the message names the file"
    for at in range(20, data_end, 97):  # zeroes anywhere in the data section: never an exception
        hit = bytearray(path.read_bytes())
        hit[at: at + 64] = bytes(64)
        bad.write_bytes(bytes(hit))
        tail = LogTail(bad)
        tail.refresh()
        tail.episode_keys()
        load_episode(tail)


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
    assert new.name in [i.run_id for i in index.refresh()] and index.changed == {new.name}
    shutil.rmtree(new)
    assert new.name not in [i.run_id for i in index.refresh()] and index.changed == {new.name}
    index.refresh()
    assert index.changed == set(), "nothing changed: nothing to redraw"
    assert not any(r.log_open for r in index.readers.values()), "logs are opened on demand"


def test_a_log_is_read_only_when_a_browser_opens_it_and_closed_after(runs: Path,
                                                                      monkeypatch) -> None:
    index = RunIndex(runs)
    scans = []
    real = LogTail.refresh
    monkeypatch.setattr(LogTail, "refresh", lambda self: scans.append(1) or real(self))
    index.refresh()
    index.refresh()
    assert scans == [], "finished runs' logs are checked from their first and last bytes"
    run = sorted(index.readers)[0]
    assert len(index.reader(run).series().iterations) == 6
    index.close_logs_except(set())
    assert not index.reader(run).log_open
    assert closed_cleanly(index.reader(run).path / "log.mcap")


def test_settled_runs_are_rechecked_round_robin_and_live_ones_every_time(runs: Path) -> None:
    for k in range(4):
        _copy_run(runs, f"20990101-00000{k}-lh1-mlp-s{k}")
    index = RunIndex(runs, settled_per_refresh=2)
    index.refresh()
    assert len(index.infos) == 6
    last = sorted(runs.iterdir())[-1]
    status = json.loads((last / "status.json").read_text())
    (last / "status.json").write_text(json.dumps({**status, "iteration": 77}))
    seen = []
    for _ in range(3):  # 6 settled runs, 2 per refresh: all of them within 3 refreshes
        index.refresh()
        seen.append(index.infos[last.name].iteration)
    assert 77 in seen
    (last / "status.json").write_text(json.dumps({**status, "state": "running"}))
    for _ in range(3):
        index.refresh()
    assert index.infos[last.name].live
    (last / "status.json").write_text(json.dumps({**status, "state": "running", "iteration": 78}))
    index.refresh()
    assert index.infos[last.name].iteration == 78, "a live run is re-read on every refresh"


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
        log.log_metrics(it, {"Train/mean_reward": float(it), **({"Episode_Success/follow": 0.5} if it % 2 else {})})
        index.refresh()
        seen.append(len(index.reader(run.name).series().iterations))
    log.log_metrics(3, {"Train/mean_reward": 30.0})  # a resumed run repeats an iteration
    index.refresh()
    series = index.reader(run.name).series()
    assert seen == list(range(1, 9))
    assert series.columns["Train/mean_reward"][3] == 30.0
    assert np.isnan(series.columns["Episode_Success/follow"][0]) and series.columns["Episode_Success/follow"][1] == 0.5
    log.close()


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
    inst = humanoid_instances([BodyGeom(**g) for g in geoms], BODY_NAMES)
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
    assert p.step(1) == 5 and p.step(-2) == 3 and not p.playing, "steps pause the replay"
    p.hold_at_end, p.loop, p.playing = False, False, True
    assert p.advance(10.0) == 19 and not p.playing, "without loop the replay stops at the end"


def test_a_second_episode_plays_on_the_same_clock() -> None:
    from server.episode import Episode

    def episode(frames: int) -> Episode:
        times = np.arange(frames) / 10
        return Episode(0, ["pelvis"], times, np.zeros((frames, 1, 3)), np.tile([1.0, 0, 0, 0],
                       (frames, 1, 1)), np.zeros(frames, int), ["follow"] * frames)

    drawn = []
    replay = Replay(lambda slot, ep, i: drawn.append((slot, i)))
    replay.set_episode("a", episode(10))
    replay.set_episode("b", episode(4))
    drawn.clear()
    replay.tick(0.25)
    assert sorted(drawn) == [("a", 2), ("b", 2)]
    drawn.clear()
    replay.tick(0.3)
    assert drawn == [("a", 5), ("b", 3)] or sorted(drawn) == [("a", 5), ("b", 3)], \
        "the shorter episode holds its last frame"
    replay.set_episode("a", None)
    assert replay.episode is None


def test_cli_binds_to_loopback_unless_exposed_and_rejects_bad_options(tmp_path: Path,
                                                                      capsys) -> None:
    args = build_parser().parse_args([])
    assert (args.host, args.port, args.expose, args.allow_launch) == ("127.0.0.1", 8080,
                                                                      False, False)
    assert build_parser().parse_args(["--expose"]).expose
    not_a_dir = tmp_path / "file"
    not_a_dir.write_text("x")
    for argv, said in ((["--runs", str(not_a_dir)], "is not a folder"),
                       (["--poll", "0"], "--poll 0.0 must be > 0"),
                       (["--launch-limit", "0"], "--launch-limit 0 must be at least 1"),
                       (["--port", "70000"], "--port 70000 must be 0..65535")):
        assert main(argv) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and said in err[0], err
    cmd = launch_command(Path("configs/tasks/lh1.yaml"), "detach", 3, tmp_path,
                         ["train.max_iterations=5", "sim.num_envs=8"])
    assert cmd[1:] == ["-m", "detach.cli", "train", "configs/tasks/lh1.yaml", "--model", "detach",
                       "--seed", "3", "--runs", str(tmp_path), "train.max_iterations=5",
                       "sim.num_envs=8"]


def test_launched_process_output_and_exit_code_are_shown(tmp_path: Path) -> None:
    import subprocess
    import sys
    from types import SimpleNamespace

    log_path = tmp_path / "console.log"
    with open(log_path, "w") as out:
        proc = subprocess.Popen([sys.executable, "-c", "print('hello'); raise SystemExit(3)"],
                                stdout=out, stderr=subprocess.STDOUT)
    shown = SimpleNamespace(content="")
    follow_output(Launched(proc, log_path, "-c ..."), shown)
    assert "exited with code 3" in shown.content and "hello" in shown.content


def test_the_index_parses_only_the_config_entries_it_shows(runs: Path) -> None:
    """The run summary the index shows (`detach.runfolder.summary`, once `server.run_index.
    _parse_config`): status.json's, else config.yaml's, in any YAML layout."""
    import yaml

    from detach.runfolder.files import parse_yaml
    from detach.runfolder.folder import RunFolder
    from detach.runfolder.messages import RunSummary
    from detach.runfolder.summary import read_config_summary, summary_of_config_data

    def parse(text: str) -> RunSummary:
        return summary_of_config_data(parse_yaml(text, "config.yaml"))

    for run in runs.iterdir():
        text = (run / "config.yaml").read_text()
        full = yaml.safe_load(text)
        for parsed in (parse(text), read_config_summary(run), RunFolder(run).summary()):
            assert (parsed.task, parsed.model, parsed.seed) == (full["task_name"], full["model_name"], full["seed"])
            assert parsed.samples_per_iteration == full["sim"]["num_envs"] * full["train"]["num_steps_per_env"]
    flow = "{task_name: lh2, model_name: cml, seed: 4, sim: {num_envs: 2}, train: {num_steps_per_env: 3}}"
    assert parse(flow) == RunSummary("lh2", "cml", 4, 6)
    with pytest.raises(ValueError, match="missing keys model_name"):
        parse("task_name: lh1\nseed: 0\n")
