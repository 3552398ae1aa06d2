"""DetachRunner: stages, checkpoints into a folder, resume, and stopping on SIGTERM."""

from __future__ import annotations

import os
import signal
from pathlib import Path

import pytest
import torch

from detach.runfolder.mcap_reader import read_metrics
from detach.runs.mcap_log import RunLogWriter
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
    assert "Loss/surrogate" not in metrics[0] and "Loss/surrogate" in metrics[1]
    assert all(m["Perf/total_fps"] > 0 and "Loss/amp/accuracy" in m for m in metrics)
    assert sorted(p.name for p in tmp_path.glob("model_*.pt")) == ["model_1.pt", "model_2.pt"]


def test_resume_continues_with_identical_optimiser_state(tmp_path: Path) -> None:
    first = _runner(tmp_path, [("ppo", 4)])
    first.learn(2)
    saved = torch.load(tmp_path / "model_1.pt", weights_only=True)
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
    from detach.config.schema import StagesCfg
    from detach.train.schedule import stage_at, stage_lengths

    schedule = stage_lengths(StagesCfg(100, 400, 500), total)
    assert schedule == expected and sum(k for _n, k in schedule) == total
    assert [stage_at(schedule, i) for i in range(total)][-1] == "joint"
    assert stage_lengths(StagesCfg(), 5) == [("ppo", 5)]


# ---------------------------------------------------------------------------- reliability
def test_a_resumed_run_is_the_run_that_would_have_happened(tmp_path: Path) -> None:
    """Weights, optimisers, normalisers, discriminator, AMP replay buffer and random state all
    come back: from the same environment state, the resumed run trains bit-identically."""
    import copy

    import shutil

    first = _runner(tmp_path, [("ppo", 4)])
    first.learn(2)  # checkpoint model_1.pt (save_interval 2)
    saved = tmp_path / "saved"
    shutil.copytree(tmp_path, saved, ignore=shutil.ignore_patterns("saved"))  # model_3 prunes this sidecar
    env_at_checkpoint = copy.deepcopy(first.env)
    replay_at_checkpoint = first.alg.replay.state_dict()
    draws: list[torch.Tensor] = []
    first.on_iteration = lambda it, m: draws.append(torch.tensor(m["Loss/surrogate"]))
    first.learn(4)

    torch.manual_seed(1234)  # another random state and another initialisation
    second = DetachRunner(env_at_checkpoint, {**train_cfg(), "save_interval": 2}, schedule=[("ppo", 4)],
                          checkpoint_dir=tmp_path / "second", progress=False)
    second.alg.reference_sampler = reference
    assert second.load_checkpoint(saved / "model_1.pt") == 2
    restored = second.alg.replay.state_dict()
    assert restored["size"] == replay_at_checkpoint["size"] > 0
    assert torch.equal(restored["obs"], replay_at_checkpoint["obs"])
    again: list[torch.Tensor] = []
    second.on_iteration = lambda it, m: again.append(torch.tensor(m["Loss/surrogate"]))
    second.learn(4)
    assert torch.equal(torch.stack(draws), torch.stack(again))
    for a, b in zip(first.alg.actor.parameters(), second.alg.actor.parameters(), strict=True):
        assert torch.equal(a, b)


def test_random_states_round_trip_through_a_checkpoint(tmp_path: Path) -> None:
    import random

    import numpy as np

    runner = _runner(tmp_path, [("ppo", 2)])
    runner.env.gen = torch.Generator().manual_seed(7)
    runner.learn(2)
    expected = (random.random(), float(np.random.rand()), torch.rand(3), torch.rand(2, generator=runner.env.gen))
    random.seed(99), np.random.seed(99), torch.manual_seed(99), runner.env.gen.manual_seed(99)
    runner.load_checkpoint(tmp_path / "model_1.pt")
    assert random.random() == expected[0] and float(np.random.rand()) == expected[1]
    assert torch.equal(torch.rand(3), expected[2])
    assert torch.equal(torch.rand(2, generator=runner.env.gen), expected[3])


def test_resuming_inside_a_stage_does_not_enter_it_again(tmp_path: Path) -> None:
    calls: list[tuple[str, bool]] = []

    def record(stage: str, resumed: bool = False) -> None:
        calls.append((stage, resumed))

    schedule = [("pretrain", 1), ("fusion", 2), ("joint", 1)]
    _runner(tmp_path, schedule, on_stage=record).learn(2)  # checkpoint inside fusion
    assert calls == [("pretrain", False), ("fusion", False)]
    calls.clear()
    resumed = _runner(tmp_path, schedule, on_stage=record)
    resumed.load_checkpoint(tmp_path / "model_1.pt")
    resumed.learn(4)
    assert calls == [("fusion", True), ("joint", False)]


def test_detach_stage_hook_keeps_the_anchors_of_a_resumed_fusion_stage() -> None:
    from types import SimpleNamespace

    from detach.train.setup import _stage_hook

    class Trunk:
        owns_trunk = True

        def __init__(self) -> None:
            self.events: list[str] = []

        def snapshot_encoders(self) -> None:
            self.events.append("snapshot")

        def freeze_encoders(self) -> None:
            self.events.append("freeze")

        def unfreeze_encoders(self) -> None:
            self.events.append("unfreeze")

    actor = Trunk()
    on_stage, _models = _stage_hook(SimpleNamespace(alg=SimpleNamespace(actor=actor, critic=object())))
    on_stage("fusion", resumed=True)
    assert actor.events == ["freeze"], "the anchors come from the checkpoint; encoders stay frozen"
    on_stage("fusion")
    assert actor.events == ["freeze", "snapshot", "freeze"]


def test_a_checkpoint_from_another_schedule_is_refused(tmp_path: Path) -> None:
    from detach.train.checkpoints import CheckpointError

    _runner(tmp_path, [("pretrain", 1), ("fusion", 2), ("joint", 1)]).learn(2)  # it 1 in fusion
    rescaled = _runner(tmp_path, [("pretrain", 2), ("fusion", 2), ("joint", 4)])
    with pytest.raises(CheckpointError, match="iteration 1 was trained in stage 'fusion', but this run's schedule "
                                              "puts it in 'pretrain'"):
        rescaled.load_checkpoint(tmp_path / "model_1.pt")


def test_loading_never_unpickles(tmp_path: Path) -> None:
    """rsl-rl's OnPolicyRunner.load uses weights_only=False; ours refuses such a file."""
    import builtins

    from detach.train.checkpoints import CheckpointError

    marker = tmp_path / "code-ran"

    class CodeOnLoad:
        def __reduce__(self):
            return builtins.open, (str(marker), "w")

    runner = _runner(tmp_path, [("ppo", 2)])
    runner.learn(2)
    state = torch.load(tmp_path / "model_1.pt", weights_only=True)
    state["infos"]["payload"] = CodeOnLoad()
    torch.save(state, tmp_path / "model_1.pt")
    with pytest.raises(CheckpointError, match="refused"):
        _runner(tmp_path, [("ppo", 2)]).load(str(tmp_path / "model_1.pt"))
    assert not marker.exists()


def test_checkpoints_of_another_architecture_fail_in_one_line(tmp_path: Path) -> None:
    from detach.train.checkpoints import CheckpointError

    _runner(tmp_path, [("ppo", 2)]).learn(2)
    cfg = train_cfg()
    cfg["actor"] = {**cfg["actor"], "hidden_dims": [16]}
    torch.manual_seed(0)
    other = DetachRunner(PointMassEnv(), cfg, checkpoint_dir=tmp_path / "other", progress=False)
    with pytest.raises(CheckpointError) as caught:
        other.load_checkpoint(tmp_path / "model_1.pt")
    message = str(caught.value)
    assert "\n" not in message and "does not fit this run's model" in message
    assert "actor:" in message and "of another shape" in message
