"""Which checkpoint of a run folder is which: the run's policy, the one to resume from.

Reading a checkpoint needs torch, which this package keeps out: callers pass the reader
(`detach.train.checkpoints.read_checkpoint`) and the error class that marks a file as
truncated or corrupt, and the choice itself is made here, once.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

from detach.runfolder.messages import ContractError
from detach.runfolder.names import (
    CHECKPOINT_DIR, CHECKPOINT_PREFIX, REPLAY_PREFIX, SELECTION_FILE, checkpoint_file, checkpoint_iteration,
    replay_iteration,
)


def checkpoint_folder(run_dir: Path) -> Path:
    return Path(run_dir) / CHECKPOINT_DIR


def checkpoint_path(folder: Path, iteration: int) -> Path:
    """The checkpoint after `iteration` in a checkpoints/ folder."""
    return Path(folder) / checkpoint_file(iteration)


def checkpoints_in(folder: Path) -> dict[int, Path]:
    """iteration -> model_<iteration>.pt of a checkpoints/ folder."""
    found = ((checkpoint_iteration(p.name), p) for p in Path(folder).glob(f"{CHECKPOINT_PREFIX}*.pt"))
    return {it: p for it, p in found if it is not None}


def replays_in(folder: Path) -> dict[int, Path]:
    """iteration -> AMP replay sidecar of a checkpoints/ folder."""
    return {it: p for p in Path(folder).glob(f"{REPLAY_PREFIX}*.pt") if (it := replay_iteration(p.name)) is not None}


def checkpoint_files(run_dir: Path) -> list[Path]:
    """A run's checkpoints (model_<iter>.pt), newest first."""
    return [p for _it, p in sorted(checkpoints_in(checkpoint_folder(run_dir)).items(), reverse=True)]


def has_checkpoint(run_dir: Path) -> bool:
    """Whether the run has a checkpoint file (read or not)."""
    try:
        return any(checkpoint_iteration(p.name) is not None for p in checkpoint_folder(run_dir).iterdir())
    except OSError:
        return False


def selected_checkpoint(run_dir: Path) -> Path | None:
    """The checkpoint that selection.json names as the run's policy, None when there is no
    selection (the run's policy is then its newest checkpoint) or its file is gone. A
    selection.json that does not follow the format raises ContractError."""
    path = Path(run_dir) / SELECTION_FILE
    try:
        text = path.read_text()
    except FileNotFoundError:
        return None
    try:
        name = json.loads(text)["checkpoint"]
    except (ValueError, KeyError, TypeError):
        raise ContractError(f"{path}: expected a JSON object with a 'checkpoint' file name") from None
    if not isinstance(name, str) or checkpoint_iteration(name) is None:
        raise ContractError(f"{path}: 'checkpoint' is not a checkpoint file name: {name!r}")
    chosen = Path(run_dir) / CHECKPOINT_DIR / name
    return chosen if chosen.is_file() else None




CheckpointReader = Callable[[Path], object]
"""Reads a checkpoint whole or raises; `unreadable` is the error of a truncated or corrupt file."""


def newest_readable(run_dir: Path, read: CheckpointReader, unreadable: type[Exception],
                    report: Callable[[str], None] = print) -> Path | None:
    """The newest checkpoint that reads back whole (None when there is none): a truncated or
    corrupt newest file (a disk that filled, a copy cut short) falls back to the previous
    one, with a line saying so. Other errors of `read` are not skipped: falling back would
    hide them."""
    for path in checkpoint_files(run_dir):
        try:
            read(path)
        except unreadable as exc:
            report(f"skipping {exc}")
            continue
        return path
    return None


def policy_checkpoint(run_dir: Path, read: CheckpointReader, unreadable: type[Exception],
                      report: Callable[[str], None] = print) -> Path | None:
    """A run's policy: the checkpoint selection.json chose on validation trials, else the
    newest that reads back whole. Every reader of a run's policy goes through here, so a
    later stage starts from the very file the run was evaluated with. ContractError for a
    selection.json that does not follow the format."""
    chosen = selected_checkpoint(Path(run_dir))
    if chosen is not None:
        try:
            read(chosen)
            return chosen
        except unreadable as exc:
            report(f"skipping the selected checkpoint: {exc}")
    return newest_readable(run_dir, read, unreadable, report)
