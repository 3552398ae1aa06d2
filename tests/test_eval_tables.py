"""eval.json summaries and the paper's tables, from fixture outcomes."""

from __future__ import annotations

import math

import pytest

from detach.eval.report import TrialOutcome, summarize
from detach.eval.tables import ablation_table, generalization_table, skills_table
from detach.runfolder.eval_result import EvalResult


def _evals(task: str, model: str, plan: list[str], scores: list[list[float]],
           completed: list[bool], trained_on: str = "lh1") -> EvalResult:
    outcomes = [TrialOutcome(s, [10.0] * len(s), c, 40.0 if c else 60.0, 40.0 if c else math.nan)
                for s, c in zip(scores, completed)]
    result = summarize(plan, outcomes, task=task, model=model)
    result.seed, result.trained_on = 0, trained_on
    return EvalResult.from_json(result.to_json())  # as a table reads it back from eval.json


LH1 = ["follow", "carry", "climb", "sit"]
LH2 = ["traj", "carry", "traj", "sit"]  # the name older eval.json files used for follow


def test_summary_rates_times_and_partial_carry() -> None:
    e = _evals("lh1", "detach", LH1, [[1, 1, 1, 1], [1, 0.5, 0, 0], [1, 0, 0, 0],
                                      [0, 0, 0, 0]], [True, False, False, False])
    assert [s.rate for s in e.subtasks] == [0.75, 0.375, 0.25, 0.25]
    assert e.lh_chain.rate == 0.25 and e.trials == 4
    assert e.lh_mean.rate == pytest.approx((1 + 0.375 + 0.25 + 0) / 4)  # the mean of each trial's mean
    assert e.mean_execution_time == pytest.approx(40.0)  # completed episodes only
    assert e.subtasks[0].ci[0] < 0.75 < e.subtasks[0].ci[1]
    assert e.sgr["formula"] == pytest.approx((0.25 + 0.25) / (0.75 + 0.375))
    assert e.sgr["reported"] == pytest.approx((0.25 + 0.25) / 2 / (0.75 + 0.375))
    nan_times = summarize(LH1, [TrialOutcome([0, 0, 0, 0], [math.nan] * 4)])
    assert nan_times.subtasks[2].mean_time is None


def _fixture() -> list[EvalResult]:
    ok, bad = [1, 1, 1, 1], [1, 1, 0, 0]
    return [
        _evals("lh1", "tokenhsi", LH1, [ok, bad, bad, bad], [True, False, False, False]),
        _evals("lh1", "detach", LH1, [ok, ok, bad, bad], [True, True, False, False]),
        _evals("lh2", "detach", LH2, [ok, ok, bad, bad], [True, False, False, False]),
        _evals("lh2", "tokenhsi", LH2, [bad, bad, bad, bad], [False] * 4),
    ]


def test_skills_table_markdown_layout() -> None:
    md = skills_table(_fixture()).to_markdown()
    lines = md.strip().splitlines()
    assert lines[2] == "| Method | Follow | Carry | Climb | Sit | LH1 (mean) | LH1 (chain) | n |"
    assert lines[4].startswith("| TokenHSI | 1.00 [") and lines[5].startswith("| DETACH |")
    assert lines[5].split(" | ")[-2].startswith("0.50 [") and lines[5].endswith("| 4 (1 seed: s0) |")


def test_generalization_table_egr_uses_lh1_of_same_model() -> None:
    table = generalization_table(_fixture())
    rows = {r[1]: r for r in table.rows}
    egr = table.keys.index("egr")
    detach = rows["DETACH"]
    assert detach[0] == "LH2" and detach[5].text() == "-"  # LH2 has no climb
    assert detach[egr].value == pytest.approx(0.75 / 0.75)  # EGR = LH2 (mean) / LH1 (mean), same model
    assert rows["TokenHSI"][egr].value == pytest.approx(0.5 / 0.625)
    csv_text = table.to_csv()
    assert csv_text.splitlines()[0].startswith("experiment,method,follow,carry,follow_2,climb,sit")
    assert "\\begin{tabular}" in table.to_latex()


def test_ablation_table_rows() -> None:
    evals = [_evals("lh1", m, LH1, [[1, 1, 1, 1]] * 2, [True, True]) for m in
             ("detach", "ablation_a1")]
    evals += [_evals("lh3", m, ["traj", "carry", "traj", "climb", "sit"],
                     [[1, 1, 1, 1, r]] * 2, [bool(r)] * 2)
              for m, r in (("detach", 1), ("ablation_a1", 0))]
    md = ablation_table(evals).to_markdown().splitlines()
    assert md[2] == "| Method | EGR | SGR | LH (mean) | LH (chain) | n |"
    assert md[4].startswith("| A1 (w/o env encoder) | 0.80 |")
    assert md[5].startswith("| DETACH | 1.00 | 0.500 |")  # SGR "reported": mean(climb, sit) / 2


def test_the_composition_readings_substitutes_are_named_beside_their_baselines() -> None:
    ok = [1, 1, 1, 1]
    results = [_evals("lh1", model, LH1, [ok], [True]) for model in ("detach", "tokenhsi_adapt", "cml_incremental")]
    assert [r[0] for r in skills_table(results).rows] == ["CML (incremental)", "TokenHSI (adapters)", "DETACH"]


def test_a_subtask_few_trials_reached_says_so_in_the_table_and_csv() -> None:
    """Zero-shot Climb at 0.00 means little when no trial got to Climb: the table says how
    many trials reached each subtask, where some did not."""
    outcomes = [TrialOutcome([1, 1, 0, 0], [5.0, 9.0, 3.0, math.nan], reached=[True, True, True, False]),
                TrialOutcome([1, 0, 0, 0], [5.0, 9.0, math.nan, math.nan], reached=[True, True, False, False])]
    result = summarize(LH1, outcomes, task="lh1", model="detach")
    result.seed, result.trained_on = 0, "lh1"
    back = EvalResult.from_json(result.to_json())
    assert [s.reached for s in back.subtasks] == [2, 2, 1, 0]
    table = skills_table([back])
    md = table.to_markdown()
    assert "0.00 [0.00, 0.66] (reached 1/2)" in md and "(reached 0/2)" in md
    assert "1.00 [0.34, 1.00] |" in md  # every trial reached Follow: nothing added
    header, row = table.to_csv().splitlines()[:2]
    reached = dict(zip(header.split(","), row.split(",")))
    assert (reached["follow_reached"], reached["climb_reached"], reached["sit_reached"]) == ("2", "1", "0")
