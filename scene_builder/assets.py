"""Public API of the asset pipeline: requests from tasks, batch builds, and reading assets back.

Stable entry points (the scene compiler and the environments rely on them):
- `default_assets_root()`: `$DETACH_ASSETS` or `./assets`.
- `requests_from_task(task, source_root)`: the deduplicated AssetRequests a task needs.
- `build_assets(requests, out, ...)`: build what is missing (cache, process pool, progress).
- `load_asset(folder) -> AssetInfo`: one built asset folder, validated.
- `read_assets(task, out) -> {object index: AssetInfo}`: a task's built assets; a missing one
  is an AssetError that says how to build it (what the scene compiler calls).
- `ensure_assets(task, out) -> {object index: AssetInfo}`: build what is missing or stale
  (with a progress line), then read; the runner calls it before it makes an environment.
Asset folder layout: docs/ARCHITECTURE.md, "Asset folder".
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, fields
from multiprocessing import get_context
from pathlib import Path
from typing import Any

import numpy as np

from detach.config.schema import SceneObjectCfg, TaskCfg
from scene_builder import procedural
from scene_builder.cache import read_config
from scene_builder.errors import AssetError
from scene_builder.pipeline import (
    PROCEDURAL, AssetRequest, BuildOptions, BuildResult, Planned, Progress, build_planned, check_cache, plan,
    print_line, source_identity,
)

__all__ = ["AssetError", "AssetInfo", "AssetRequest", "BuildOptions", "BuildResult", "build_assets",
           "default_assets_root", "ensure_assets", "load_asset", "read_assets", "request_diff",
           "request_for_object", "requests_from_task"]


REBUILD = "rebuild with `detach-scene build --force`"


def default_assets_root() -> Path:
    """Where assets live unless told otherwise: `$DETACH_ASSETS`, else `./assets` (cwd)."""
    return Path(os.environ.get("DETACH_ASSETS") or "assets")


@dataclass(frozen=True, eq=False)
class AssetInfo:
    """One built asset as the scene compiler needs it. Frames: object frame = bbox centre at
    the origin, metres, Z up, facing +Y (world pose comes from the task's pos3d/z_rot_angle)."""

    folder: Path
    category: str
    model_id: str
    mesh_path: Path
    """Visual mesh (mesh.obj)."""
    hull_paths: tuple[Path, ...]
    """Convex collision pieces (collision/hull_NNN.obj), one MuJoCo geom each."""
    bbox: tuple[float, float, float]
    tar_sit_pos: tuple[float, float, float]
    tar_climb_pos: tuple[float, float, float]
    height_map: np.ndarray
    """float32 [128, 128]; row 0 = max Y, column 0 = min X; metres above the lowest point."""
    config: dict[str, Any]
    """The whole config.json."""


def load_asset(folder: str | Path) -> AssetInfo:
    """Read an asset folder; AssetError (one line) if it is missing or incomplete."""
    folder = Path(folder)
    config = read_config(folder)
    if config is None:
        raise AssetError(f"{folder}: not an asset folder (no readable config.json); run `detach-scene build`")
    try:
        hulls = tuple(folder / name for name in config["collision"]["files"])
        hmap = np.load(folder / "height_map" / "map2d.npy")
        info = AssetInfo(
            folder=folder, category=config["category"], model_id=config["model_id"], mesh_path=folder / "mesh.obj",
            hull_paths=hulls, bbox=tuple(config["bbox"]), tar_sit_pos=tuple(config["tarSitPos"]),
            tar_climb_pos=tuple(config["tarClimbPos"]), height_map=hmap, config=config,
        )
    except (KeyError, TypeError, OSError, ValueError) as e:
        raise AssetError(f"{folder}: incomplete asset ({type(e).__name__}: {e}); {REBUILD}") from None
    missing = [p for p in (info.mesh_path, *hulls) if not p.is_file()]
    if missing:
        raise AssetError(f"{folder}: incomplete asset (missing {missing[0].name}); {REBUILD}")
    return info


def request_for_object(
    obj: SceneObjectCfg, source_root: str | Path | None = None, up: str = "y"
) -> AssetRequest:
    """The AssetRequest of one scene object. A non-procedural `source` is a path relative to
    `source_root` (default: the cwd); `up` applies to such file sources only."""
    if obj.source == PROCEDURAL:
        return AssetRequest(obj.category, obj.model_id, PROCEDURAL, obj.variant, "y", 0.0, None, obj.size)
    path = Path(obj.source)
    if not path.is_absolute() and source_root is not None:
        path = Path(source_root) / path
    return AssetRequest(obj.category, obj.model_id, str(path), obj.variant, up,  # type: ignore[arg-type]
                        0.0, None, obj.size)


def request_diff(a: AssetRequest, b: AssetRequest) -> str:
    """Which fields two requests disagree on, for error messages."""
    return ", ".join(f"{f.name} {getattr(a, f.name)!r} vs {getattr(b, f.name)!r}"
                     for f in fields(AssetRequest) if getattr(a, f.name) != getattr(b, f.name))


def requests_from_task(
    task: TaskCfg, source_root: str | Path | None = None, up: str = "y"
) -> list[AssetRequest]:
    """Unique requests of a task's scene, in scene order. Pure (no file access).

    Objects sharing `<category>/<model_id>` must ask for the same thing; otherwise one folder
    would have to hold two different assets, an AssetError naming both objects.
    """
    seen: dict[tuple[str, str], tuple[int, SceneObjectCfg, AssetRequest]] = {}
    for i, obj in enumerate(task.scene):
        req = request_for_object(obj, source_root, up)
        if req.source == PROCEDURAL:
            try:
                procedural.resolve_category(req.category)
            except AssetError as e:
                raise AssetError(f"task '{task.name}': scene[{i}] '{obj.name}': {e}") from None
        key = (req.category, req.model_id)
        if key in seen and seen[key][2] != req:
            j, other, prev = seen[key]
            raise AssetError(f"task '{task.name}': scene[{j}] '{other.name}' and scene[{i}] '{obj.name}' "
                             f"both use {key[0]}/{key[1]} but differ ({request_diff(prev, req)}); "
                             "give them different model_ids")
        seen.setdefault(key, (i, obj, req))
    return [req for _, _, req in seen.values()]


def _claimed_by_another(p: Planned, out: Path) -> str | None:
    """The source of an existing, different asset in the folder `p` would write, else None.

    Same content (sha256) or same source (file path, procedural label: an edited source is a
    rebuild) is the same asset; anything else would be silently replaced."""
    config = read_config(p.request.folder(out))
    if config is None or config.get("source_sha256") == p.sha256:
        return None
    old = config.get("source_path")
    if old is None:  # built before source_path was recorded: best effort from `source`
        old = str(config.get("source", ""))
        old = old if old.startswith(f"{PROCEDURAL}:") else os.path.abspath(old)
    return None if old == source_identity(p) else str(config.get("source", old))


def _clashes(planned: dict[int, Planned], out: Path, force: bool) -> dict[int, str]:
    """One-line errors for requests whose asset id is taken: by another request of this batch
    (all of them fail: which one should win?) or, without `force`, by a different existing asset."""
    errors: dict[int, str] = {}
    by_folder: dict[Path, list[int]] = {}
    for i, p in planned.items():
        by_folder.setdefault(p.request.folder(out), []).append(i)
    for folder, members in by_folder.items():
        sources = {source_identity(planned[i]) for i in members}
        requests = {planned[i].request for i in members}
        if len(sources) > 1 or len(requests) > 1:
            for i in members:
                others = sorted({planned[j].label for j in members if planned[j].label != planned[i].label})
                request = planned[i].request
                errors[i] = (f"{planned[i].label}: asset id {request.category}/{request.model_id} "
                             f"is also claimed by {', '.join(others) or 'a differently-built copy'} in this batch; "
                             "give one of them another id (--name CATEGORY/MODEL_ID, or separate runs with "
                             "different --out)")
    if not force:
        for i, p in planned.items():
            other = None if i in errors else _claimed_by_another(p, out)
            if other is not None:
                errors[i] = (f"{p.label}: {p.request.folder(out)} already holds a different asset (built from "
                             f"{other}); pass --force to replace it, or --name CATEGORY/MODEL_ID to build this one "
                             "under another id")
    return errors


def build_assets(
    requests: Sequence[AssetRequest],
    out: str | Path | None = None,
    options: BuildOptions | None = None,
    jobs: int | None = None,
    force: bool = False,
    progress: bool = False,
) -> list[BuildResult]:
    """Build every request into `out` (default `default_assets_root()`), one result each,
    in request order. Cached assets are skipped (a warm run only hashes and reads JSON);
    misses run in a process pool of `jobs` workers (default: all cores; 1 = in-process).
    An asset id already holding a different asset fails unless `force` (which also rebuilds
    current assets); two requests of the batch with one id both fail.
    `progress` prints a line per asset (and heartbeats while CoACD runs) on stdout, in
    terminals and redirected logs alike. Never raises for a bad input: it comes back as a
    'failed' result."""
    out = Path(out) if out is not None else default_assets_root()
    options = options or BuildOptions()
    results: dict[int, BuildResult] = {}
    planned: dict[int, Planned] = {}
    for i, req in enumerate(requests):
        try:
            planned[i] = plan(req, options)
        except AssetError as e:
            results[i] = BuildResult(req, "failed", req.folder(out), error=str(e))
    for i, error in _clashes(planned, out, force).items():
        results[i] = BuildResult(planned.pop(i).request, "failed", requests[i].folder(out), error=error)
    todo: list[tuple[int, Planned]] = []
    for i, p in planned.items():
        if not force and check_cache(p, out):
            results[i] = BuildResult(p.request, "cached", p.request.folder(out))
        else:
            todo.append((i, p))
    say: Progress | None = print_line if progress else None
    jobs = max(1, min(jobs or os.cpu_count() or 1, len(todo)))
    if say is not None and todo:
        say(f"assets: building {len(todo)} of {len(requests)} into {out}/ ({jobs} worker{'s' * (jobs > 1)}; "
            f"{len(requests) - len(todo) - sum(r.status == 'failed' for r in results.values())} cached)")
    done = 0

    def finished(i: int, result: BuildResult) -> None:
        nonlocal done
        results[i], done = result, done + 1
        if say is not None:
            what = (f"built in {result.seconds:.1f} s: {result.summary}" if result.status == "built"
                    else f"{result.status}" + (" (see the error below)" if result.status == "failed" else ""))
            say(f"[{done}/{len(todo)}] {result.request.category}/{result.request.model_id} {what}")

    if jobs == 1:
        for i, p in todo:
            if say is not None:
                say(f"[{done + 1}/{len(todo)}] {p.request.category}/{p.request.model_id}: building from {p.label}")
            finished(i, build_planned(p, out, options, say))
    else:  # spawn: no inherited Embree/OpenMP thread state from the parent
        todo_by_index = dict(todo)
        with ProcessPoolExecutor(jobs, mp_context=get_context("spawn")) as pool:
            futures = {pool.submit(build_planned, p, out, options, say): i for i, p in todo}
            for fut in as_completed(futures):
                i = futures[fut]
                try:
                    result = fut.result()
                except Exception as e:  # the worker died (e.g. a crash inside CoACD's C++ core)
                    p = todo_by_index[i]
                    result = BuildResult(p.request, "failed", p.request.folder(out),
                                         error=f"{p.label}: worker process died ({type(e).__name__}), "
                                               "possibly while building another asset; retry with --jobs 1")
                finished(i, result)
    return [results[i] for i in range(len(requests))]


def read_assets(task: TaskCfg, out: str | Path | None = None,
                source_root: str | Path | None = None) -> dict[int, AssetInfo]:
    """AssetInfo per scene object index, read from `out` (default `default_assets_root()`).

    Builds nothing: an object whose folder is missing is an AssetError naming the folder and
    the command that builds it."""
    out = Path(out) if out is not None else default_assets_root()
    loaded: dict[Path, AssetInfo] = {}
    by_index = {}
    for i, obj in enumerate(task.scene):
        folder = request_for_object(obj, source_root).folder(out)
        if folder not in loaded:
            if not (folder / "config.json").is_file():
                raise AssetError(f"task '{task.name}': scene[{i}] '{obj.name}' needs the asset {folder}, "
                                 f"which is not built; run `detach-scene build --tasks <task.yaml> --out {out}`")
            loaded[folder] = load_asset(folder)
        by_index[i] = loaded[folder]
    return by_index


def ensure_assets(
    task: TaskCfg,
    out: str | Path | None = None,
    source_root: str | Path | None = None,
    options: BuildOptions | None = None,
    jobs: int | None = None,
    log: Any = None,
) -> dict[int, AssetInfo]:
    """AssetInfo per scene object index, building whatever is missing or stale first.

    `log(line)` (e.g. print) hears one line before a build and one after it, so the wait
    shows in non-terminal logs too; a warm cache prints nothing. Raises AssetError (one
    line, all failures joined) if any asset cannot be built."""
    out = Path(out) if out is not None else default_assets_root()
    requests = requests_from_task(task, source_root)
    options = options or BuildOptions()
    missing = []
    for req in requests:
        try:
            if not check_cache(plan(req, options), out):
                missing.append(req)
        except AssetError:
            missing.append(req)  # build_assets reports it as a failed result
    if missing:
        if log is not None:
            log(f"assets: building {len(missing)} of {len(requests)} for task '{task.name}' into {out}/ "
                f"(CoACD; cached afterwards)")
        results = build_assets(missing, out, options, jobs)
        failed = [r.error for r in results if r.status == "failed"]
        if failed:
            raise AssetError(f"task '{task.name}': {len(failed)} asset(s) failed: " + "; ".join(failed))
        if log is not None:
            log(f"assets: built {len(results)} in {sum(r.seconds or 0.0 for r in results):.1f} s")
    return read_assets(task, out, source_root)
