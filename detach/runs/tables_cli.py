"""`detach-run table`: the paper's tables from the eval*.json files of runs or a sweep.

Five guards keep a table honest:
- a table reads one trial set (`detach.eval.trial_sets`): a sweep's the held-out test trials
  (its `test_seed_offset`), a runs folder's the development trials, and says which in a note;
  each row names its aids, computed from the configs of the cell and the cells it started
  from (`detach.eval.aids`);
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

A sweep's table also notes the commit(s) its cells were trained at (`code_note`).
"""

from __future__ import annotations

import os
import sys
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Collection, Mapping, Sequence

from detach.config import ConfigError
from detach.eval.aids import merge_aids, run_aids
from detach.eval.tables import TABLES, render
from detach.eval.trial_sets import describe
from detach.runfolder.eval_result import EvalResult
from detach.runfolder.names import trial_set_of_file
from detach.runfolder.atomic import atomic_write_text
from detach.runfolder.folder import RunFolder, find_runs, read_eval
from detach.runs.provenance import last_git

Report = Callable[[str], None]


def _stderr(line: str) -> None:
    print(f"detach-run table: {line}", file=sys.stderr)


@dataclass
class _Found:
    result: EvalResult
    path: Path
    written: float


AidsOf = Callable[[RunFolder], list[str]]


def own_aids(run: RunFolder) -> list[str]:
    """The aids of a run's own config ([] where it does not read back)."""
    try:
        return run_aids(run.config())
    except (OSError, ValueError, ConfigError):
        return []


def collect_evals(runs: list[RunFolder], cells: Mapping[str, Collection[str]] | None = None,
                  report: Report = _stderr, trial_set: str | None = None,
                  aids_of: AidsOf | None = None) -> list[EvalResult]:
    """Every usable eval*.json of the given runs (when `cells` is given: of those sweep cells,
    on the tasks it names for each; with `trial_set`, of that set only); of a sweep cell
    evaluated more than once on a task, only the newest evaluation. `aids_of` names each
    run's aids (default: those its evaluation recorded, else its own config's)."""
    found: dict[tuple[str, ...], _Found] = {}
    duplicates = unasked = 0
    aids_of = aids_of or own_aids
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
        for path in run.evaluation_paths():
            if trial_set is not None and trial_set_of_file(path.name) != trial_set:
                continue
            try:
                result = read_eval(path)
                written = path.stat().st_mtime
            except (OSError, ValueError) as exc:
                report(f"skipped {path}: {exc}")
                continue
            if trial_set is not None and result.trial_set != trial_set:
                report(f"skipped {path}: it holds {result.trial_set} trials, not {trial_set} trials as its name says")
                continue
            if cells is not None or result.aids is None:
                result.aids = aids_of(run)
            if cells is not None and result.task not in cells[cell]:
                unasked += 1
                continue
            key = ("cell", cell, result.task, result.trial_set) if cell else ("run", run_id, path.name)
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
                seeds: Sequence[int] | None = None, trial_set: str | None = None) -> int:
    """Print the table(s) of a runs folder or of a sweep's cells (under `preset`, None = the
    sweep's default settings; of `seeds` instead of its own when given) and write .md, .csv,
    _ci.csv and .tex beside each. `trial_set` (None: a sweep's test set where it has one, else
    the development set) picks the evaluations; a development table of a sweep with a test set
    writes files ending in `_dev`."""
    if not source.exists():
        raise ConfigError("sweep file or runs folder not found", str(source))
    if source.is_dir() and seeds is not None:
        raise ConfigError("--seeds: with a sweep file only (a runs folder's table pools every run in it)", str(source))
    seeded = "" if seeds is None else "_seeds" + "-".join(map(str, seeds))  # the preset's own files stay
    offset = None
    if source.is_dir():
        trial_set = trial_set or "development"
        evals = collect_evals(find_runs(source), trial_set=trial_set)
        kinds, name = [kind] if kind else list(TABLES), source.name
        out = out or source / "tables"
        curves = None
    else:
        from detach.runs.sweep_config import load_sweep
        from detach.runs.sweep_graph import cell_evaluations, existing_runs

        sweep = load_sweep(source, preset=preset, seeds=seeds)
        offset = sweep.test_seed_offset
        trial_set = trial_set or ("test" if offset is not None else "development")
        if trial_set == "test" and offset is None:
            raise ConfigError("--trial-set test: this sweep has no test_seed_offset (no held-out trials)", str(source))
        cells = cell_evaluations(source, preset, seeds)
        runs = existing_runs(runs_dir)
        evals = collect_evals(find_runs(runs_dir), cells, trial_set=trial_set,
                              aids_of=_chain_aids(source, sweep, runs, trial_set == "test"))
        kinds, name = [kind or sweep.table], sweep.name
        out = out or runs_dir / "tables"
        curves = {key: run for key, run in runs.items() if key in cells}
    if trial_set == "development" and offset is not None:
        seeded += "_dev"  # the sweep's own name is its test table's
    if not evals:
        raise ConfigError(f"no evaluation on the {trial_set} trials found (train and evaluate runs first"
                          + ("; `detach-run sweep` evaluates its finished cells on them)" if trial_set == "test"
                             else ")"), str(source))
    _check_writable(out)
    evaluated = sorted({e.task for e in evals})
    if task is not None and task not in evaluated:  # else an empty table, exit 0: a typo looks like no result
        raise ConfigError(f"--task: no evaluation of task '{task}' (evaluated: {', '.join(evaluated)})",
                          str(source))
    code = code_note(curves) if curves else None
    for k in kinds:
        table = render(k, evals, task, sgr_variant)
        table.notes.append(describe(trial_set, offset))
        if code:
            table.notes.append(code)
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


def code_note(runs: Mapping[str, RunFolder]) -> str | None:
    """Which code trained the sweep's cells (their provenance.json), for the table's notes. A
    cell's key digests its config, not the code, so one table can pool cells that the same
    key trained under different code (a reward or clip change between sessions); the note
    makes that visible. None when no cell's commit is known."""
    gits = [git for git in map(last_git, runs.values()) if git and git.get("commit")]
    counts = Counter(str(git["commit"])[:7] + (" with uncommitted changes" if git.get("diff") else "")
                     for git in gits)
    if not counts:
        return None
    total = sum(counts.values())
    cells = f"the sweep's {total} cell{'s' if total > 1 else ''} in the runs folder"
    if len(counts) == 1:
        return f"Code: {cells}: trained at commit {next(iter(counts))}."
    listed = ", ".join(f"{c} ({n} cell{'s' if n > 1 else ''})" for c, n in counts.most_common())
    return (f"Code: {cells}: trained at {len(counts)} commits, {listed}; a cell's key digests its config, "
            f"not the code (each cell's provenance.json).")


AFTER_TEST = "recipe chosen after a test evaluation"
"""The aid that marks a cell trained after the test trials of another recipe of its stage,
model and seed were played in the same runs folder: its recipe may have been picked on them."""


def _chain_aids(source: Path, sweep, runs: Mapping[str, RunFolder], test: bool) -> AidsOf:
    """A sweep cell's aids: its own and those of the cells it started from (the policy
    inherits them), plus `AFTER_TEST` (test tables) where `_after_test` says so."""
    from detach.runs.sweep_graph import cells as sweep_cells

    parents = {c.key: c.parent for c in sweep_cells(sweep, source)}

    def aids_of(run: RunFolder) -> list[str]:
        try:
            key = run.status().cell
        except (OSError, ValueError):
            key = None
        chain, at = [], key
        while at is not None and at in runs:
            chain.append(own_aids(runs[at]))
            at = parents.get(at)
        aids = merge_aids(reversed(chain)) if chain else own_aids(run)
        if test and key is not None and _after_test(key, run, runs):
            aids.append(AFTER_TEST)
        return aids

    return aids_of


def _after_test(key: str, run: RunFolder, runs: Mapping[str, RunFolder]) -> bool:
    """Another cell of the same stage, model and seed (another recipe: another digest) had
    a test evaluation on file before this cell's run was created."""
    prefix = key.rsplit("/", 1)[0] + "/"
    try:
        created = run.config_path.stat().st_mtime
    except OSError:
        return False
    for other_key, other in runs.items():
        if other_key == key or not other_key.startswith(prefix):
            continue
        for path in other.evaluation_paths():
            try:
                if trial_set_of_file(path.name) == "test" and path.stat().st_mtime < created:
                    return True
            except OSError:
                continue
    return False


def _check_writable(out: Path) -> None:
    """Refuse an --out the table files cannot be written to before anything is printed."""
    existing = next(p for p in (out, *out.parents) if p.exists())
    if not existing.is_dir():
        raise ConfigError(f"--out: expected a folder, found a file ({existing})", str(out))
    if not os.access(existing, os.W_OK | os.X_OK):
        raise ConfigError(f"--out: {existing} is not writable", str(out))

