"""What resuming a run may do: from which checkpoint, with which overrides, and when to refuse.

A run is continued from its newest checkpoint that reads back whole (newer broken files are
renamed *.corrupt); a run killed before its first checkpoint restarts from iteration 0 with
its recorded config. Overrides may only train longer or evaluate differently, never change
what the checkpoints were trained with, and a run another live process trains is refused:
two processes training one folder would corrupt it (docs/RELIABILITY.md).
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

from detach.config import ConfigError, load_run_config
from detach.config.schema import RunConfig
from detach.eval.trial_sets import TrialSetError
from detach.runfolder.folder import RunFolder
from detach.runfolder.liveness import STALE_AFTER_S, this_host
from detach.runfolder.names import checkpoint_iteration
from detach.runs.session import trial_set_of
from detach.train.checkpoints import check_model, newest_readable_checkpoint, read_checkpoint
from detach.train.schedule import resumed_stages

RESUME_OVERRIDABLE = ("train.max_iterations", "train.save_interval", "train.keep_checkpoints",
                      "train.torch_threads", "train.stages.", "eval.")
"""What a resume may change: how long and how often to save, how to evaluate, and how many
CPU threads torch uses (speed, not numbers: a run may go on where there are more cores)."""


@dataclass(frozen=True)
class ResumePlan:
    """How a run is taken up: its stored config, the config it continues with, and the
    checkpoint it continues from (None: it restarts from iteration 0)."""

    run: RunFolder
    stored: RunConfig
    config: RunConfig
    checkpoint: Path | None


def plan_resume(run_dir: Path, overrides: Sequence[str] = (), test_offset: int | None = None,
                rename: bool = True) -> ResumePlan:
    """Check that the run may be resumed with `overrides` and choose its checkpoint (`rename`:
    rename newer unreadable checkpoints *.corrupt; a dry run leaves them). ConfigError says why not."""
    run = RunFolder(Path(run_dir))
    if not run.config_path.exists():
        raise ConfigError("not a run folder (no config.yaml)", str(run_dir))
    if run.latest_checkpoint() is None:
        return _plan_restart(run, overrides, test_offset)
    refuse_if_alive(run)
    check_test_trials(run, test_offset)
    stored = run.config()  # validates the stored config as a user error, not a traceback
    checkpoint = resume_checkpoint(run, stored, rename=rename)
    config = extended_config(run, stored, overrides, checkpoint) if overrides else stored
    return ResumePlan(run, stored, config, checkpoint)


def _plan_restart(run: RunFolder, overrides: Sequence[str], test_offset: int | None) -> ResumePlan:
    """A run killed before its first checkpoint: nothing to resume from, so it trains again
    from iteration 0 with its recorded config (a new log.mcap replaces the old one)."""
    try:
        run.status()
    except (OSError, ValueError) as exc:
        raise ConfigError(f"run has no checkpoint, and its status.json is unreadable ({exc}); "
                          f"expected a run folder that was started", str(run.path)) from None
    refuse_if_alive(run)
    check_test_trials(run, test_offset)
    stored = run.config()
    _check_overridable(overrides)
    config = load_run_config(run.config_path, overrides) if overrides else stored
    return ResumePlan(run, stored, config, None)


def check_test_trials(run: RunFolder, test_offset: int | None) -> None:
    """Refuse --test-trials for a run that is no sweep cell before anything trains."""
    try:
        trial_set_of(run, test_offset)
    except TrialSetError as exc:
        raise ConfigError(str(exc)) from None


def resume_checkpoint(run: RunFolder, cfg: RunConfig, rename: bool = True) -> Path:
    """The newest checkpoint that reads back whole and is of the run's model. Newer files that
    do not read back (truncated, corrupt) are renamed *.corrupt: the resumed run writes
    those iterations again, and no reader should pick the broken file meanwhile."""
    checkpoint = newest_readable_checkpoint(run.path)
    if checkpoint is None:
        raise ConfigError("no checkpoint of the run reads back whole (all truncated or corrupt)",
                          str(run.checkpoints))
    check_model(read_checkpoint(checkpoint), checkpoint, cfg.model_name, cfg.model.kind)
    for newer in run.checkpoint_files():
        if newer == checkpoint or not rename:
            break
        newer.rename(newer.with_name(newer.name + ".corrupt"))
        print(f"renamed the unreadable {newer.name} to {newer.name}.corrupt")
    return checkpoint


def refuse_if_alive(run: RunFolder) -> None:
    """Two processes training one run folder would corrupt it. A pid of this host is looked
    up; one of another host (shared storage) is trusted while its heartbeat is fresh."""
    if not run.owner_alive():
        return
    status = run.status()
    if status.host and status.host != this_host():
        raise ConfigError(f"run is still {status.state} on host {status.host} (pid {status.pid}, status "
                          f"updated {time.time() - (status.updated or 0):.0f} s ago); stop it there, or "
                          f"resume once its status is {STALE_AFTER_S:.0f} s old", str(run.path))
    raise ConfigError(f"run is still {status.state} (pid {status.pid}); stop it first "
                      f"(kill -TERM {status.pid}) and resume when it is interrupted", str(run.path))


def _check_overridable(overrides: Sequence[str]) -> None:
    for text in overrides:
        key = text.split("=", 1)[0]
        if not key.startswith(RESUME_OVERRIDABLE):
            raise ConfigError(f"cannot change '{key}' when resuming; only "
                              f"{', '.join(k + '*' if k.endswith('.') else k for k in RESUME_OVERRIDABLE)} may change")


def extended_config(run: RunFolder, old: RunConfig, overrides: Sequence[str], checkpoint: Path) -> RunConfig:
    """The run's config (`old`, as stored) with overrides that cannot invalidate the
    checkpoints (train longer).

    The past never changes: a longer run extends its last stage (DETACH's schedule is
    written out in train.stages, so it is no longer rescaled), and a schedule stated with
    train.stages.* must give every completed iteration the stage it was trained in."""
    _check_overridable(overrides)
    new = load_run_config(run.config_path, overrides)
    completed = checkpoint_iteration(checkpoint.name)
    if new.train.max_iterations <= completed:
        raise ConfigError(f"train.max_iterations: expected more than the {completed + 1} iterations the "
                          f"run has completed, found {new.train.max_iterations}")
    stated = any(text.split("=", 1)[0].startswith("train.stages.") for text in overrides)
    stages = resumed_stages(old, new, completed, stated)
    if stages is not None:
        new = dataclasses.replace(new, train=dataclasses.replace(new.train, stages=stages))
    return new
