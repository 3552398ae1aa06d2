"""eval.json / eval_<task>.json: the evaluation of one checkpoint on one task, and the
checks every reader applies (`implausible`: numbers that follow the format but cannot be)."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

from detach.runfolder.messages import ContractError, need_key, need_number
from detach.runfolder.names import EVAL_FILE


# ------------------------------------------------------------------------------- eval.json
@dataclass
class RateResult:
    """A success rate with its confidence interval (all in [0, 1]) over n trials."""

    rate: float
    ci: list[float]
    n: int

    @classmethod
    def from_json(cls, data: Any, where: str) -> "RateResult":
        rate = need_number(data, "rate", where)
        if not 0.0 <= rate <= 1.0:
            raise ContractError(f"{where}: 'rate' must be in [0, 1], found {rate}")
        ci = need_key(data, "ci", list, where)
        if len(ci) != 2 or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                                   and 0.0 <= v <= 1.0 for v in ci) or ci[0] > ci[1]:
            raise ContractError(f"{where}: 'ci' must be two numbers 0 <= low <= high <= 1, found {ci!r:.60}")
        n = need_key(data, "n", int, where)
        if n < 0:
            raise ContractError(f"{where}: 'n' must be >= 0, found {n}")
        return cls(rate, [float(ci[0]), float(ci[1])], int(n))


@dataclass
class SubtaskResult(RateResult):
    index: int = 0
    skill: str = ""
    mean_time: float | None = None
    """Mean execution time (s) of the subtask over the trials that completed it."""
    reached: int | None = None
    """Trials that got to this subtask (None in files of earlier versions): a subtask no trial
    reached has no measured rate, whatever its 0.00 says."""

    def to_json(self) -> dict[str, Any]:
        return {"index": self.index, "skill": self.skill, "rate": self.rate, "ci": self.ci, "n": self.n,
                "mean_time": self.mean_time, "reached": self.reached}


SGR_VARIANTS: tuple[str, ...] = ("reported", "formula")
"""Skill generalisation rate: `formula` = ((S_climb + S_sit) / 2) / ((S_follow + S_carry) / 2)
as the paper prints it; `reported` = mean of the novel skills the plan has / (S_follow +
S_carry), which reproduces the values the paper reports (e.g. its LH3 0.13). The default is
the first."""


@dataclass
class EvalResult:
    """eval.json / eval_<task>.json: the evaluation of one checkpoint on one task."""

    task: str
    model: str
    trials: int
    plan: list[str]
    subtasks: list[SubtaskResult]
    lh_chain: RateResult
    """Every subtask of the plan succeeded in the same episode."""
    lh_mean: RateResult
    """The mean of the subtask rates (the paper's LH success): the mean over trials of each
    trial's mean subtask score, with a normal interval."""
    sgr: dict[str, float]
    """Skill generalisation rate per variant (`SGR_VARIANTS`)."""
    confidence: float = 0.95
    trained_on: str | None = None
    seed: int | None = None
    checkpoint: str | None = None
    iteration: int | None = None
    mean_execution_time: float | None = None
    """Mean time (s) from the start of the task to the completion of its last subtask, over the
    episodes that completed the whole plan (None when none did)."""
    execution_time_ci: list[float] | None = None
    trial_scores: list[list[float]] | None = None
    """Per trial, every subtask's score: what tables pool across seeds."""
    trial_set: str = "development"
    """Which trials were played (`detach.eval.trial_sets`): development (files of earlier
    versions, which all played the run's own seed) or test."""
    trial_seed: int | None = None
    """The evaluation env's seed (None in files of earlier versions: the run's seed)."""
    aids: list[str] | None = None
    """What the run used that the paper's recipe does not (`detach.eval.aids`; None in files
    of earlier versions: unknown, tables then read the run's config)."""

    @property
    def lh_success(self) -> RateResult:
        """The strict LH success (`lh_chain`), by its name in files of earlier versions."""
        return self.lh_chain

    def to_json(self) -> dict[str, Any]:
        return {"task": self.task, "trained_on": self.trained_on, "model": self.model, "seed": self.seed,
                "checkpoint": self.checkpoint, "iteration": self.iteration, "trials": self.trials,
                "confidence": self.confidence, "plan": list(self.plan),
                "subtasks": [s.to_json() for s in self.subtasks],
                "lh_mean": asdict(self.lh_mean), "lh_chain": asdict(self.lh_chain),
                "mean_execution_time": self.mean_execution_time, "execution_time_ci": self.execution_time_ci,
                "sgr": dict(self.sgr), "trial_scores": self.trial_scores, "trial_set": self.trial_set,
                "trial_seed": self.trial_seed, "aids": self.aids}

    @classmethod
    def from_json(cls, data: Any, where: str = EVAL_FILE) -> "EvalResult":
        subtasks = []
        for i, s in enumerate(need_key(data, "subtasks", list, where)):
            w = f"{where}: subtasks[{i}]"
            r = RateResult.from_json(s, w)
            subtasks.append(SubtaskResult(r.rate, r.ci, r.n, index=int(need_key(s, "index", int, w)),
                                          skill=str(need_key(s, "skill", str, w)),
                                          mean_time=need_number(s, "mean_time", w, optional=True),
                                          reached=need_key(s, "reached", int, w, optional=True)))
        plan = [str(p) for p in need_key(data, "plan", list, where)]
        ci = data.get("execution_time_ci") if isinstance(data, dict) else None
        chain_key = "lh_chain" if "lh_chain" in data else "lh_success"  # its name before the two LH rates
        lh_chain = RateResult.from_json(need_key(data, chain_key, dict, where), f"{where}: {chain_key}")
        if "lh_mean" in data:
            lh_mean = RateResult.from_json(need_key(data, "lh_mean", dict, where), f"{where}: lh_mean")
        else:  # an older file: the mean of its subtask rates, without an interval of its own
            mean = sum(s.rate for s in subtasks) / max(len(subtasks), 1)
            lh_mean = RateResult(mean, [mean, mean], lh_chain.n)
        sgr = data.get("sgr")
        if isinstance(sgr, (int, float)) and not isinstance(sgr, bool):
            sgr = {"formula": float(sgr)}
        if not isinstance(sgr, dict) or not all(isinstance(v, (int, float)) for v in sgr.values()):
            raise ContractError(f"{where}: 'sgr' must map variants ({', '.join(SGR_VARIANTS)}) to numbers")
        scores = data.get("trial_scores")
        if scores is not None and not (isinstance(scores, list) and all(
                isinstance(t, list) and len(t) == len(plan) and all(isinstance(v, (int, float)) for v in t)
                for t in scores)):
            raise ContractError(f"{where}: 'trial_scores' must be one list of {len(plan)} numbers per trial")
        return cls(task=str(need_key(data, "task", str, where)), model=str(need_key(data, "model", str, where)),
                   trials=int(need_key(data, "trials", int, where)), plan=plan, subtasks=subtasks,
                   lh_chain=lh_chain, lh_mean=lh_mean, sgr={str(k): float(v) for k, v in sgr.items()},
                   trial_scores=scores,
                   confidence=float(need_number(data, "confidence", where, optional=True) or 0.95),
                   trained_on=need_key(data, "trained_on", str, where, optional=True),
                   seed=need_key(data, "seed", int, where, optional=True),
                   checkpoint=need_key(data, "checkpoint", str, where, optional=True),
                   iteration=need_key(data, "iteration", int, where, optional=True),
                   mean_execution_time=need_number(data, "mean_execution_time", where, optional=True),
                   execution_time_ci=[float(v) for v in ci] if isinstance(ci, list) else None,
                   trial_set=_trial_set(data, where),
                   trial_seed=need_key(data, "trial_seed", int, where, optional=True),
                   aids=_aids(data, where))


def _trial_set(data: Any, where: str) -> str:
    value = data.get("trial_set", "development") if isinstance(data, dict) else "development"
    if value not in ("development", "test"):
        raise ContractError(f"{where}: 'trial_set' must be 'development' or 'test', found {value!r}")
    return str(value)


def _aids(data: Any, where: str) -> list[str] | None:
    value = data.get("aids") if isinstance(data, dict) else None
    if value is not None and not (isinstance(value, list) and all(isinstance(a, str) for a in value)):
        raise ContractError(f"{where}: 'aids' must be a list of names")
    return value




def implausible(result: EvalResult) -> str | None:
    """Why numbers that follow the contract are still impossible (None when they are fine):
    no trials, or a statistic that is not a finite number."""
    if result.trials < 1:
        return f"'trials' must be >= 1, found {result.trials}"
    sgr = result.sgr.values() if isinstance(result.sgr, dict) else [result.sgr]
    numbers = {"sgr": list(sgr), "mean_execution_time": [result.mean_execution_time],
               "execution_time_ci": list(result.execution_time_ci or [])}
    for key, values in numbers.items():
        if any(v is not None and not (isinstance(v, (int, float)) and math.isfinite(v)) for v in values):
            return f"'{key}' is not a finite number"
    return None
