"""From per-trial outcomes to the `EvalResult` of eval.json (`detach.runfolder.eval_result`).

Subtask rates use the paper's definitions (carry: grasp only = 0.5). Two LH rates: `lh_mean`,
the mean of the subtask rates (the paper's), and `lh_chain`, every subtask in one episode.
The execution time runs from the start of the task to the completion of its last subtask, over
completed episodes (the paper's Time(s); our episodes are capped at `env.episode_length`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Sequence

from detach.eval.metrics import mean_interval, sgr, success_rate
from detach.runfolder.eval_result import SGR_VARIANTS, EvalResult, RateResult, SubtaskResult


@dataclass
class TrialOutcome:
    """One evaluation episode of a plan."""

    scores: list[float]
    """Per subtask: 1 success, 0 failure, 0.5 carry grasped only; 0 if never reached."""
    times: list[float] = field(default_factory=list)
    """Per subtask execution time in seconds; NaN for subtasks never started."""
    completed: bool = False
    """The whole skill sequence was completed (LH success)."""
    total_time: float = math.nan
    """Seconds from the start to plan completion, failure or time-out."""
    completion_time: float = math.nan
    """Seconds from the start to the completion of the last subtask (NaN if not completed)."""
    reached: list[bool] | None = None
    """Per subtask: the episode got to it (None: not recorded, as in fixtures)."""


def summarize(plan: Sequence[str], outcomes: Sequence[TrialOutcome], confidence: float = 0.95,
              task: str = "", model: str = "") -> EvalResult:
    """The evaluation of `outcomes` of `plan` (skill names) on `task` by `model`."""
    subtasks = []
    for i, skill in enumerate(plan):
        rate = success_rate([o.scores[i] for o in outcomes], confidence)
        times = [o.times[i] for o in outcomes if i < len(o.times) and not math.isnan(o.times[i])]
        mean_time = sum(times) / len(times) if times else None
        known = [o.reached[i] for o in outcomes if o.reached is not None and i < len(o.reached)]
        reached = sum(known) if outcomes and len(known) == len(outcomes) else None
        subtasks.append(SubtaskResult(rate.value, [rate.low, rate.high], rate.n, index=i, skill=skill,
                                      mean_time=mean_time, reached=reached))
    chain = success_rate([1.0 if o.completed else 0.0 for o in outcomes], confidence)
    mean = success_rate([sum(o.scores) / max(len(o.scores), 1) for o in outcomes], confidence)
    times = [o.completion_time for o in outcomes if not math.isnan(o.completion_time)]
    mean_time, low, high = mean_interval(times, confidence)
    rates = [s.rate for s in subtasks]
    return EvalResult(task=task, model=model, trials=len(outcomes), plan=list(plan), subtasks=subtasks,
                      lh_chain=RateResult(chain.value, [chain.low, chain.high], chain.n),
                      lh_mean=RateResult(mean.value, [mean.low, mean.high], mean.n),
                      sgr={v: sgr(plan, rates, v) for v in SGR_VARIANTS}, confidence=confidence,
                      mean_execution_time=None if math.isnan(mean_time) else mean_time,
                      execution_time_ci=None if math.isnan(mean_time) else [low, high],
                      trial_scores=[[float(v) for v in o.scores] for o in outcomes])
