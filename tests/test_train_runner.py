"""DetachRunner: stages, checkpoints into a folder, resume, and stopping on SIGTERM."""

from __future__ import annotations

import os
import signal
from pathlib import Path

import pytest
import torch

from detach.runs.mcap_log import RunLogWriter, read_metrics
from detach.train.runner import DetachRunner, StopRequested
from tests.fakes import PointMassEnv
from tests.test_amp_ppo import reference, train_cfg


def _runner(tmp_path: Path, schedule, log=None, **kw) -> DetachRunner:
    torch.manual_seed(0)
    cfg = train_cfg()
    cfg["save_interval"] = 2
    runner = DetachRunner(PointMassEnv(), cfg, schedule=schedule, checkpoint_dir=tmp_path,
                          log=log, progress=False, **kw)
    runner.alg.reference_sampler = reference
    return runner


def test_stages_metrics_and_checkpoints(tmp_path: Path) -> None:
    stages: list[str] = []
    log = RunLogWriter(tmp_path / "log.mcap")
    runner = _runner(tmp_path, [("pretrain", 1), ("fusion", 1), ("joint", 1)], log=log,
                     on_stage=stages.append)
    runner.learn(3)
    log.close()
    assert stages == ["pretrain", "fusion", "joint"]
    metrics = read_metrics(tmp_path / "log.mcap")
    assert [m["iteration"] for m in metrics] == [0, 1, 2]
    assert [m["stage"] for m in metrics] == ["pretrain", "fusion", "joint"]
    assert "loss/surrogate" not in metrics[0] and "loss/surrogate" in metrics[1]
    assert all(m["fps"] > 0 and "loss/amp/accuracy" in m for m in metrics)
    assert sorted(p.name for p in tmp_path.glob("model_*.pt")) == ["model_1.pt", "model_2.pt"]


def test_resume_continues_with_identical_optimiser_state(tmp_path: Path) -> None:
    first = _runner(tmp_path, [("ppo", 4)])
    first.learn(2)
    saved = torch.load(tmp_path / "model_1.pt", weights_only=False)
    assert saved["iter"] == 1
    second = _runner(tmp_path, [("ppo", 4)])
    assert second.load_checkpoint(tmp_path / "model_1.pt") == 2
    a = first.alg.optimizer.state_dict()
    b = second.alg.optimizer.state_dict()
    for key in a["state"]:
        for name, value in a["state"][key].items():
            assert torch.equal(value, b["state"][key][name]), (key, name)
    assert a["param_groups"][0]["lr"] == b["param_groups"][0]["lr"]
    seen: list[int] = []
    second.on_iteration = lambda it, _m: seen.append(it)
    second.learn(4)
    assert seen == [2, 3] and (tmp_path / "model_3.pt").exists()


def test_sigterm_checkpoints_then_stops(tmp_path: Path) -> None:
    before = signal.getsignal(signal.SIGTERM)
    runner = _runner(tmp_path, [("ppo", 50)])
    runner.on_iteration = lambda it, _m: it == 1 and os.kill(os.getpid(), signal.SIGTERM)
    with pytest.raises(StopRequested, match="SIGTERM"):
        runner.learn(50)
    assert runner.completed_iteration == 1
    assert (tmp_path / "model_1.pt").exists()
    assert signal.getsignal(signal.SIGTERM) is before, "the previous handler is restored"


@pytest.mark.parametrize("total,expected", [
    (1000, [("pretrain", 100), ("fusion", 400), ("joint", 500)]),
    (10, [("pretrain", 1), ("fusion", 4), ("joint", 5)]),
    (3, [("pretrain", 1), ("fusion", 1), ("joint", 1)]),
    (2, [("fusion", 1), ("joint", 1)]),
    (7, [("pretrain", 1), ("fusion", 3), ("joint", 3)]),
])
def test_stage_schedule_scales_and_keeps_every_stage(total, expected) -> None:
    from detach.config_schema import StagesCfg
    from detach.train.schedule import stage_at, stage_lengths

    schedule = stage_lengths(StagesCfg(100, 400, 500), total)
    assert schedule == expected and sum(k for _n, k in schedule) == total
    assert [stage_at(schedule, i) for i in range(total)][-1] == "joint"
    assert stage_lengths(StagesCfg(), 5) == [("ppo", 5)]
