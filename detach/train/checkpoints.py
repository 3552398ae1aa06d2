"""Checkpoint files: written whole, read without running code, pruned, and the random state.

- Reading never unpickles: `torch.load(..., weights_only=True)` only rebuilds tensors and
  plain containers, so a checkpoint crafted to run code on load is refused (a pickled
  `__reduce__` would otherwise execute on `--eval`, `--resume` and a sweep's automatic
  resume). Every way a file can be unusable (refused, truncated, not a checkpoint, of
  another model) is one `CheckpointError` line, which the CLI reports with exit code 2.
- Writing goes through `detach.runfolder.atomic.atomic_writer`: fsynced, renamed into place, the
  temporary file removed when the disk is full or the process is stopped mid-write.
- Retention (`train.keep_checkpoints`): the newest `last` checkpoints and every checkpoint
  whose iteration count is a multiple of `every`; the AMP replay sidecar only for the newest.
- The random-number state (Python, NumPy, torch CPU and CUDA, the environment's generator)
  travels in the checkpoint so that a resumed run draws what the uninterrupted run would have.
"""

from __future__ import annotations

import contextlib
import pickle
import random
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch

from detach.runfolder.atomic import atomic_writer, fsync_folder
from detach.runfolder.checkpoints import checkpoints_in, newest_readable, policy_checkpoint, replays_in
from detach.runfolder.folder import RunFolder
from detach.runfolder.messages import ContractError
from detach.runfolder.names import checkpoint_iteration, replay_file
from detach.config.yaml_source import ConfigError

REQUIRED_KEYS = ("actor_state_dict", "critic_state_dict", "iter")


PICKLED_REFUSAL = ("refused: the file holds Python objects besides tensors, which are not loaded because "
                   "loading them could run code (detach never writes such files); re-export the weights from "
                   "the run that made it with `detach-run export RUN --format init` (or save only tensors: "
                   "actor_state_dict, critic_state_dict, iter)")
"""Why a checkpoint that needs unpickling is refused, and how to get one that does not."""


class CheckpointError(ConfigError):
    """A checkpoint that cannot be used, in one line naming the file and why."""


class UnreadableCheckpoint(CheckpointError):
    """A truncated or corrupt file: an older checkpoint may stand in for it."""


def read_checkpoint(path: Path, map_location: str | torch.device | None = "cpu",
                    actor_only: bool = False) -> dict[str, Any]:
    """The checkpoint's dict, loaded with `weights_only=True`; CheckpointError otherwise.
    `actor_only`: a policy without its critic (`detach-run export --format policy`) will do."""
    try:
        state = torch.load(path, map_location=map_location, weights_only=True)
    except FileNotFoundError:
        raise CheckpointError("checkpoint not found", str(path)) from None
    except pickle.UnpicklingError as exc:
        if "weights only" in str(exc).lower():
            raise CheckpointError(PICKLED_REFUSAL, str(path)) from None
        raise UnreadableCheckpoint(f"unreadable checkpoint (corrupt: {first_line(exc)})", str(path)) from None
    except (RuntimeError, EOFError, KeyError, ValueError, OSError, IndexError, TypeError) as exc:
        raise UnreadableCheckpoint(f"unreadable checkpoint, truncated or corrupt ({type(exc).__name__}: "
                              f"{first_line(exc)})", str(path)) from None
    required = [k for k in REQUIRED_KEYS if not (actor_only and k == "critic_state_dict")]
    if not isinstance(state, dict) or any(k not in state for k in required):
        raise CheckpointError(f"not a detach checkpoint (expected the keys {', '.join(required)})",
                              str(path))
    return state


def first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return (text[0][:120] if text else "") or "no detail"


def read_sidecar(path: Path, map_location: str | torch.device | None = "cpu") -> Any:
    """A file saved beside a checkpoint (the AMP replay buffer), loaded weights-only too."""
    try:
        return torch.load(path, map_location=map_location, weights_only=True)
    except Exception as exc:  # noqa: BLE001 - every way a file can be unusable is one line
        raise CheckpointError(f"unreadable AMP replay buffer ({type(exc).__name__}: {first_line(exc)}); "
                              f"delete it to resume with an empty buffer", str(path)) from None


def check_model(state: dict[str, Any], path: Path, model_name: str, model_kind: str) -> None:
    """CheckpointError when the checkpoint records another model than the run's."""
    infos = state.get("infos") if isinstance(state.get("infos"), dict) else {}
    saved_name, saved_kind = infos.get("model"), infos.get("model_kind")
    if saved_name is None and saved_kind is None:
        return  # written before checkpoints named their model: the weights themselves decide
    if (saved_name, saved_kind) != (model_name, model_kind):
        raise CheckpointError(f"checkpoint is for model {saved_name} ({saved_kind}), the run is "
                              f"{model_name} ({model_kind})", str(path))


def describe_mismatch(expected: dict[str, torch.Tensor], found: Any) -> str:
    """Why the weights `found` do not fit a module whose state dict is `expected`, briefly."""
    if not isinstance(found, dict):
        return f"expected a state dict, found {type(found).__name__}"
    missing = [k for k in expected if k not in found]
    unexpected = [k for k in found if k not in expected]
    shapes = [k for k in expected if k in found and torch.is_tensor(found[k])
              and tuple(found[k].shape) != tuple(expected[k].shape)]
    parts = [f"{len(keys)} {what} (e.g. {keys[0]})" for what, keys in
             (("missing", missing), ("unexpected", unexpected), ("of another shape", shapes)) if keys]
    return "; ".join(parts) or "incompatible values"


def load_module_weights(module: torch.nn.Module, weights: Any, path: Path, part: str,
                        may_lack: tuple[str, ...] = ()) -> None:
    """`module.load_state_dict(weights)`, with a one-line CheckpointError instead of the
    kilobytes of key names torch prints for a checkpoint of another architecture.
    `may_lack`: key prefixes the weights may leave out (a shipped policy's training-only
    modules, `training_only_prefixes`); those keep the module's own values. Every other key is
    still required."""
    expected = module.state_dict()
    if may_lack and isinstance(weights, dict):
        weights = {**{k: v for k, v in expected.items() if k.startswith(may_lack) and k not in weights}, **weights}
    try:
        module.load_state_dict(weights)
    except (RuntimeError, KeyError, TypeError, AttributeError):
        raise CheckpointError(f"the {part} weights do not fit this run's model ("
                              f"{describe_mismatch(expected, weights)}); was the checkpoint "
                              f"written by another model or config?", str(path)) from None


def write_checkpoint(path: Path, state: dict[str, Any]) -> None:
    """Write `state` atomically and durably (nothing is left under any name on failure)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_writer(path) as f:
        torch.save(state, f)


# ------------------------------------------------------------------------------ retention
def saves_after(iteration: int, total: int, interval: int) -> bool:
    """Whether training saves a checkpoint after 0-based `iteration` of `total`: every
    `interval`-th and the last (a stop signal saves too, `DetachRunner.learn`)."""
    return (iteration + 1) % interval == 0 or iteration == total - 1


def kept_iterations(iterations: list[int], last: int, every: int) -> set[int]:
    """Iterations whose checkpoints retention keeps: the newest `last` (all when 0), every one
    with (iteration + 1) % every == 0 (none when 0), and always the newest."""
    ordered = sorted(set(iterations), reverse=True)
    keep = set(ordered if last <= 0 else ordered[:last])
    if every > 0:
        keep |= {it for it in ordered if (it + 1) % every == 0}
    return keep | set(ordered[:1])


def prune_checkpoints(folder: Path, last: int, every: int) -> list[Path]:
    """Delete checkpoints retention does not keep and replay sidecars of all but the newest
    checkpoint; returns the deleted files."""
    models = checkpoints_in(folder)
    keep = kept_iterations(list(models), last, every)
    newest = max(models, default=None)
    doomed = [p for it, p in models.items() if it not in keep]
    doomed += [p for it, p in replays_in(folder).items() if it != newest]
    for path in doomed:
        with contextlib.suppress(OSError):
            path.unlink()
    if doomed:
        fsync_folder(folder)
    return doomed


LOW_DISK_SAVES = 20
"""Warn when the disk holding a run's checkpoints has room for fewer saves than this."""


def folder_bytes(folder: Path) -> int:
    """Bytes of the files directly in `folder` (0 when it is missing)."""
    if not folder.is_dir():
        return 0
    return sum(p.stat().st_size for p in folder.iterdir() if p.is_file())


def disk_room_warning(folder: Path, save_bytes: int, growth_bytes: int) -> tuple[int, str] | None:
    """(saves that still fit, a warning line) when the disk under `folder` is close to full,
    else None. A save needs room for its whole file while it is written (`save_bytes`) and
    leaves the folder `growth_bytes` larger once retention has pruned; a run that fills the
    disk fails mid-write, so the line comes while there is still time to free space."""
    free = shutil.disk_usage(folder).free
    per_save = max(growth_bytes, 0)
    fits = free // per_save if per_save else (LOW_DISK_SAVES if free >= 2 * save_bytes else 0)
    if fits >= LOW_DISK_SAVES:
        return None
    return int(fits), (f"warning: {free / 2**30:.1f} GiB free on the disk of {folder}: room for about "
                       f"{int(fits)} more checkpoint saves (each {save_bytes / 2**20:.0f} MB written, "
                       f"the folder grows {per_save / 2**20:.0f} MB per save); free space or keep fewer "
                       "(train.keep_checkpoints), or the run stops when the disk is full")


def replay_path(checkpoint: Path) -> Path | None:
    """The AMP replay sidecar saved with a checkpoint (None for a file not named model_<it>.pt)."""
    iteration = checkpoint_iteration(checkpoint.name)
    return None if iteration is None else checkpoint.with_name(replay_file(iteration))


# ------------------------------------------------------------------------------ random state
def capture_rng(env_generator: torch.Generator | None = None) -> dict[str, Any]:
    """Every random-number state a training iteration draws from, as weights-only data."""
    version, internal, gauss = random.getstate()
    name, keys, pos, has_gauss, cached = np.random.get_state()
    state: dict[str, Any] = {
        "python": {"version": version, "state": torch.tensor(internal, dtype=torch.int64), "gauss": gauss},
        "numpy": {"name": name, "keys": torch.from_numpy(keys.astype(np.int64)), "pos": int(pos),
                  "has_gauss": int(has_gauss), "cached_gaussian": float(cached)},
        "torch": torch.get_rng_state(),
    }
    if torch.cuda.is_available() and torch.cuda.is_initialized():
        state["cuda"] = torch.cuda.get_rng_state_all()
    if env_generator is not None:
        state["env"] = env_generator.get_state()
    return state


def restore_rng(state: dict[str, Any], env_generator: torch.Generator | None = None) -> None:
    """Inverse of `capture_rng` (states absent from an older checkpoint stay as they are)."""
    if "python" in state:
        py = state["python"]
        random.setstate((py["version"], tuple(int(v) for v in py["state"].tolist()), py["gauss"]))
    if "numpy" in state:
        npy = state["numpy"]
        np.random.set_state((npy["name"], npy["keys"].numpy().astype(np.uint32), npy["pos"],
                             npy["has_gauss"], npy["cached_gaussian"]))
    if "torch" in state:
        torch.set_rng_state(state["torch"].cpu())
    if "cuda" in state and torch.cuda.is_available():
        torch.cuda.set_rng_state_all([s.cpu() for s in state["cuda"]])
    if "env" in state and env_generator is not None:
        env_generator.set_state(state["env"].cpu())


def newest_readable_checkpoint(run_dir: Path, map_location: str | torch.device | None = "cpu",
                               report: Callable[[str], None] = print) -> Path | None:
    """The newest checkpoint that reads back whole (None when there is none; the choice:
    `detach.runfolder.checkpoints.newest_readable`). A truncated or corrupt newest file falls
    back to the previous one, with a line saying so; a file refused for holding code, or one
    of another model, is not skipped: CheckpointError, since falling back would hide it."""
    return newest_readable(run_dir, lambda path: read_checkpoint(path, map_location), UnreadableCheckpoint, report)


def run_policy_checkpoint(run_dir: Path, map_location: str | torch.device | None = "cpu",
                          report: Callable[[str], None] = print) -> Path | None:
    """A run's policy: the checkpoint selection.json chose on validation trials
    (`train.select_checkpoint_trials`), else the newest that reads back whole
    (`detach.runfolder.checkpoints.policy_checkpoint`). Every reader of a run's policy
    (evaluation, play, export, a later stage's `train.init_from`) goes through here."""
    try:
        return policy_checkpoint(run_dir, lambda path: read_checkpoint(path, map_location), UnreadableCheckpoint,
                                 report)
    except ContractError as exc:
        raise CheckpointError(str(exc)) from None


def find_init_checkpoint(source: str, report: Callable[[str], None] = print) -> tuple[Path, Path | None]:
    """(checkpoint file, its run folder or None) of `train.init_from`: a run folder (its
    policy, `run_policy_checkpoint`) or a checkpoint file."""
    path = Path(source)
    if path.is_dir():
        try:
            chosen = run_policy_checkpoint(path, "cpu", report)
        except CheckpointError as exc:
            raise ConfigError(f"train.init_from: {exc}") from None
        if chosen is None:
            raise ConfigError(f"train.init_from: the run folder {path} has no readable checkpoint")
        return chosen, path
    if path.is_file():
        run = path.parent.parent
        return path, run if RunFolder(run).config_path.is_file() else None
    raise ConfigError(f"train.init_from: {source} is neither a run folder nor a checkpoint file")
