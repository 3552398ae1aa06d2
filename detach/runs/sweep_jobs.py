"""What brings a sweep cell to done, as a job for `detach.runs.worker`.

Nothing when the cell is finished and fully evaluated; the evaluations it lacks when it is
finished; a resume when it has a checkpoint; else a new run, starting from its parent cell's
run (`train.init_from`) and taught by its teacher cells' runs (`train.teachers`).
"""

from __future__ import annotations

from pathlib import Path

from detach.runfolder.folder import RunFolder
from detach.runs.sweep_graph import Cell, missing_evals
from detach.runs.job_file import JobStep
from detach.train.teachers import ORACLE
from detach.config.yaml_source import ConfigError

JOBS_DIR = ".jobs"


def job_path(out: Path, cell: Cell) -> Path:
    """`<runs>/.jobs/<cell key, / as .>.json`: one file per cell, rewritten when it runs again."""
    return out / JOBS_DIR / f"{cell.key.replace('/', '.')}.json"


def cell_steps(cell: Cell, previous: RunFolder | None, parent: RunFolder | None, out: Path,
               trials: int, device: str, teachers: dict[str, RunFolder] | None = None) -> list[JobStep]:
    """The API calls that bring the cell to done (`teachers`: the run of each teacher cell, by
    key; a resumed run keeps the teachers its config pinned)."""
    own = any(t.stem == cell.task.stem for t in cell.evals)
    common = {"trials": trials, "device": device, "test_offset": cell.test_offset}
    after = {"eval_on": [str(t) for t in cell.evals if t.stem != cell.task.stem], "evaluate": own}
    if previous is not None:
        state = previous.status().state
        if state == "finished":
            return [JobStep("evaluate", {"target": str(previous.path), "task": str(t), **common})
                    for t in missing_evals(cell, previous)]
        if previous.latest_checkpoint() is not None:
            return [JobStep("resume", {"run_dir": str(previous.path), **common, **after})]
    init = [f"train.init_from={parent.path.resolve()}"] if parent is not None else []
    taught = []
    for skill, source in cell.teachers:
        if source != ORACLE and (teachers is None or source not in teachers):
            raise ConfigError(f"cell {cell.key}: its {skill} teacher, cell {source}, has no run in {out}")
        taught.append(f"+train.teachers.{skill}={source if source == ORACLE else teachers[source].path.resolve()}")
    return [JobStep("train", {"task": str(cell.task), "model": cell.model, "seed": cell.seed, "runs": str(out),
                              "cell": cell.key, "presets": list(cell.presets), **common, **after,
                              "overrides": [*cell.overrides, *init, *taught]})]
