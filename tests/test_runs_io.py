"""Run folders, MCAP logs and evaluation statistics (pure I/O and math, no simulation)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from detach.config import resolve
from detach.eval.metrics import egr, mean_interval, sgr, success_rate, wilson_interval
from detach.runfolder.messages import EpisodeFrame, SceneMessage, SceneObject
from detach.runfolder.names import METRICS_TOPIC, TF_TOPIC
from detach.runfolder.folder import RunFolder, find_runs
from detach.runfolder.mcap_reader import iter_messages, read_episodes, read_metrics, read_scene
from detach.runs.mcap_log import RunLogWriter

ROOT = Path(__file__).resolve().parents[1]


def test_wilson_interval_known_values() -> None:
    low, high = wilson_interval(50, 100)
    assert low == pytest.approx(0.4038, abs=1e-3) and high == pytest.approx(0.5962, abs=1e-3)
    assert wilson_interval(0, 100)[0] == 0.0 and wilson_interval(0, 100)[1] > 0.0
    assert wilson_interval(100, 100)[1] == 1.0 and wilson_interval(100, 100)[0] < 1.0


def test_success_rate_partial_credit_uses_mean_interval() -> None:
    rate = success_rate([1.0, 0.5, 0.5, 0.0])
    assert rate.value == pytest.approx(0.5) and 0.0 <= rate.low < 0.5 < rate.high <= 1.0
    assert success_rate([]).n == 0
    mean, low, high = mean_interval([10.0, 12.0, 14.0])
    assert mean == pytest.approx(12.0) and low < 12.0 < high


def test_generalisation_rates_reproduce_the_paper() -> None:
    # Paper Table II, DETACH on LH2: Follow 1.00, Carry 0.96, Follow 0.67, Sit 0.16 -> SGR 0.08;
    # LH SR 0.70 against LH1's 0.72 -> EGR 0.97.
    plan = ["follow", "carry", "follow", "sit"]
    assert sgr(plan, [1.00, 0.96, 0.67, 0.16]) == pytest.approx(0.0816, abs=1e-3)
    assert sgr(["traj", "carry", "traj", "sit"], [1.00, 0.96, 0.67, 0.16]) == sgr(plan, [1.00, 0.96, 0.67, 0.16])
    assert egr(0.70, 0.72) == pytest.approx(0.97, abs=0.005)
    assert egr(0.5, 0.0) == 0.0


@pytest.fixture()
def cfg():
    return resolve(ROOT / "configs/tasks/lh1.yaml", "mlp", seed=4)


def test_run_folder_layout_and_states(tmp_path: Path, cfg) -> None:
    run = RunFolder.create(tmp_path, cfg, now=0)
    assert run.path.name.endswith("-lh1-mlp-s4")
    assert run.config() == cfg and run.checkpoints.is_dir()
    assert run.status().state == "queued"
    run.set_state("running", iteration=3)
    status = run.set_state("failed", error="RuntimeError: boom")
    assert status.state == "failed" and status.iteration == 3 and status.started
    assert status.error == "RuntimeError: boom" and run.status() == status
    with pytest.raises(ValueError):
        run.set_state("exploded")  # type: ignore[arg-type]
    again = RunFolder.create(tmp_path, cfg, now=0)
    assert again.path != run.path and again.path.name.endswith("-2")
    assert [r.path for r in find_runs(tmp_path)] == sorted([run.path, again.path])
    (run.checkpoints / "model_10.pt").write_bytes(b"x")
    (run.checkpoints / "model_9.pt").write_bytes(b"x")
    assert run.latest_checkpoint().name == "model_10.pt"
    assert not list(tmp_path.rglob(".*.json*")), "temporary files left behind"


def _write_log(path: Path, frames: int = 40) -> None:
    with RunLogWriter(path, flush_every=10) as log:
        log.log_scene(SceneMessage("t", [SceneObject("box", "Box", "Box/b/mesh.obj", [1, 2, 0.35], [1, 0, 0, 0],
                                                     [0.5, 0.5, 0.7], False)],
                                   {"0": [[0, 0], [1, 1]]}, [], ["pelvis", "torso"], []))
        for i in range(5):
            log.log_metrics(i, {"Train/mean_reward": i / 10, "Loss/value": 1.0 - i / 10}, stage="ppo")
        for f in range(frames):
            log.log_frame(EpisodeFrame(episode=f // 20, frame=f % 20, time=f / 30,
                                       bodies=["pelvis", "torso"], pos=[[0, 0, 0.9 + f], [0, 0, 1.2]],
                                       quat=[[1, 0, 0, 0], [1, 0, 0, 0]], subtask=f // 20, skill="follow"))


def test_mcap_round_trip_message_for_message(tmp_path: Path) -> None:
    path = tmp_path / "log.mcap"
    _write_log(path)
    metrics = read_metrics(path)
    assert [m["iteration"] for m in metrics] == list(range(5))
    assert metrics[3] == {"iteration": 3, "stage": "ppo", "Train/mean_reward": 0.3,
                          "Loss/value": pytest.approx(0.7)}
    assert read_scene(path).objects[0].name == "box"
    episodes = read_episodes(path)
    assert sorted(episodes) == [0, 1] and len(episodes[1]) == 20
    assert episodes[1][5]["pos"][0] == [0, 0, 25.9] and episodes[1][5]["subtask"] == 1
    tf = [m for topic, _t, m in iter_messages(path, [TF_TOPIC])]
    assert len(tf) == 40
    first = tf[0]["transforms"][0]
    assert first["child_frame_id"] == "pelvis" and first["rotation"]["w"] == 1


def test_truncated_mcap_is_readable_up_to_the_cut(tmp_path: Path) -> None:
    path = tmp_path / "log.mcap"
    _write_log(path)
    data = path.read_bytes()
    counts = []
    for fraction in (0.2, 0.4, 0.6, 0.8, 0.95):
        cut = tmp_path / f"cut_{fraction}.mcap"
        cut.write_bytes(data[: int(len(data) * fraction)])
        counts.append((len(read_metrics(cut)),
                       sum(len(v) for v in read_episodes(cut).values())))
    assert counts == sorted(counts), "a longer prefix never reads less"
    assert counts[-1] == (5, 40), "losing only the summary loses no message"
    assert any(0 < frames < 40 for _m, frames in counts), counts


def test_live_log_is_readable_before_close(tmp_path: Path) -> None:
    path = tmp_path / "log.mcap"
    log = RunLogWriter(path, flush_every=1000)
    log.log_metrics(0, {"Perf/total_fps": 100.0})
    log.log_metrics(1, {"Perf/total_fps": 120.0})
    assert [m["Perf/total_fps"] for m in read_metrics(path)] == [100.0, 120.0]
    log.close()
    assert json.loads(json.dumps(read_metrics(path)))[1]["iteration"] == 1


def test_append_keeps_earlier_messages(tmp_path: Path) -> None:
    path = tmp_path / "log.mcap"
    _write_log(path, frames=4)
    with RunLogWriter(path, append=True) as log:
        log.log_metrics(5, {"Train/mean_reward": 0.5})
    assert [m["iteration"] for m in read_metrics(path)] == [0, 1, 2, 3, 4, 5]
    assert read_scene(path).objects[0].name == "box"
    assert sum(len(v) for v in read_episodes(path).values()) == 4


def test_append_copies_earlier_messages_byte_for_byte(tmp_path: Path) -> None:
    """An evaluation or resume reopens the log with append=True, which copies every earlier
    message into a fresh file. It used to decode and re-encode each one as JSON: 128 of a
    climb run's 141 evaluation seconds went to that copy of its 247 MB log. The copy now
    passes each message's bytes through untouched (only /metrics is read, when a resume drops
    iterations), so a message in any JSON spelling survives exactly."""
    from mcap.reader import make_reader

    path = tmp_path / "log.mcap"
    _write_log(path, frames=2)
    spelled = b'{ "iteration": 9,  "stage": "joint", "Train/mean_reward": 1.50 }'
    with RunLogWriter(path, append=True) as log:
        log.write_raw(METRICS_TOPIC, spelled, 123)

    def payloads() -> list[tuple[str, int, bytes]]:
        with open(path, "rb") as f:
            return [(ch.topic, m.log_time, m.data) for _s, ch, m in make_reader(f).iter_messages(log_time_order=False)]

    before = payloads()
    with RunLogWriter(path, append=True):
        pass
    assert payloads() == before
    assert (METRICS_TOPIC, 123, spelled) in before
    with RunLogWriter(path, append=True, metrics_until=4):
        pass
    after = payloads()
    assert (METRICS_TOPIC, 123, spelled) not in after, "iteration 9 is past the resumed checkpoint"
    assert after == [p for p in before if p[2] != spelled]


def test_resumed_log_keeps_only_iterations_up_to_the_checkpoint(tmp_path: Path) -> None:
    """A run killed after logging iterations 0..4 with checkpoint 2 trains 3 and 4 again."""
    path = tmp_path / "log.mcap"
    _write_log(path, frames=4)
    with RunLogWriter(path, append=True, metrics_until=2) as log:
        for iteration in (3, 4, 5):
            log.log_metrics(iteration, {"Train/mean_reward": 1.0})
    assert [m["iteration"] for m in read_metrics(path)] == [0, 1, 2, 3, 4, 5]
    assert read_metrics(path)[3]["Train/mean_reward"] == 1.0, "the retrained iteration replaces the old"
    assert sum(len(v) for v in read_episodes(path).values()) == 4, "episodes are kept"
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_atomic_writer_leaves_the_old_file_or_the_new_one(tmp_path: Path) -> None:
    from detach.runfolder.atomic import atomic_writer

    target = tmp_path / "model_1.pt"
    target.write_bytes(b"old")
    with pytest.raises(OSError):
        with atomic_writer(target) as f:
            f.write(b"half of the new")
            raise OSError(28, "No space left on device")
    assert target.read_bytes() == b"old" and [p.name for p in tmp_path.iterdir()] == ["model_1.pt"]
    with atomic_writer(target) as f:
        f.write(b"new")
    assert target.read_bytes() == b"new" and [p.name for p in tmp_path.iterdir()] == ["model_1.pt"]


def test_status_names_its_host_and_survives_a_heartbeat(tmp_path: Path, cfg) -> None:
    import socket

    run = RunFolder.create(tmp_path, cfg, now=0)
    status = run.set_state("running", iteration=2)
    assert status.host == socket.gethostname() and status.pid
    before = status.updated
    run.heartbeat()
    after = run.status()
    assert after.updated >= before and after.iteration == 2 and after.state == "running"
