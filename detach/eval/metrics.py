"""The paper's evaluation metrics as pure functions over per-trial outcomes.

A trial of an LH task yields, per subtask, a score (1 success, 0 failure, 0.5 for a carry
whose box was grasped but not delivered) and an execution time in seconds (from the subtask's
start to the next subtask's start, a failure or the time-out). Rates come with confidence
intervals: Wilson's interval for 0/1 outcomes, a normal interval on the mean otherwise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from statistics import NormalDist
from typing import Sequence

from detach.skills import canonical_name


@dataclass(frozen=True)
class Rate:
    """A success rate with its confidence interval (all in [0, 1])."""

    value: float
    low: float
    high: float
    n: int



def _z(confidence: float) -> float:
    return NormalDist().inv_cdf(0.5 + confidence / 2.0)


def wilson_interval(successes: float, n: int, confidence: float = 0.95) -> tuple[float, float]:
    """Wilson score interval: well behaved at 0 and 1, unlike the normal approximation."""
    if n == 0:
        return 0.0, 1.0
    z = _z(confidence)
    p = successes / n
    denom = 1.0 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denom
    return max(0.0, centre - half), min(1.0, centre + half)


def success_rate(scores: Sequence[float], confidence: float = 0.95) -> Rate:
    """Mean score with a CI: Wilson for 0/1 scores, normal (clipped to [0, 1]) otherwise."""
    n = len(scores)
    if n == 0:
        return Rate(0.0, 0.0, 1.0, 0)
    mean = sum(scores) / n
    if all(s in (0.0, 1.0) for s in scores):
        low, high = wilson_interval(sum(scores), n, confidence)
    else:
        var = sum((s - mean) ** 2 for s in scores) / max(n - 1, 1)
        half = _z(confidence) * math.sqrt(var / n)
        low, high = max(0.0, mean - half), min(1.0, mean + half)
    return Rate(mean, low, high, n)


def mean_interval(values: Sequence[float], confidence: float = 0.95) -> tuple[float, float, float]:
    """(mean, low, high) with a normal interval; for execution times."""
    n = len(values)
    if n == 0:
        return math.nan, math.nan, math.nan
    mean = sum(values) / n
    var = sum((v - mean) ** 2 for v in values) / max(n - 1, 1)
    half = _z(confidence) * math.sqrt(var / n)
    return mean, mean - half, mean + half


def skill_rate(plan: Sequence[str], subtask_rates: Sequence[float], skill: str) -> float:
    """Success of a skill in a plan: its first occurrence, 0 when the plan lacks it. Names are
    compared as canonical skill names (`traj` of older files is follow).

    The first occurrence (not the mean over repeats) is what reproduces the paper's LH2 SGR
    (0.08 from Follow 1.00, Carry 0.96, Sit 0.16, no Climb).
    """
    want = canonical_name(skill)
    for s, rate in zip(plan, subtask_rates):
        if _canonical(s) == want:
            return rate
    return 0.0


def _canonical(name: str) -> str:
    try:
        return canonical_name(name)
    except ValueError:
        return name


LEARNED_SKILLS = ("follow", "carry")
"""The paper's foundational skills, trained fully (the denominator of SGR)."""
NOVEL_SKILLS = ("climb", "sit")
"""The paper's skills acquired compositionally (the numerator of SGR)."""


def sgr(plan: Sequence[str], subtask_rates: Sequence[float], variant: str = "reported") -> float:
    """Skill generalisation rate (variants: `detach.runfolder.eval_result.SGR_VARIANTS`).

    `formula`, as the paper prints it: ((S_climb + S_sit) / 2) / ((S_follow + S_carry) / 2),
    a skill the plan lacks counting 0. `reported`, what reproduces the paper's own values:
    the mean of the novel skills the plan has, over S_follow + S_carry (LH3 DETACH: (0.40 +
    0.10) / 2 / (1.00 + 0.95) = 0.13; the formula gives 0.26). Both agree on LH2.
    """
    learned = sum(skill_rate(plan, subtask_rates, s) for s in LEARNED_SKILLS)
    if learned <= 0:
        return 0.0
    if variant == "formula":
        return sum(skill_rate(plan, subtask_rates, s) for s in NOVEL_SKILLS) / learned
    if variant != "reported":
        raise ValueError(f"unknown SGR variant {variant!r}; expected reported or formula")
    present = [s for s in NOVEL_SKILLS if any(_canonical(p) == s for p in plan)]
    novel = sum(skill_rate(plan, subtask_rates, s) for s in present) / max(len(present), 1)
    return novel / learned


def egr(lh_rate: float, lh1_rate: float) -> float:
    """Environment generalisation rate S_Li / S_L1 (LH success on task i over LH1)."""
    return lh_rate / lh1_rate if lh1_rate > 0 else 0.0
