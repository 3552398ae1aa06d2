"""Which training stage each PPO iteration belongs to.

DETACH's progressive protocol (paper, "Progressive Training Protocol") runs three stages:
`pretrain` (encoders alone), `fusion` (encoders frozen) and `joint` (everything, with
preservation regularisers). Other models run a single `ppo` stage. When a run is shorter than
the configured stage lengths (a quick CPU run), the stages are scaled proportionally so that
every stage still happens, in order.
"""

from __future__ import annotations

from detach.config_schema import StagesCfg

STAGE_NAMES = ("pretrain", "fusion", "joint")


def stage_lengths(stages: StagesCfg, total: int) -> list[tuple[str, int]]:
    """[(stage, iterations)] covering exactly `total` iterations."""
    lengths = [(n, getattr(stages, n)) for n in STAGE_NAMES if getattr(stages, n) > 0]
    if not lengths:
        return [("ppo", total)]
    configured = sum(k for _n, k in lengths)
    if configured == total:
        return lengths
    scaled = [[n, max(1, round(k * total / configured))] for n, k in lengths]
    # Fix rounding on the longest stages; keep every stage while there is room for it.
    while sum(k for _n, k in scaled) > total:
        longest = max(scaled, key=lambda nk: nk[1])
        if longest[1] > 1:
            longest[1] -= 1
        else:
            scaled.pop(0)  # fewer iterations than stages: the earliest stages go first
    while sum(k for _n, k in scaled) < total:
        max(scaled, key=lambda nk: nk[1])[1] += 1
    return [(n, k) for n, k in scaled]


def stage_at(schedule: list[tuple[str, int]], iteration: int) -> str:
    """Stage of a 0-based iteration; iterations past the schedule stay in the last stage."""
    end = 0
    for name, k in schedule:
        end += k
        if iteration < end:
            return name
    return schedule[-1][0]
