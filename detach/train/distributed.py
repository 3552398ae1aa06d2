"""Multi-GPU training with `torchrun --nproc_per_node=K detach-run ...`: one run across K GPUs.

rsl-rl's runner reads torchrun's environment (`WORLD_SIZE`, `RANK`, `LOCAL_RANK`), joins the
NCCL process group, broadcasts rank 0's actor and critic and averages PPO's gradients;
`AmpPPO` adds the discriminators and the auxiliary losses (`detach.train.amp_ppo`). Here: each
rank's device (`cuda:LOCAL_RANK`) and environment seed (`seed + RANK`, so that ranks collect
different experience); a worker rank (`detach.train.setup.train_worker`) writes nothing: only
rank 0 has a run folder, a log, checkpoints and the evaluation.
"""

from __future__ import annotations

import os

from detach.config import ConfigError


def world_size() -> int:
    return int(os.environ.get("WORLD_SIZE", "1"))


def rank() -> int:
    return int(os.environ.get("RANK", "0"))


def is_worker() -> bool:
    """A rank other than 0 of a torchrun launch: it trains but writes no run folder."""
    return world_size() > 1 and rank() > 0


def local_device(device: str) -> str:
    """The device of this rank: `cuda:LOCAL_RANK` under torchrun (what rsl-rl's runner
    expects), `device` otherwise."""
    if world_size() <= 1:
        return device
    if not str(device).startswith("cuda"):
        raise ConfigError(f"--device {device}: a torchrun launch ({world_size()} processes) trains on "
                          f"GPUs; use --device cuda")
    return f"cuda:{int(os.environ.get('LOCAL_RANK', '0'))}"

