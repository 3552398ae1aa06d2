"""The paper's tables from evaluation results (`EvalResult`), as Markdown, CSV and LaTeX.

- Table I ("skills"): Method | Follow | Carry | Climb | Sit | LH (mean) | LH (chain) | n, on
  LH1; a plug-in skill used by the evaluated plans gets its own column after the four.
- Table II ("generalization"): per experiment (LH2, LH3) and method, the subtask rates in the
  paper's column order Follow | Carry | Follow | Climb | Sit ('-' where the plan lacks one),
  Time(s), LH (mean), LH (chain), SGR, EGR, n. EGR divides by the same model's LH1 rate.
- Table III ("ablation"): Method | EGR | SGR | LH (mean) | LH (chain) | n on LH3.

LH (mean) is the paper's LH success (the mean of the subtask rates: its Table I LH column is
0.30 / 0.55 / 0.72 from its own subtask rates), LH (chain) the stricter "every subtask in one
episode". EGR = LH_i / LH_1 on the mean rates; SGR follows `sgr_variant` (default "reported",
see `detach.eval.metrics.sgr`). Several seeds of one (task, model) pool their trials: a rate
is the mean over all trials with the interval of `success_rate` on them (Wilson for 0/1
scores, normal for partial credit, as in eval.json); a cell also shows the spread across
seeds (± the std of the per-seed rates) when there are several, and `n` the pooled trials and
seeds; the CSV has each seed's rate in a column of its own (`<key>_s<seed>`). Files of older
versions without per-trial scores pool trial-weighted rates. A row is a method with its aids
(`detach.eval.aids`): the same model trained with and without a teacher are two rows, and the
method column names every aid ("DETACH + chosen checkpoint").
"""

from __future__ import annotations

import csv
import io
import statistics
from dataclasses import dataclass, field
from typing import Callable, Iterable, Sequence

from detach.eval.aids import label
from detach.eval.metrics import LEARNED_SKILLS, NOVEL_SKILLS, egr, sgr, success_rate, wilson_interval
from detach.models import model_label, model_order
from detach.runfolder.eval_result import SGR_VARIANTS, EvalResult
from detach.skills import canonical_name, display_name, skill_names

PAPER_SKILLS = (*LEARNED_SKILLS, *NOVEL_SKILLS)
LH_COLUMNS = [("follow", 0), ("carry", 0), ("follow", 1), ("climb", 0), ("sit", 0)]
"""Paper's Table II columns: (skill, occurrence of that skill in the plan)."""
TIME_NOTE = ("Time(s): start of the task to completion of its last subtask, completed episodes only; our "
             "episodes are capped at env.episode_length (40 s) while the paper reports 85-103 s.")


@dataclass
class Cell:
    value: float | None
    low: float | None = None
    high: float | None = None
    spread: float | None = None
    """Std of the per-seed values (several seeds only)."""
    digits: int = 2
    per_seed: dict[int, float] | None = None
    """Each seed's value (the CSV's `<key>_s<seed>` columns)."""
    reached: tuple[int, int] | None = None
    """(trials that got to the subtask, trials) where known: a subtask few trials reached has
    a rate of few trials (shown when some never got there; the CSV's `<key>_reached`)."""

    def text(self, with_ci: bool = True) -> str:
        if self.value is None:
            return "-"
        main = f"{self.value:.{self.digits}f}"
        if with_ci and self.spread is not None:
            main += f" ±{self.spread:.{self.digits}f}"
        if with_ci and self.low is not None and self.high is not None:
            main += f" [{self.low:.{self.digits}f}, {self.high:.{self.digits}f}]"
        if self.reached is not None and self.reached[0] < self.reached[1]:
            main += f" (reached {self.reached[0]}/{self.reached[1]})"
        return main


@dataclass
class Table:
    title: str
    header: list[str]
    """Column headers as printed."""
    keys: list[str] = field(default_factory=list)
    """Column names in CSV files (unique, lower case)."""
    rows: list[list[str | Cell]] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    def _texts(self, with_ci: bool) -> list[list[str]]:
        return [[c.text(with_ci) if isinstance(c, Cell) else c for c in row] for row in self.rows]

    def to_markdown(self) -> str:
        lines = [f"**{self.title}**", "", "| " + " | ".join(self.header) + " |",
                 "|" + "|".join(" --- " for _ in self.header) + "|"]
        lines += ["| " + " | ".join(row) + " |" for row in self._texts(True)]
        lines += ["", *self.notes] if self.notes else []
        return "\n".join(lines) + "\n"

    def _seeds(self) -> list[int]:
        return sorted({s for row in self.rows for c in row if isinstance(c, Cell) and c.per_seed for s in c.per_seed})

    def to_csv(self) -> str:
        """One row per table row, one column per key, then each number's per-seed values
        (`<key>_s<seed>`, empty where a row lacks that seed); numbers rounded to 4 decimals."""
        out = io.StringIO()
        writer = csv.writer(out, lineterminator="\n")
        seeds = self._seeds()
        seeded = [i for i in range(len(self.keys))
                  if any(isinstance(row[i], Cell) and row[i].per_seed for row in self.rows)]
        counted = [i for i in range(len(self.keys))
                   if any(isinstance(row[i], Cell) and row[i].reached for row in self.rows)]
        writer.writerow([*self.keys, *(f"{self.keys[i]}_s{s}" for i in seeded for s in seeds),
                         *(f"{self.keys[i]}_reached" for i in counted)])
        for row in self.rows:
            per_seed = [_num((c.per_seed or {}).get(s)) if isinstance(c := row[i], Cell) else ""
                        for i in seeded for s in seeds]
            reached = [c.reached[0] if isinstance(c := row[i], Cell) and c.reached else "" for i in counted]
            writer.writerow([*(_num(c.value) if isinstance(c, Cell) else c for c in row), *per_seed, *reached])
        return out.getvalue()

    def to_ci_csv(self) -> str:
        """The intervals, spreads and n of every number: <key>_low, <key>_high, <key>_std."""
        out = io.StringIO()
        writer = csv.writer(out, lineterminator="\n")
        first = self.rows[0] if self.rows else [""] * len(self.keys)
        header: list[str] = []
        for key, cell in zip(self.keys, first):
            header += [f"{key}_low", f"{key}_high", f"{key}_std"] if isinstance(cell, Cell) and key != "n" else [key]
        writer.writerow(header)
        for row in self.rows:
            flat: list[object] = []
            for key, cell in zip(self.keys, row):
                if isinstance(cell, Cell) and key != "n":
                    flat += [_num(cell.low), _num(cell.high), _num(cell.spread)]
                else:
                    flat.append(_num(cell.value) if isinstance(cell, Cell) else cell)
            writer.writerow(flat)
        return out.getvalue()

    def to_latex(self) -> str:
        cols = "l" * 1 + "c" * (len(self.header) - 1)
        body = [" & ".join(self.header) + r" \\ \hline"]
        body += [" & ".join(r.replace("%", r"\%") for r in row) + r" \\"
                 for row in self._texts(False)]
        return ("\\begin{table}[t]\n\\centering\n\\begin{tabular}{" + cols + "}\n\\hline\n"
                + "\n".join(body) + "\n\\hline\n\\end{tabular}\n\\caption{" + self.title
                + "}\n\\end{table}\n")


def _num(v: float | None) -> str | float:
    return "" if v is None else round(float(v), 4)


def _canonical(name: str) -> str:
    try:
        return canonical_name(name)
    except ValueError:
        return name


def _column(e: EvalResult, skill: str, occurrence: int) -> int | None:
    """Index of the `occurrence`-th subtask of `skill` in the plan, None if there is none."""
    found = [i for i, s in enumerate(e.plan) if _canonical(s) == skill]
    return found[occurrence] if occurrence < len(found) else None


TrialValue = Callable[[EvalResult, list[float]], float | None]
"""A per-trial value of an evaluation (None: the evaluation does not have it)."""


def subtask_cell(evals: Sequence[EvalResult], skill: str, occurrence: int = 0) -> Cell:
    """A subtask's pooled rate, with how many trials reached it where every file says."""
    cell = pool(evals, subtask_value(skill, occurrence))
    counts = []
    for e in evals:
        k = _column(e, skill, occurrence)
        if k is not None:
            counts.append((e.subtasks[k].reached, e.trials))
    if counts and all(r is not None for r, _n in counts):
        cell.reached = (sum(r for r, _n in counts), sum(n for _r, n in counts))
    return cell


def subtask_value(skill: str, occurrence: int = 0) -> TrialValue:
    return lambda e, scores: None if (k := _column(e, skill, occurrence)) is None else scores[k]


def lh_mean_value(e: EvalResult, scores: list[float]) -> float:
    return sum(scores) / max(len(scores), 1)


def lh_chain_value(e: EvalResult, scores: list[float]) -> float:
    return 1.0 if all(s >= 1.0 for s in scores) else 0.0


def _fallback(e: EvalResult, value: TrialValue) -> float | None:
    """The evaluation's rate of `value` from its summary (files without per-trial scores)."""
    if value is lh_mean_value:
        return e.lh_mean.rate
    if value is lh_chain_value:
        return e.lh_chain.rate
    rates = [s.rate for s in e.subtasks]
    return value(e, rates)


def pool(evals: Sequence[EvalResult], value: TrialValue) -> Cell:
    """A rate over several seeds: the mean of the per-seed rates ± their std, with the
    interval of every trial pooled (Wilson for 0/1 scores) and each seed's rate."""
    by_seed: dict[int, list[float]] = {}
    for i, e in enumerate(evals):
        seed = e.seed if e.seed is not None else -1 - i  # unknown seeds count apart
        if e.trial_scores:
            by_seed.setdefault(seed, []).extend(v for t in e.trial_scores if (v := value(e, t)) is not None)
        elif (rate := _fallback(e, value)) is not None:
            by_seed.setdefault(seed, []).extend([rate] * e.trials)  # no per-trial scores: weight by trials
    per_seed = {s: sum(v) / len(v) for s, v in by_seed.items() if v}
    if not per_seed:
        return Cell(None)
    trials = [v for vals in by_seed.values() for v in vals]
    spread = statistics.stdev(per_seed.values()) if len(per_seed) > 1 else None
    mean = sum(per_seed.values()) / len(per_seed)
    if all(e.trial_scores for e in evals):
        r = success_rate(trials)
        low, high = r.low, r.high
    else:
        low, high = wilson_interval(sum(trials), len(trials))
    return Cell(mean, low, high, spread, per_seed={s: r for s, r in per_seed.items() if s >= 0} or None)


def _n(evals: Sequence[EvalResult]) -> str:
    """Trials and seeds, with one seed which one, and with several each seed's LH mean: a
    recipe that works on one seed only shows so in the row itself, and a one-seed row beside
    pooled ones names the seed it rests on."""
    seeds = sorted({e.seed for e in evals})
    text = f"{sum(e.trials for e in evals)} ({len(seeds)} seed{'s' if len(seeds) != 1 else ''}"
    if len(seeds) == 1:
        return text + f": s{seeds[0]})"
    per_seed = pool(evals, lh_mean_value).per_seed or {}
    if len(per_seed) > 1:
        text += ": " + " / ".join(f"s{s} {v:.2f}" for s, v in sorted(per_seed.items()))
    return text + ")"


Method = tuple[str, tuple[str, ...]]
"""(model, aids): one row of a table."""


def _method(e: EvalResult) -> Method:
    return (e.model, tuple(e.aids or ()))


def _group(evals: Iterable[EvalResult]) -> dict[tuple[str, str, Method], list[EvalResult]]:
    groups: dict[tuple[str, str, Method], list[EvalResult]] = {}
    for e in evals:
        key = (e.trained_on or e.task, e.task, _method(e))
        groups.setdefault(key, []).append(e)
    return groups


def _order(method: Method) -> tuple[int, str, int, tuple[str, ...]]:
    model, aids = method
    order = model_order()  # the registry's: built-in models first, then add-ons
    return (order.index(model) if model in order else len(order), model, len(aids), aids)


def method_label(method: Method) -> str:
    model, aids = method
    return label(model_label(model), aids)


def _lh1_rate(groups, trained_on: str, method: Method) -> float | None:
    runs = groups.get((trained_on, "lh1", method))
    return pool(runs, lh_mean_value).value if runs else None


def _sgr(runs: Sequence[EvalResult], variant: str) -> Cell:
    """SGR of the pooled subtask rates (first occurrence of each skill)."""
    plan = runs[0].plan
    rates = [pool(runs, subtask_value(_canonical(s), [_canonical(p) for p in plan[:i]].count(_canonical(s)))).value
             or 0.0 for i, s in enumerate(plan)]
    return Cell(sgr(plan, rates, variant), digits=3)


def skill_columns(evals: Sequence[EvalResult]) -> list[str]:
    """The paper's four skills, then any other registered skill the evaluated plans use."""
    used = {_canonical(s) for e in evals for s in e.plan}
    return [*PAPER_SKILLS, *(s for s in skill_names() if s not in PAPER_SKILLS and s in used)]


def skills_table(evals: Sequence[EvalResult], task: str = "lh1", sgr_variant: str = SGR_VARIANTS[0]) -> Table:
    """Paper Table I: success rates of the skills and of the whole task (LH1)."""
    groups = _group(evals)
    columns = skill_columns([e for e in evals if e.task == task])
    table = Table(f"Success rates for foundational skills and composite task completion ({task.upper()})",
                  ["Method", *(display_name(s) for s in columns), f"{task.upper()} (mean)",
                   f"{task.upper()} (chain)", "n"],
                  ["method", *columns, "lh_mean", "lh_chain", "n"])
    for method in sorted({m for (_tr, t, m) in groups if t == task}, key=_order):
        runs = [e for (tr, t, m), es in groups.items() if t == task and m == method for e in es]
        row: list[str | Cell] = [method_label(method)]
        row += [subtask_cell(runs, s) for s in columns]
        row += [pool(runs, lh_mean_value), pool(runs, lh_chain_value), _n(runs)]
        table.rows.append(row)
    return table


def generalization_table(evals: Sequence[EvalResult], experiments: Sequence[str] = ("lh2", "lh3"),
                         sgr_variant: str = SGR_VARIANTS[0]) -> Table:
    """Paper Table II: policies trained on one task evaluated on LH2 and LH3."""
    groups = _group(evals)
    table = Table("Generalization of policies to LH tasks",
                  ["Experiment", "Method", *[display_name(s) for s, _k in LH_COLUMNS], "Time(s)",
                   "LH (mean)", "LH (chain)", "SGR", "EGR", "n"],
                  ["experiment", "method", "follow", "carry", "follow_2", "climb", "sit", "time_s",
                   "lh_mean", "lh_chain", "sgr", "egr", "n"],
                  notes=[TIME_NOTE, f"SGR variant: {sgr_variant}; EGR = LH (mean) / the same model's LH1 (mean)."])
    for task in experiments:
        for (trained_on, t, model), runs in sorted(groups.items(), key=lambda kv: _order(kv[0][2])):
            if t != task:
                continue
            row: list[str | Cell] = [task.upper(), method_label(model)]
            row += [subtask_cell(runs, s, k) for s, k in LH_COLUMNS]
            times = [e.mean_execution_time for e in runs if e.mean_execution_time]
            row.append(Cell(sum(times) / len(times) if times else None, digits=1))
            lh = pool(runs, lh_mean_value)
            row += [lh, pool(runs, lh_chain_value), _sgr(runs, sgr_variant)]
            lh1 = _lh1_rate(groups, trained_on, model)
            row += [Cell(egr(lh.value or 0.0, lh1) if lh1 else None), _n(runs)]
            table.rows.append(row)
    return table


def ablation_table(evals: Sequence[EvalResult], task: str = "lh3", sgr_variant: str = SGR_VARIANTS[0]) -> Table:
    """Paper Table III: EGR, SGR and LH success of Full / A1 / A2 on LH3."""
    groups = _group(evals)
    table = Table(f"Ablation on {task.upper()}", ["Method", "EGR", "SGR", "LH (mean)", "LH (chain)", "n"],
                  ["method", "egr", "sgr", "lh_mean", "lh_chain", "n"],
                  notes=[f"SGR variant: {sgr_variant}; EGR = LH (mean) on {task.upper()} / LH1 (mean)."])
    for (trained_on, t, model), runs in sorted(groups.items(), key=lambda kv: _order(kv[0][2])):
        if t != task:
            continue
        lh = pool(runs, lh_mean_value)
        lh1 = _lh1_rate(groups, trained_on, model)
        table.rows.append([method_label(model), Cell(egr(lh.value or 0.0, lh1) if lh1 else None),
                           _sgr(runs, sgr_variant), lh, pool(runs, lh_chain_value), _n(runs)])
    return table


TABLES = {"skills": skills_table, "generalization": generalization_table,
          "ablation": ablation_table}


def render(kind: str, evals: Sequence[EvalResult], task: str | None = None,
           sgr_variant: str = SGR_VARIANTS[0]) -> Table:
    """One table by name; `task` replaces the paper's evaluation task (LH1 / LH2+LH3 / LH3)."""
    if sgr_variant not in SGR_VARIANTS:
        raise ValueError(f"unknown SGR variant {sgr_variant!r}; expected one of {', '.join(SGR_VARIANTS)}")
    if task is None:
        return TABLES[kind](evals, sgr_variant=sgr_variant)
    if kind == "generalization":
        return generalization_table(evals, experiments=(task,), sgr_variant=sgr_variant)
    return TABLES[kind](evals, task=task, sgr_variant=sgr_variant)
