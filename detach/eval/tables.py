"""The paper's tables from eval.json files, as Markdown, CSV and LaTeX.

- Table I ("skills"): Method | Follow | Carry | Climb | Sit | LH1, evaluations on LH1; a
  plug-in skill that appears in the evaluated plans gets its own column after the four.
- Table II ("generalization"): per experiment (LH2, LH3) and method, the subtask rates in the
  paper's column order Follow | Carry | Follow | Climb | Sit ('-' where the plan lacks one),
  Time(s), LH., SGR., EGR.; EGR divides by the same model's LH1 success rate.
- Table III ("ablation"): Method | EGR | SGR | LH SR on LH3.
Several seeds of one (task, model) pool their trials: rates are trial-weighted means and the
interval is recomputed on the pooled trials.
"""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass, field
from typing import Any, Iterable, Sequence

from detach.eval.metrics import LEARNED_SKILLS, NOVEL_SKILLS, egr, wilson_interval
from detach.run_contract import EvalResult
from detach.skills import canonical_name, display_name, skill_names

METHOD_NAMES = {"cml": "CML", "tokenhsi": "TokenHSI", "detach": "DETACH (ours)",
                "ablation_a1": "A1 (w/o env encoder)", "ablation_a2": "A2 (w/o self encoder)",
                "mlp": "MLP"}
METHOD_ORDER = ["mlp", "cml", "tokenhsi", "ablation_a1", "ablation_a2", "detach"]
PAPER_SKILLS = (*LEARNED_SKILLS, *NOVEL_SKILLS)
LH_COLUMNS = [("follow", 0), ("carry", 0), ("follow", 1), ("climb", 0), ("sit", 0)]
"""Paper's Table II columns: (skill, occurrence of that skill in the plan)."""


@dataclass
class Cell:
    value: float | None
    low: float | None = None
    high: float | None = None
    digits: int = 2

    def text(self, with_ci: bool = True) -> str:
        if self.value is None:
            return "-"
        main = f"{self.value:.{self.digits}f}"
        if with_ci and self.low is not None and self.high is not None:
            return f"{main} [{self.low:.{self.digits}f}, {self.high:.{self.digits}f}]"
        return main


@dataclass
class Table:
    title: str
    header: list[str]
    rows: list[list[str | Cell]] = field(default_factory=list)

    def _texts(self, with_ci: bool) -> list[list[str]]:
        return [[c.text(with_ci) if isinstance(c, Cell) else c for c in row] for row in self.rows]

    def to_markdown(self) -> str:
        lines = [f"**{self.title}**", "", "| " + " | ".join(self.header) + " |",
                 "|" + "|".join(" --- " for _ in self.header) + "|"]
        lines += ["| " + " | ".join(row) + " |" for row in self._texts(True)]
        return "\n".join(lines) + "\n"

    def to_csv(self) -> str:
        """Numbers in separate value/low/high columns, for spreadsheets."""
        out = io.StringIO()
        writer = csv.writer(out)
        header: list[str] = []
        for name, cell in zip(self.header, self.rows[0] if self.rows else []):
            header += [name, f"{name} low", f"{name} high"] if isinstance(cell, Cell) else [name]
        writer.writerow(header or self.header)
        for row in self.rows:
            flat: list[Any] = []
            for cell in row:
                flat += ([cell.value, cell.low, cell.high] if isinstance(cell, Cell) else [cell])
            writer.writerow(["" if v is None else v for v in flat])
        return out.getvalue()

    def to_latex(self) -> str:
        cols = "l" * 1 + "c" * (len(self.header) - 1)
        body = [" & ".join(self.header) + r" \\ \hline"]
        body += [" & ".join(r.replace("%", r"\%") for r in row) + r" \\"
                 for row in self._texts(False)]
        return ("\\begin{table}[t]\n\\centering\n\\begin{tabular}{" + cols + "}\n\\hline\n"
                + "\n".join(body) + "\n\\hline\n\\end{tabular}\n\\caption{" + self.title
                + "}\n\\end{table}\n")


def _pool(evals: Sequence[EvalResult], getter) -> Cell:
    """Trial-weighted mean of a rate over seeds, with the interval of the pooled trials."""
    pairs = [(getter(e), e.trials) for e in evals]
    pairs = [(r, n) for r, n in pairs if r is not None]
    if not pairs:
        return Cell(None)
    n = sum(k for _r, k in pairs)
    rate = sum(r * k for r, k in pairs) / n
    low, high = wilson_interval(rate * n, n)
    return Cell(rate, low, high)


def _canonical(name: str) -> str:
    try:
        return canonical_name(name)
    except ValueError:
        return name


def _subtask_rate(e: EvalResult, skill: str, occurrence: int) -> float | None:
    seen = [s for s in e.subtasks if _canonical(s.skill) == skill]
    return seen[occurrence].rate if occurrence < len(seen) else None


def _lh_rate(e: EvalResult) -> float:
    return e.lh_success.rate


def _group(evals: Iterable[EvalResult]) -> dict[tuple[str, str, str], list[EvalResult]]:
    groups: dict[tuple[str, str, str], list[EvalResult]] = {}
    for e in evals:
        key = (e.trained_on or e.task, e.task, e.model)
        groups.setdefault(key, []).append(e)
    return groups


def _models(groups: dict[tuple[str, str, str], list], task: str) -> list[str]:
    found = {m for (_tr, t, m) in groups if t == task}
    return sorted(found, key=lambda m: (METHOD_ORDER.index(m) if m in METHOD_ORDER else 99, m))


def _lh1_rate(groups, trained_on: str, model: str) -> float | None:
    runs = groups.get((trained_on, "lh1", model))
    return _pool(runs, _lh_rate).value if runs else None


def skill_columns(evals: Sequence[EvalResult]) -> list[str]:
    """The paper's four skills, then any other registered skill the evaluated plans use."""
    used = {_canonical(s) for e in evals for s in e.plan}
    return [*PAPER_SKILLS, *(s for s in skill_names() if s not in PAPER_SKILLS and s in used)]


def skills_table(evals: Sequence[EvalResult], task: str = "lh1") -> Table:
    """Paper Table I: success rates of the skills and of the whole task (LH1)."""
    groups = _group(evals)
    columns = skill_columns([e for e in evals if e.task == task])
    table = Table(f"Success rates for foundational skills and composite task completion "
                  f"({task.upper()})", ["Method", *(display_name(s) for s in columns), task.upper()])
    for model in _models(groups, task):
        runs = [e for (tr, t, m), es in groups.items() if t == task and m == model for e in es]
        row: list[str | Cell] = [METHOD_NAMES.get(model, model)]
        row += [_pool(runs, lambda e, s=s: _subtask_rate(e, s, 0)) for s in columns]
        row.append(_pool(runs, _lh_rate))
        table.rows.append(row)
    return table


def generalization_table(evals: Sequence[EvalResult],
                         experiments: Sequence[str] = ("lh2", "lh3")) -> Table:
    """Paper Table II: policies trained on one task evaluated on LH2 and LH3."""
    groups = _group(evals)
    table = Table("Generalization of policies to LH tasks",
                  ["Experiment", "Method", *[display_name(c[0]) for c in LH_COLUMNS], "Time(s)",
                   "LH.", "SGR.", "EGR."])
    for task in experiments:
        for (trained_on, t, model), runs in sorted(groups.items()):
            if t != task:
                continue
            row: list[str | Cell] = [task.upper(), METHOD_NAMES.get(model, model)]
            row += [_pool(runs, lambda e, s=s, k=k: _subtask_rate(e, s, k)) for s, k in LH_COLUMNS]
            times = [e.mean_execution_time for e in runs if e.mean_execution_time]
            row.append(Cell(sum(times) / len(times) if times else None))
            lh = _pool(runs, _lh_rate)
            row.append(lh)
            row.append(Cell(sum(e.sgr for e in runs) / len(runs)))
            lh1 = _lh1_rate(groups, trained_on, model)
            row.append(Cell(egr(lh.value or 0.0, lh1) if lh1 else None))
            table.rows.append(row)
    table.rows.sort(key=lambda r: (r[0], METHOD_ORDER.index(_key(r[1]))
                                   if _key(r[1]) in METHOD_ORDER else 99))
    return table


def _key(name: str | Cell) -> str:
    inverse = {v: k for k, v in METHOD_NAMES.items()}
    return inverse.get(name, name) if isinstance(name, str) else ""


def ablation_table(evals: Sequence[EvalResult], task: str = "lh3") -> Table:
    """Paper Table III: EGR, SGR and LH success of Full / A1 / A2 on LH3."""
    groups = _group(evals)
    table = Table(f"Ablation on {task.upper()}", ["Method", "EGR", "SGR", "LH SR"])
    for (trained_on, t, model), runs in sorted(
            groups.items(), key=lambda kv: METHOD_ORDER.index(kv[0][2])
            if kv[0][2] in METHOD_ORDER else 99):
        if t != task:
            continue
        lh = _pool(runs, _lh_rate)
        lh1 = _lh1_rate(groups, trained_on, model)
        table.rows.append([METHOD_NAMES.get(model, model),
                           Cell(egr(lh.value or 0.0, lh1) if lh1 else None),
                           Cell(sum(e.sgr for e in runs) / len(runs), digits=3), lh])
    return table


TABLES = {"skills": skills_table, "generalization": generalization_table,
          "ablation": ablation_table}


def render(kind: str, evals: Sequence[EvalResult], task: str | None = None) -> Table:
    """One table by name; `task` replaces the paper's evaluation task (LH1 / LH2+LH3 / LH3)."""
    if task is None:
        return TABLES[kind](evals)
    if kind == "generalization":
        return generalization_table(evals, experiments=(task,))
    return TABLES[kind](evals, task=task)
