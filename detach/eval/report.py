"""From per-trial outcomes to the eval.json of a run folder.

eval.json (contract of ARCHITECTURE.md, "Run folder"):
{
  "task": "lh2", "trained_on": "lh1", "model": "detach", "seed": 0,
  "checkpoint": "checkpoints/model_500.pt", "trials": 100, "confidence": 0.95,
  "plan": ["traj", "carry", "traj", "sit"],
  "subtasks": [{"index": 0, "skill": "traj", "rate": 1.0, "ci": [0.96, 1.0], "n": 100,
                "mean_time": 12.1}, ...],
  "lh_success": {"rate": 0.7, "ci": [0.6, 0.78], "n": 100},
  "mean_execution_time": 85.0, "execution_time_ci": [80.1, 89.9],
  "sgr": 0.08
}
Subtask rates use the paper's definitions (carry: grasp only = 0.5); an execution time runs
from the subtask's start to the next subtask's start, a failure or the time-out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Sequence

from detach.eval.metrics import mean_interval, sgr, success_rate


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


def summarize(plan: Sequence[str], outcomes: Sequence[TrialOutcome], confidence: float = 0.95,
              **meta: Any) -> dict[str, Any]:
    """The eval.json dictionary for `outcomes` of `plan`; `meta` adds task/model/seed/..."""
    subtasks = []
    for i, skill in enumerate(plan):
        rate = success_rate([o.scores[i] for o in outcomes], confidence)
        times = [o.times[i] for o in outcomes if i < len(o.times) and not math.isnan(o.times[i])]
        mean_time = sum(times) / len(times) if times else None
        subtasks.append({"index": i, "skill": skill, **rate.to_json(), "mean_time": mean_time})
    lh = success_rate([1.0 if o.completed else 0.0 for o in outcomes], confidence)
    totals = [o.total_time for o in outcomes if not math.isnan(o.total_time)]
    mean_time, low, high = mean_interval(totals, confidence)
    return {**meta, "trials": len(outcomes), "confidence": confidence, "plan": list(plan),
            "subtasks": subtasks, "lh_success": lh.to_json(),
            "mean_execution_time": None if math.isnan(mean_time) else mean_time,
            "execution_time_ci": None if math.isnan(mean_time) else [low, high],
            "sgr": sgr(plan, [s["rate"] for s in subtasks])}
