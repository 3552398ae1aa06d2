"""`detach-run export SWEEP_YAML ...`: a sweep's policies shipped without their run folders.

A table cell can be checked without retraining only if its policy is kept. Run folders with
checkpoints are too large to commit, so each chosen cell's policy is exported actor-only in
float16 (`export --format policy`, a few MB) with the run's config beside it, and a manifest
says which cell each file is (key, config digest, commit) and what it scores: the exported
file itself is evaluated on the cell's evaluation tasks and trial set, so `detach-run eval
FILE --task T [--test-trials OFFSET]` repeats the manifest's figure exactly (the float32
cell's own figure is listed beside it).
"""

from __future__ import annotations

import hashlib
import sys
from pathlib import Path
from typing import Callable, Sequence

from detach.config import ConfigError
from detach.runs.export import export_run
from detach.runfolder.atomic import atomic_write_json, atomic_write_text
from detach.runfolder.folder import RunFolder, read_eval, read_json
from detach.runs.provenance import last_git
from detach.runs.session import eval_config, eval_path, evaluate_policy_file
from detach.runs.sweep_config import load_sweep
from detach.runs.sweep_graph import cells, existing_runs

MANIFEST = "manifest.json"


def _commit(run: RunFolder) -> str | None:
    """The commit the run was started (or last resumed) at, from provenance.json."""
    git = last_git(run) or {}
    return f"{git['commit']}{' (dirty)' if git.get('dirty') else ''}" if git.get("commit") else None


def _figures(result_path: Path) -> dict:
    e = read_eval(result_path)
    return {"task": e.task, "trial_set": e.trial_set, "trial_seed": e.trial_seed, "trials": e.trials,
            "lh_mean": e.lh_mean.rate, "lh_mean_ci": list(e.lh_mean.ci), "lh_chain": e.lh_chain.rate,
            "subtasks": {f"{s.index}:{s.skill}": s.rate for s in e.subtasks}, "aids": e.aids}


def _refuse_foreign_manifest(manifest: Path, sweep: str, preset: str | None, stage: str) -> None:
    """One manifest per folder: shipping another sweep, preset or stage into a folder would
    overwrite the manifest of the policies already there, which then lose their figures."""
    if not manifest.exists():
        return
    try:
        held = read_json(manifest)  # bounded: a policy folder may come from elsewhere
        found = (held["sweep"], held["preset"], held["stage"])
    except (OSError, ValueError, KeyError, TypeError):
        raise ConfigError("--output holds a manifest.json that is not a policy manifest; expected a folder "
                          "without one or with this sweep's", str(manifest)) from None
    if found != (sweep, preset, stage):
        raise ConfigError(f"--output holds the policies of sweep {found[0]}, preset {found[1]}, stage {found[2]}; "
                          f"shipping {sweep}, preset {preset}, stage {stage} there would overwrite their "
                          f"manifest: choose another --output", str(manifest))


def ship_sweep(sweep_path: Path, runs_dir: Path, out: Path, stage: str, preset: str | None = None,
               seeds: Sequence[int] | None = None, models: Sequence[str] | None = None,
               trials: int | None = None, device: str = "cpu",
               report: Callable[[str], None] = lambda s: print(s, file=sys.stderr)) -> Path:
    """Export the policy of every finished cell of `stage` (of `models`, default all) into
    `out`, evaluate each exported file as the sweep evaluates the cell, and write
    out/manifest.json (and manifest.md). Returns the manifest's path."""
    sweep = load_sweep(sweep_path, preset=preset, seeds=seeds)
    chosen = [c for c in cells(sweep, sweep_path) if c.stage == stage and (not models or c.model in models)]
    if not chosen:
        raise ConfigError(f"no cell of stage '{stage}'" + (f" of {', '.join(models)}" if models else "")
                          + f" in sweep {sweep.name}; stages: {', '.join(s.name for s in sweep.stages)}",
                          str(sweep_path))
    _refuse_foreign_manifest(out / MANIFEST, sweep.name, sweep.preset, stage)
    runs = existing_runs(runs_dir)
    out.mkdir(parents=True, exist_ok=True)
    entries = []
    for cell in chosen:
        run = runs.get(cell.key)
        if run is None or run.status().state != "finished":
            report(f"skipped {cell.key}: no finished run of it in {runs_dir}")
            continue
        name = f"{sweep.name}_{sweep.preset or 'default'}_{cell.stage}_{cell.model}_s{cell.seed}"
        exported = export_run(run.path, fmt="policy", output=out / f"{name}.policy.pt")
        cfg = run.config()
        figures, cell_figures = [], []
        for task in cell.evals:
            path = evaluate_policy_file(exported.path, task, None, trials, device, test_offset=cell.test_offset)
            figures.append(_figures(path))
            own = eval_path(run, cfg, eval_config(cfg, None if task.stem == cfg.task_name else task), cell.trial_set)
            if own.exists():
                cell_figures.append(_figures(own))
        entries.append({"file": exported.path.name, "cell": cell.key, "config_digest": cell.key.rsplit("/", 1)[1],
                        "model": cell.model, "seed": cell.seed, "stage": cell.stage, "run": run.path.name,
                        "commit": _commit(run), "iteration": exported.iteration,
                        "sha256": hashlib.sha256(exported.path.read_bytes()).hexdigest(),
                        "bytes": exported.path.stat().st_size, "figures": figures, "cell_figures": cell_figures})
        report(f"shipped {cell.key} -> {exported.path.name} ({exported.path.stat().st_size / 1e6:.1f} MB)")
    manifest = out / MANIFEST
    atomic_write_json(manifest, {"sweep": sweep.name, "preset": sweep.preset, "stage": stage,
                                 "test_seed_offset": sweep.test_seed_offset, "policies": entries})
    atomic_write_text(manifest.with_suffix(".md"), _markdown(entries, sweep.test_seed_offset))
    return manifest


def _markdown(entries: list[dict], offset: int | None) -> str:
    lines = ["| file | cell | commit | task | trials | LH mean [95%] | chain | cell's own (float32) |",
             "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    for e in entries:
        own = {f["task"]: f for f in e["cell_figures"]}
        for f in e["figures"]:
            o = own.get(f["task"])
            lines.append(f"| {e['file']} | {e['cell']} | {(e['commit'] or '?')[:12]} | {f['task']} | "
                         f"{f['trials']} {f['trial_set']} | {f['lh_mean']:.2f} [{f['lh_mean_ci'][0]:.2f}, "
                         f"{f['lh_mean_ci'][1]:.2f}] | {f['lh_chain']:.2f} | "
                         f"{'-' if o is None else format(o['lh_mean'], '.2f')} |")
    repeat = ("detach-run eval FILE --task TASK --trials N"
              + (f" --test-trials {offset}" if offset is not None else ""))
    return "\n".join(lines) + f"\n\nEach figure is the exported file's own; `{repeat}` repeats it.\n"
