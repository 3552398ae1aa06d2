"""What the panels show, without a server: chart arrays and axes (issue 22 defects 1, 2), legend
labels (defect 5), the runs table, filters, groups and config diffs (item 9), the tables with
their pooled runs, per-run rows and the paper's reference rows (defect 6, item 11)."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest

from detach.eval.tables import TABLES
from server.curves import (
    INTEGER_STEPS, X_AXES, chart, curve_groups, matching, run_curves, run_x, scale_exponent,
    smooth, uplot_options, y_range,
)
from server.paper_reference import ABLATION, GENERALIZATION, SKILLS
from server.run_index import MetricSeries, RunIndex, RunInfo
from server.run_views import (
    config_diff, filter_runs, group_runs, run_labels, runs_table, status_markdown,
)
from server.table_views import build_tables, table_csv, table_html
from tests.dashboard_fixtures import make_runs


def _series(its, **columns) -> MetricSeries:
    its = np.asarray(its, dtype=float)
    return MetricSeries(its, {k: np.asarray(v, dtype=float) for k, v in columns.items()},
                        times=1_700_000_000 + 30.0 * its)


# --- charts -----------------------------------------------------------------------------
def test_a_metric_that_starts_late_has_a_drawn_line_and_an_axis() -> None:
    """Defect 1: Success/* appear from the first evaluation on; before, NaN made the browser's
    range NaN (no axis, no line). The chart starts at the first value and has a range."""
    its = np.arange(20)
    late = np.where(its < 10, np.nan, its / 20)
    c = chart("Success/follow", run_curves("Success/follow", [("a", _series(its, **{
        "Success/follow": late}), None)], "iteration"))
    assert c.drawn and c.data[0][0] == 10 and np.isfinite(c.data[1]).all()
    lo, hi = c.y_range
    assert math.isfinite(lo) and math.isfinite(hi) and lo < 0.5 < 0.95 < hi
    # Two runs on different iterations: NaN where one has no value, and still a finite range.
    other = _series(np.arange(0, 30, 3), **{"Success/follow": np.linspace(0, 1, 10)})
    both = chart("Success/follow", run_curves("Success/follow", [
        ("a", _series(its, **{"Success/follow": late}), None), ("b", other, None)], "iteration"))
    assert np.isnan(both.data[1]).any() and np.isnan(both.data[2]).any()
    assert all(math.isfinite(v) for v in both.y_range)
    options = uplot_options(both)
    assert options["scales"]["y"]["range"] == both.y_range and options["scales"]["y"]["auto"] is False


def test_small_values_are_scaled_so_that_tick_labels_differ() -> None:
    """Defect 2: a learning rate of 1e-3..1e-4 read '0.001, 0, 0, 0' (3-decimal labels)."""
    lr = 1e-3 * np.exp(-np.arange(50) / 20)
    c = chart("learning_rate", run_curves("learning_rate", [("a", _series(np.arange(50),
                                                                           learning_rate=lr), None)]))
    assert c.exponent == -3 and c.title == "learning_rate (x1e-3)"
    lo, hi = c.y_range
    assert 0.5 <= hi - lo < 20, "the scaled span needs no more than 3 decimals per tick"
    np.testing.assert_allclose(c.data[1], lr * 1e3)
    flat = chart("x", run_curves("x", [("a", _series(np.arange(3), x=[0.9981, 0.9990, 0.9995]),
                                        None)]))
    assert flat.exponent == -3 and flat.y_range[1] - flat.y_range[0] >= 1.0
    assert scale_exponent(0.0, 1.0) == 0 and scale_exponent(0.0, 2e5) == 5


def test_a_constant_series_gets_a_range_around_its_value_and_iterations_whole_ticks() -> None:
    """Defect 2: constant zero got a 0-100 axis; the iteration axis ticked at 0.5, 1.5."""
    assert y_range(np.zeros(5)) == (-1.0, 1.0)
    lo, hi = y_range(np.full(5, 3.0))
    assert lo < 3.0 < hi and hi - lo < 1.0
    c = chart("loss/x", run_curves("loss/x", [("a", _series([0, 1, 2], **{"loss/x": [0, 0, 0]}),
                                                None)]))
    axes = uplot_options(c)["axes"]
    assert tuple(axes[0]["incrs"]) == INTEGER_STEPS and all(float(s).is_integer()
                                                            for s in INTEGER_STEPS)
    assert c.y_range == (-1.0, 1.0)


def test_smoothing_log_scale_and_the_other_x_axes() -> None:
    y = np.array([0.0, 1.0, 0.0, 1.0, 0.0, 1.0, np.nan, 1.0])
    s = smooth(y, 0.6)
    assert np.isnan(s[6]) and s[0] == 0.0 and 0.2 < s[-1] < 0.8, "debiased EMA over finite values"
    np.testing.assert_array_equal(smooth(y, 0.0), y)
    series = _series(np.arange(8), **{"reward/mean": y})
    smoothed = chart("reward/mean", run_curves("reward/mean", [("a", series, 64)]), smoothing=0.6)
    assert len(smoothed.data) == 3 and smoothed.labels == ["a", "a (raw)"]
    assert smoothed.colors[1].endswith("44"), "raw values in a faint copy of the colour"
    logged = chart("reward/mean", run_curves("reward/mean", [("a", series, 64)]), log=True)
    assert logged.log and logged.notes and logged.y_range[0] > 0
    np.testing.assert_array_equal(run_x(series, "samples", 64), (np.arange(8) + 1) * 64)
    np.testing.assert_allclose(run_x(series, X_AXES[2], None), np.arange(8) * 0.5)
    assert run_x(series, "samples", None) is None
    with pytest.raises(ValueError, match="unknown x axis"):
        run_x(series, "epochs", None)


def test_groups_have_one_case_and_the_filter_takes_regex_or_words() -> None:
    keys = ["Reward/follow/position", "reward/mean", "Loss/value", "loss/surrogate", "fps",
            "Episode/length", "episode/return"]
    groups = curve_groups(keys)
    assert list(groups) == ["general", "episode", "loss", "reward"]
    assert groups["reward"] == ["Reward/follow/position", "reward/mean"]
    assert matching(keys, "loss/(value|surr)") == ["Loss/value", "loss/surrogate"]
    assert matching(keys, "reward follow") == ["Reward/follow/position"]
    assert matching(keys, "(unclosed") == [] and matching(keys, "") == keys
    assert matching(["a(b"], "a(b") == ["a(b"], "an invalid expression is plain text"
    assert matching(["a" * 40 + "!"], "(a+)+$") == [], "nested repetition is plain text (no ReDoS)"


# --- runs ---------------------------------------------------------------------------------
def _info(run_id: str, model: str = "detach", seed: int = 0, **kw) -> RunInfo:
    return RunInfo(run_id, Path(run_id), task="lh1", model=model, seed=seed, state="finished", **kw)


def test_legend_labels_tell_apart_runs_that_share_model_task_and_seed() -> None:
    """Defect 5: three runs read 'detach lh1 s0'."""
    infos = [_info("20261201-100000-lh1-detach-s0"), _info("20261201-110000-lh1-detach-s0"),
             _info("20261201-120000-lh1-detach-s0", cell="table1/lh1/detach/s0"),
             _info("20261201-130000-lh1-mlp-s1", model="mlp", seed=1)]
    labels = run_labels(infos)
    assert len(set(labels.values())) == 4
    assert labels["20261201-130000-lh1-mlp-s1"] == "mlp lh1 s1"
    assert "20261201-100000" in labels["20261201-100000-lh1-detach-s0"]
    assert "table1" in labels["20261201-120000-lh1-detach-s0"]
    copies = run_labels([_info("20261201-100000-lh1-detach-s0"),
                         _info("20261201-100000-lh1-detach-s0-2")])  # RunFolder's name suffix
    assert len(set(copies.values())) == 2


def test_runs_table_filters_groups_and_never_depends_on_the_clock() -> None:
    infos = [_info("20261201-100000-lh1-detach-s0", updated=1_800_000_000.0),
             _info("20261201-110000-lh1-mlp-s1", model="mlp", seed=1, cell="table1/lh1/mlp/s1"),
             _info("20261201-120000-lh1-cml-s2", model="cml", seed=2, error="Killed",
                   problems=("status.json unreadable",))]
    table = runs_table(infos, ["20261201-110000-lh1-mlp-s1"])
    assert table == runs_table(infos, ["20261201-110000-lh1-mlp-s1"]), "no 'N s ago'"
    assert "✓" in table and "**unreadable**" in table and "status.json unreadable" in table
    assert [i.model for i in filter_runs(infos, "lh1 s1")] == ["mlp"]
    assert [i.model for i in filter_runs(infos, "table1")] == ["mlp"]
    assert list(group_runs(infos, "model")) == ["cml", "detach", "mlp"]
    assert list(group_runs(infos, "sweep cell")) == ["(not in a sweep)", "table1/lh1/mlp"]
    grouped = runs_table(infos, by="model")
    assert "**model detach** (1 run)" in grouped
    assert "error:** Killed" in status_markdown(infos[2])
    with pytest.raises(ValueError, match="expected one of"):
        group_runs(infos, "colour")


def test_config_diff_lists_the_keys_that_differ() -> None:
    a = "seed: 0\nsim: {num_envs: 16, backend: mujoco_batch}\nmodel: {kind: detach}\n"
    b = "seed: 1\nsim: {num_envs: 32, backend: mujoco_batch}\nextra: [1, 2]\n"
    assert config_diff(a, b) == [("extra", None, [1, 2]), ("model.kind", "detach", None),
                                 ("seed", 0, 1), ("sim.num_envs", 16, 32)]
    assert config_diff(a, a) == []


# --- tables -----------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def evals(tmp_path_factory) -> list:
    root = tmp_path_factory.mktemp("tables") / "runs"
    make_runs(root, models=("mlp", "detach", "detach"), broken=False, iterations=3, frames=4)
    index = RunIndex(root)
    index.refresh()
    return index.evals_by_run()


def test_tables_pool_what_detach_eval_tables_pools_and_say_which_runs(evals) -> None:
    shown = build_tables(evals)
    for name, build in TABLES.items():
        assert shown[name].table.rows == build([e for _r, e in evals]).rows
    skills = shown["skills"]
    detach_rows = [i for i, row in enumerate(skills.table.rows) if row[0] == "DETACH"]
    assert len(detach_rows) == 1 and len(skills.runs[detach_rows[0]]) == 2
    html = table_html(skills)
    assert "white-space:nowrap" in html and "Pooled runs" in html and "2 runs" in html
    n_col = skills.table.header.index("n")  # the number of trials pooled, with the seeds
    assert str(skills.table.rows[detach_rows[0]][n_col]).startswith("80 (2 seeds: s")  # and each seed's LH mean


def test_the_generalisation_csv_has_one_column_per_key_and_rounded_numbers(evals) -> None:
    """Defect 6: the CSV had the Follow column twice and full-precision floats."""
    for name, shown in build_tables(evals, per_run=True, paper=True).items():
        header, *rows = [line.split(",") for line in table_csv(shown).splitlines()]
        assert len(set(header)) == len(header), (name, header)
        assert rows and all(len(r) == len(header) for r in rows)
        numbers = [v for r in rows for v in r if re.fullmatch(r"-?\d+\.\d+", v)]
        assert numbers and all(len(v.split(".")[1]) <= 4 for v in numbers), (name, numbers)
    gen = build_tables(evals)["generalization"]
    header = table_csv(gen).splitlines()[0].split(",")
    assert header[:5] == ["experiment", "method", "follow", "carry", "follow_2"]


def test_per_run_rows_and_the_papers_numbers(evals) -> None:
    shown = build_tables(evals, labels={r: f"label-{r[-2:]}" for r, _e in evals},
                         per_run=True, paper=True)
    skills = shown["skills"]
    assert skills.kinds.count("run") == 3 and skills.kinds.count("paper") == len(SKILLS)
    run_rows = [row for row, kind in zip(skills.table.rows, skills.kinds) if kind == "run"]
    assert all(str(row[0]).startswith("↳ label-") for row in run_rows)
    paper = {row[0]: row for row, kind in zip(skills.table.rows, skills.kinds) if kind == "paper"}
    keys = skills.table.keys
    assert paper["paper: DETACH"][keys.index("lh_mean")].value == 0.72
    assert paper["paper: CML"][keys.index("follow")].value == 0.95
    gen = shown["generalization"]
    assert gen.kinds.count("paper") == len(GENERALIZATION)
    assert "swapped" in table_html(gen)
    assert shown["ablation"].kinds.count("paper") == len(ABLATION)
    csv = table_csv(skills).splitlines()
    assert len(csv) == 1 + len(skills.table.rows)
    assert "paper: DETACH" in "\n".join(csv)


def test_a_table_with_only_the_papers_rows_says_it_pooled_nothing(evals) -> None:
    """Runs whose evaluations fit no table (e.g. a follow-only run) leave the paper's rows
    alone in it: the table says that none of the pooled runs is in it."""
    for name, shown in build_tables([], paper=True).items():
        assert shown.kinds and set(shown.kinds) == {"paper"}
        assert "no evaluations for this table" in table_html(shown), name
    for name, shown in build_tables(evals, paper=True).items():
        assert "no evaluations for this table" not in table_html(shown), name


def test_paper_numbers_are_consistent_with_the_papers_definitions() -> None:
    """LH is the mean of the subtask rates, EGR = LH / LH1 (which shows that the paper's
    Table II headers SGR./EGR. are swapped), and Table III repeats DETACH on LH3."""
    for m, row in SKILLS.items():
        mean = (row["follow"] + row["carry"] + row["climb"] + row["sit"]) / 4
        assert abs(mean - row["lh_mean"]) < 0.006, m
    for (task, m), row in GENERALIZATION.items():
        assert abs(row["lh_mean"] / SKILLS[m]["lh_mean"] - row["egr"]) < 0.015, (task, m)
    assert ABLATION["detach"]["egr"] == GENERALIZATION[("lh3", "detach")]["egr"]
    assert ABLATION["detach"]["sgr"] == GENERALIZATION[("lh3", "detach")]["sgr"]
