"""The paper's metrics reproduced from the paper's own numbers, through the evaluation format
(eval.json) and the table code that `detach-run table` uses."""

from __future__ import annotations

import json

import pytest

from detach.eval import metrics
from detach.eval.tables import generalization_table, skills_table
from detach.runfolder.eval_result import EvalResult, RateResult, SubtaskResult


def evaluation(task: str, model: str, plan: list[str], rates: list[float], n: int = 100) -> EvalResult:
    """An eval.json whose trials have exactly these subtask rates (n trials, 0/1 scores)."""
    trials = [[1.0 if t < round(r * n) else 0.0 for r in rates] for t in range(n)]
    subtasks = [SubtaskResult(r, [r, r], n, index=i, skill=s) for i, (s, r) in enumerate(zip(plan, rates))]
    mean = sum(rates) / len(rates)
    result = EvalResult(task=task, model=model, trials=n, plan=plan, subtasks=subtasks,
                        lh_chain=RateResult(0.0, [0.0, 0.0], n), lh_mean=RateResult(mean, [mean, mean], n),
                        sgr={}, trained_on="lh1", seed=0, trial_scores=trials)
    return EvalResult.from_json(result.to_json())


LH1 = ["follow", "carry", "climb", "sit"]
LH2 = ["follow", "carry", "follow", "sit"]
LH3 = ["follow", "carry", "follow", "climb", "sit"]
PAPER = [  # Table I and Table II of the paper (subtask rates only)
    evaluation("lh1", "cml", LH1, [0.95, 0.25, 0.00, 0.00]),
    evaluation("lh1", "tokenhsi", LH1, [1.00, 1.00, 0.19, 0.01]),
    evaluation("lh1", "detach", LH1, [0.98, 0.97, 0.51, 0.42]),
    evaluation("lh2", "tokenhsi", LH2, [1.00, 0.56, 0.13, 0.01]),
    evaluation("lh2", "detach", LH2, [1.00, 0.96, 0.67, 0.16]),
    evaluation("lh3", "tokenhsi", LH3, [1.00, 0.50, 0.21, 0.20, 0.00]),
    evaluation("lh3", "detach", LH3, [1.00, 0.95, 0.50, 0.40, 0.10]),
]


def test_table_one_lh_column_is_the_mean_of_the_subtask_rates() -> None:
    table = skills_table(PAPER)
    lh = {row[0]: row[table.keys.index("lh_mean")].value for row in table.rows}
    assert lh == pytest.approx({"CML": 0.30, "TokenHSI": 0.55, "DETACH": 0.72}, abs=0.005)
    assert table.header[-3:] == ["LH1 (mean)", "LH1 (chain)", "n"]


@pytest.mark.parametrize("experiment,method,egr,sgr", [
    ("LH2", "TokenHSI", 0.76, 0.01), ("LH2", "DETACH", 0.97, 0.08),
    ("LH3", "TokenHSI", 0.69, None), ("LH3", "DETACH", 0.81, 0.13)])
def test_table_two_egr_and_sgr_reproduce_the_paper(experiment: str, method: str, egr: float,
                                                   sgr: float | None) -> None:
    table = generalization_table(PAPER)
    row = next(r for r in table.rows if r[0] == experiment and r[1] == method)
    # The paper divides its printed two-decimal LH values (LH2 TokenHSI: 0.42 / 0.55 = 0.764,
    # printed 0.76; from the unrounded 0.425 it would be 0.77) and prints LH3 DETACH's
    # 0.59 / 0.72 = 0.819 as 0.81: within 0.01 of every printed EGR
    lh_i = round(row[table.keys.index("lh_mean")].value, 2)
    lh_1 = {"TokenHSI": 0.55, "DETACH": 0.72}[method]
    assert metrics.egr(lh_i, lh_1) == pytest.approx(egr, abs=0.01)
    assert row[table.keys.index("egr")].value == pytest.approx(egr, abs=0.015)
    if sgr is not None:  # the paper's 0.67 for LH3 TokenHSI is 0.067 by its own numbers
        assert row[table.keys.index("sgr")].value == pytest.approx(sgr, abs=0.005)
    lh = {"LH2": {"TokenHSI": 0.42, "DETACH": 0.70}, "LH3": {"TokenHSI": 0.38, "DETACH": 0.59}}
    assert row[table.keys.index("lh_mean")].value == pytest.approx(lh[experiment][method], abs=0.0051)


def test_the_printed_sgr_formula_is_selectable() -> None:
    table = generalization_table(PAPER, sgr_variant="formula")
    row = next(r for r in table.rows if r[0] == "LH3" and r[1] == "DETACH")
    assert row[table.keys.index("sgr")].value == pytest.approx((0.40 + 0.10) / (1.00 + 0.95), abs=1e-3)


def test_csv_keys_are_unique_and_numbers_rounded() -> None:
    table = generalization_table(PAPER)
    header, first = table.to_csv().splitlines()[:2]
    assert header == ("experiment,method,follow,carry,follow_2,climb,sit,time_s,lh_mean,lh_chain,sgr,egr,n,"
                      "follow_s0,carry_s0,follow_2_s0,climb_s0,sit_s0,lh_mean_s0,lh_chain_s0")  # each seed's rates
    assert all(len(v.split(".")[-1]) <= 4 for v in first.split(",")[2:-1] if "." in v)
    assert table.to_ci_csv().splitlines()[0].startswith("experiment,method,follow_low,follow_high,follow_std")


def test_detach_run_table_prints_both_lh_columns_and_either_sgr(tmp_path, capsys: pytest.CaptureFixture[str]) -> None:
    """Through `detach-run table` on run folders holding the paper's numbers as eval.json."""
    from pathlib import Path

    from detach import cli
    from detach.config import resolve
    from detach.runfolder.folder import RunFolder

    follow = Path(__file__).resolve().parents[1] / "configs/tasks/follow.yaml"
    for result in PAPER:
        run = RunFolder.create(tmp_path / "runs", resolve(follow, "mlp"))
        run.set_state("finished")
        run.eval_path.write_text(json.dumps(result.to_json()))
    runs, out = tmp_path / "runs", tmp_path / "tables"
    assert cli.main(["table", str(runs), "--kind", "generalization", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "LH (mean)" in printed and "LH (chain)" in printed
    rows = [line.split(",") for line in (out / "runs_generalization.csv").read_text().splitlines()]
    keys, detach_lh3 = rows[0], next(r for r in rows if r[:2] == ["LH3", "DETACH"])
    assert float(detach_lh3[keys.index("sgr")]) == pytest.approx(0.128, abs=1e-3)
    assert (out / "runs_generalization_ci.csv").read_text().startswith("experiment,method,follow_low")
    assert cli.main(["table", str(runs), "--kind", "generalization", "--out", str(out), "--sgr", "formula"]) == 0
    rows = [line.split(",") for line in (out / "runs_generalization.csv").read_text().splitlines()]
    detach_lh3 = next(r for r in rows if r[:2] == ["LH3", "DETACH"])
    assert float(detach_lh3[keys.index("sgr")]) == pytest.approx(0.256, abs=1e-3)
