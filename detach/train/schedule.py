"""Which training stage each PPO iteration belongs to.

DETACH's progressive protocol (paper, "Progressive Training Protocol") runs three stages:
`pretrain` (encoders alone), `fusion` (encoders frozen) and `joint` (everything, with
preservation regularisers). Other models run a single `ppo` stage. When a run is shorter than
the configured stage lengths (a quick CPU run), the stages are scaled proportionally so that
every stage still happens, in order.

A resumed run never changes its past: `resumed_stages` extends the last stage when
`train.max_iterations` grows, instead of rescaling a schedule that iterations already ran in.
"""

from __future__ import annotations

from detach.config.schema import RunConfig, StagesCfg
from detach.config.yaml_source import ConfigError

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


# ------------------------------------------------------------------------------ resuming
Schedule = list[tuple[str, int]]


def run_schedule(stages: StagesCfg, total: int, staged: bool) -> Schedule:
    """The schedule a run follows: DETACH's stages for a staged model, else one `ppo` stage."""
    return stage_lengths(stages, total) if staged else [("ppo", total)]


def extend_schedule(schedule: Schedule, total: int) -> Schedule:
    """The same schedule over `total` iterations: its last stage grows; a shorter total cuts
    stages from the end. Iterations before the end keep their stage (the past never changes)."""
    out: Schedule = []
    left = total
    for name, k in schedule:
        if left <= 0:
            break
        out.append((name, min(k, left)))
        left -= min(k, left)
    if left > 0:
        out[-1] = (out[-1][0], out[-1][1] + left)
    return out


def stages_of(schedule: Schedule) -> StagesCfg:
    """`train.stages` stating `schedule` explicitly (its lengths sum to the run's total, so
    `stage_lengths` returns it unscaled)."""
    lengths = dict.fromkeys(STAGE_NAMES, 0)
    for name, k in schedule:
        if name in lengths:
            lengths[name] += k
    return StagesCfg(**lengths)


def first_changed_iteration(old: Schedule, new: Schedule, completed: int) -> tuple[int, str, str] | None:
    """(iteration, old stage, new stage) of the first completed iteration (0..completed) that
    the new schedule puts in another stage, or None when the past is unchanged."""
    for iteration in range(completed + 1):
        before, after = stage_at(old, iteration), stage_at(new, iteration)
        if before != after:
            return iteration, before, after
    return None


def resumed_stages(old: RunConfig, new: RunConfig, completed: int, stated: bool) -> StagesCfg | None:
    """`train.stages` for a resumed run whose config changed from `old` to `new` after
    `completed` iterations (None for a model without stages).

    Unless the user `stated` a schedule, the old one is kept and its last stage extended (or
    cut from the end); written out explicitly, so that a longer `train.max_iterations` no
    longer rescales it. A stated schedule must keep the stage of every completed iteration."""
    if not old.model.staged:
        return None
    before = stage_lengths(old.train.stages, old.train.max_iterations)
    if not stated:
        return stages_of(extend_schedule(before, new.train.max_iterations))
    after = stage_lengths(new.train.stages, new.train.max_iterations)
    changed = first_changed_iteration(before, after, completed)
    if changed is not None:
        iteration, was, now = changed
        raise ConfigError(f"train.stages: the new schedule {_text(after)} puts iteration {iteration} in "
                          f"'{now}', but the run trained it in '{was}' ({_text(before)}); a resumed run "
                          f"may only change stages after iteration {completed}")
    return stages_of(after)


def _text(schedule: Schedule) -> str:
    return " + ".join(f"{name} {k}" for name, k in schedule)
