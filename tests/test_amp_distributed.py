"""Multi-GPU training's extra all-reduces, on CPU: two processes (gloo) train AmpPPO on
different data from different initial weights; after `broadcast_parameters` and a few
iterations every rank holds the same actor, critic, discriminator and discriminator
normaliser (AMP and an auxiliary loss both update; rsl-rl's own path averages PPO's
gradients)."""

from __future__ import annotations

import os

import pytest
import torch
import torch.distributed as dist
import torch.multiprocessing as mp
from rsl_rl.runners import OnPolicyRunner

from tests.fakes import PointMassEnv
from tests.test_amp_ppo import reference, train_cfg

WORLD = 2


def _flat(alg) -> dict[str, torch.Tensor]:
    """Every tensor that must agree across ranks, flattened per module."""
    mods = {"actor": alg.actor, "critic": alg.critic, "disc": alg.discriminators}
    return {k: torch.cat([t.detach().float().flatten() for t in m.state_dict().values()]) for k, m in mods.items()}


def _same_on_all_ranks(x: torch.Tensor) -> bool:
    parts = [torch.empty_like(x) for _ in range(WORLD)]
    dist.all_gather(parts, x)
    return all(torch.equal(parts[0], p) for p in parts[1:])


def _worker(rank: int, store: str, out: str) -> None:
    torch.set_num_threads(1)
    dist.init_process_group("gloo", init_method=f"file://{store}", rank=rank, world_size=WORLD)
    try:
        torch.manual_seed(rank)  # different initial weights and data on each rank
        runner = OnPolicyRunner(PointMassEnv(), train_cfg(), log_dir=None, device="cpu")
        alg = runner.alg
        alg.is_multi_gpu, alg.gpu_global_rank, alg.gpu_world_size = True, rank, WORLD
        alg.reference_sampler = reference
        # an auxiliary loss on the actor whose gradient depends on this rank's data
        alg.aux_loss_fn = lambda obs, _stage: (alg.actor(obs).pow(2).mean(), {"aux": 0.0})
        before = _flat(alg)
        assert not _same_on_all_ranks(before["disc"]), "ranks start apart"
        alg.broadcast_parameters()
        start = _flat(alg)
        runner.learn(3)
        after = _flat(alg)
        result = {k: (_same_on_all_ranks(start[k]), _same_on_all_ranks(after[k]), not torch.equal(start[k], after[k]))
                  for k in start}
        torch.save(result, f"{out}.{rank}")
    finally:
        dist.destroy_process_group()


@pytest.mark.skipif(not dist.is_available(), reason="torch.distributed is not available")
def test_ranks_agree_after_broadcast_and_updates(tmp_path) -> None:
    os.environ.pop("WORLD_SIZE", None)
    out = str(tmp_path / "result")
    mp.spawn(_worker, args=(str(tmp_path / "store"), out), nprocs=WORLD, join=True)
    for rank in range(WORLD):
        result = torch.load(f"{out}.{rank}", weights_only=True)
        for module, (start, end, trained) in result.items():
            assert start and end and trained, (rank, module, start, end, trained)
