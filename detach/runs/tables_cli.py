"""`detach-run table`: the paper's tables from the eval*.json files of runs or a sweep."""

from __future__ import annotations

import json
from pathlib import Path

from detach.config import ConfigError
from detach.eval.tables import TABLES, render
from detach.run_contract import EVAL_GLOB, EvalResult
from detach.runs.folder import RunFolder, atomic_write_text, find_runs


def collect_evals(runs: list[RunFolder], cells: set[str] | None = None) -> list[EvalResult]:
    """Every eval*.json of the given runs (restricted to sweep cells when given)."""
    evals = []
    for run in runs:
        if cells is not None:
            try:
                if run.status().cell not in cells:
                    continue
            except (OSError, ValueError):
                continue
        for path in sorted(run.path.glob(EVAL_GLOB)):
            try:
                evals.append(EvalResult.from_json(json.loads(path.read_text(encoding="utf-8")), str(path)))
            except (OSError, ValueError):
                continue
    return evals


def print_table(source: Path, runs_dir: Path, kind: str | None, out: Path | None,
                task: str | None = None) -> int:
    if not source.exists():
        raise ConfigError("sweep file or runs folder not found", str(source))
    if source.is_dir():
        evals, kinds, name = collect_evals(find_runs(source)), [kind] if kind else list(TABLES), source.name
        out = out or source / "tables"
    else:
        from detach.runs.sweep import cells, load_sweep

        sweep = load_sweep(source)
        keys = {c.key for c in cells(sweep, source)}
        quick = load_sweep(source, quick=True)
        keys |= {c.key for c in cells(quick, source)}
        evals = collect_evals(find_runs(runs_dir), keys)
        kinds, name = [kind or sweep.table], sweep.name
        out = out or runs_dir / "tables"
    if not evals:
        raise ConfigError("no eval.json found (train and evaluate runs first)", str(source))
    for k in kinds:
        table = render(k, evals, task)
        markdown = table.to_markdown()
        print(markdown)
        stem = out / f"{name}_{k}"
        atomic_write_text(stem.with_suffix(".md"), markdown)
        atomic_write_text(stem.with_suffix(".csv"), table.to_csv())
        atomic_write_text(stem.with_suffix(".tex"), table.to_latex())
        print(f"written: {stem}.md, .csv, .tex\n")
    return 0
