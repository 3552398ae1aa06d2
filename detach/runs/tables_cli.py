"""`detach-run table`: the paper's tables from the eval*.json files of runs or a sweep.

Four guards keep a table honest:
- a sweep's table reads the evaluations its `eval:` asks of each cell, no others: a phase-A
  cell evaluated by hand on LH1 must not pool into the LH1 column;
- one evaluation per sweep cell and evaluated task, the newest: a cell trained twice (two
  sweeps over one file, a re-run) must not count its trials twice, which would double n and
  shrink the intervals;
- a run counts once however many copies of its folder there are (`cp -r RUN RUN.bak`): runs
  are identified by the run id status.json records at creation, not by folder name (a folder
  of an earlier version, without an id, by its name);
- a file that does not follow the contract, or holds impossible numbers (NaN, a rate
  outside [0, 1], zero trials), is left out with a line on stderr saying which and why.
"""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Collection, Mapping, Sequence

from detach.config import ConfigError
from detach.eval.tables import TABLES, render
from detach.run_contract import EVAL_GLOB, EvalResult
from detach.runs.folder import RunFolder, atomic_write_text, find_runs, read_eval

Report = Callable[[str], None]


def _stderr(line: str) -> None:
    print(f"detach-run table: {line}", file=sys.stderr)


@dataclass
class _Found:
    result: EvalResult
    path: Path
    written: float


def collect_evals(runs: list[RunFolder], cells: Mapping[str, Collection[str]] | None = None,
                  report: Report = _stderr) -> list[EvalResult]:
    """Every usable eval*.json of the given runs (when `cells` is given: of those sweep cells,
    on the tasks it names for each); of a sweep cell evaluated more than once on a task, only
    the newest evaluation."""
    found: dict[tuple[str, ...], _Found] = {}
    duplicates = unasked = 0
    copies: dict[str, set[str]] = {}
    """Run id -> the folders holding it (a copied run folder shares its id)."""
    for run in runs:
        try:
            status = run.status()
            cell, run_id = status.cell, status.run_id or run.path.name
        except (OSError, ValueError):
            cell, run_id = None, run.path.name
        copies.setdefault(run_id, set()).add(run.path.name)
        if cells is not None and cell not in cells:
            continue
        for path in sorted(run.path.glob(EVAL_GLOB)):
            try:
                result = read_eval(path)
                written = path.stat().st_mtime
            except (OSError, ValueError) as exc:
                report(f"skipped {path}: {exc}")
                continue
            if cells is not None and result.task not in cells[cell]:
                unasked += 1
                continue
            key = ("cell", cell, result.task) if cell else ("run", run_id, path.name)
            previous = found.get(key)
            if previous is not None:  # a cell trained twice, or a copied run folder (said below)
                duplicates += bool(cell)
                if (previous.written, str(previous.path)) > (written, str(path)):
                    continue
            found[key] = _Found(result, path, written)
    if unasked:
        report(f"{unasked} evaluation(s) on a task the sweep does not evaluate their cell on left out "
               f"(a sweep's table reads the evaluations its `eval:` asks for)")
    for run_id, folders in sorted(copies.items()):
        if len(folders) > 1:
            first, *rest = sorted(folders)
            report(f"{', '.join(rest)}: a copy of run folder {first} (same run id {run_id}); its evaluations "
                   f"count once")
    if duplicates:
        report(f"{duplicates} older evaluation(s) of a sweep cell left out (a cell counts once: its newest "
               f"evaluation per task)")
    return [f.result for f in found.values()]


def print_table(source: Path, runs_dir: Path, kind: str | None, out: Path | None,
                task: str | None = None, sgr_variant: str = "reported", preset: str | None = None,
                seeds: Sequence[int] | None = None) -> int:
    """Print the table(s) of a runs folder or of a sweep's cells (under `preset`, None = the
    sweep's default settings; of `seeds` instead of its own when given) and write .md, .csv,
    _ci.csv and .tex beside each."""
    if not source.exists():
        raise ConfigError("sweep file or runs folder not found", str(source))
    if source.is_dir() and seeds is not None:
        raise ConfigError("--seeds: with a sweep file only (a runs folder's table pools every run in it)", str(source))
    seeded = "" if seeds is None else "_seeds" + "-".join(map(str, seeds))  # the preset's own files stay
    if source.is_dir():
        evals, kinds, name = collect_evals(find_runs(source)), [kind] if kind else list(TABLES), source.name
        out = out or source / "tables"
        curves = None
    else:
        from detach.runs.sweep import cell_evaluations, existing_runs, load_sweep

        sweep = load_sweep(source, preset=preset, seeds=seeds)
        cells = cell_evaluations(source, preset, seeds)
        evals = collect_evals(find_runs(runs_dir), cells)
        kinds, name = [kind or sweep.table], sweep.name
        out = out or runs_dir / "tables"
        curves = {key: run for key, run in existing_runs(runs_dir).items() if key in cells}
    if not evals:
        raise ConfigError("no eval.json found (train and evaluate runs first)", str(source))
    _check_writable(out)
    evaluated = sorted({e.task for e in evals})
    if task is not None and task not in evaluated:  # else an empty table, exit 0: a typo looks like no result
        raise ConfigError(f"--task: no evaluation of task '{task}' (evaluated: {', '.join(evaluated)})",
                          str(source))
    for k in kinds:
        table = render(k, evals, task, sgr_variant)
        if not table.rows:  # e.g. a sweep in progress: phase A evaluated, its LH1 cells not yet
            _stderr(f"{k}: no run evaluated on this table's task yet (evaluated: {', '.join(evaluated)}; "
                    f"--task NAME tables one of those); nothing written")
            continue
        markdown = table.to_markdown()
        print(markdown)
        stem = out / ((name if curves is not None else f"{name}_{k}")  # a sweep has one table
                      + (f"_{task}" if task else "")  # the table on another task than the paper's
                      + seeded)
        files = {stem.with_suffix(".md"): markdown, stem.with_suffix(".csv"): table.to_csv(),
                 stem.with_name(f"{stem.name}_ci.csv"): table.to_ci_csv(), stem.with_suffix(".tex"): table.to_latex()}
        try:
            for path, text in files.items():
                atomic_write_text(path, text)
        except OSError as exc:
            raise ConfigError(f"cannot write the table files ({exc.strerror or exc}); expected a writable "
                              f"--out folder", str(out)) from None
        print(f"written: {stem}.md, .csv, _ci.csv, .tex\n")
    if curves:
        from detach.runs.curves import write_sweep_curves

        title = (f"{name}" + (f" [{preset}]" if preset else "")
                 + (f", seeds {', '.join(map(str, seeds))}" if seeds else ""))
        for path in write_sweep_curves(curves, out, name + seeded, title, _stderr):
            print(f"written: {path}")
    return 0


def _check_writable(out: Path) -> None:
    """Refuse an --out the table files cannot be written to before anything is printed."""
    existing = next(p for p in (out, *out.parents) if p.exists())
    if not existing.is_dir():
        raise ConfigError(f"--out: expected a folder, found a file ({existing})", str(out))
    if not os.access(existing, os.W_OK | os.X_OK):
        raise ConfigError(f"--out: {existing} is not writable", str(out))

