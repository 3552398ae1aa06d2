"""One asset, end to end: source -> decimate -> orient -> normalise -> height map -> targets ->
hulls -> folder.

Everything is computed in memory first and written last, into a temporary folder renamed
into place, so bad input (an AssetError at any step) leaves nothing behind. Time and memory
are bounded by the face caps (decimate.py) and CoACD's per-asset budget (hulls.py); what the
pipeline had to decide for an imported file (orientation, decimation, a moved target, a coarser
CoACD threshold, a suspicious size) is recorded in config.json and returned as warnings.
"""

from __future__ import annotations

import json
import os
import time
import traceback
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
import trimesh
from trimesh.exchange.obj import export_obj

from scene_builder import procedural
from scene_builder.cache import PIPELINE_VERSION, atomic_folder, cache_key, is_current, sha256_file
from scene_builder.decimate import HULL_FACES, MAX_FACES, decimate
from scene_builder.errors import AssetError
from scene_builder.heightmap import GRIDS, RESOLUTION, grid_points, heights_from_top, surface_top
from scene_builder.hulls import TIME_BUDGET, convex_hulls
from scene_builder.importers import load_mesh, resolve_mesh_path
from scene_builder.normalize import frame_transform
from scene_builder.orientation import assess
from scene_builder.size_check import size_warning
from scene_builder.targets import SIT_OFFSET, centre_height, target_cell
from scene_builder.vis import height_map_image, vis_scene

PROCEDURAL = "procedural"
IMPORT_RULES = 2
"""Version of the processing of imported files (orientation check, decimation, target fallback).
It is part of their cache keys, so imported assets rebuild when it changes, while procedural
assets, whose output did not change, stay cached (PIPELINE_VERSION would rebuild everything)."""
Progress = Callable[[str], None]


@dataclass(frozen=True)
class AssetRequest:
    """What to build and where: `<out>/<category>/<model_id>/` from `source`.

    `source` is "procedural" (generator `category`, seed `variant`) or a path to a mesh file
    or a 3D-FUTURE model folder. `up` is the source's up axis ("y": 3D-FUTURE convention,
    front +Z; "z": already Z up, facing +Y; "auto": chosen from the geometry, see
    orientation.py; procedural sources are always "y"). `flip` turns it upside down (180 deg
    about Y). `yaw` (deg) turns the object about +Z after that. `scale` (uniform) or `size`
    (exact bbox x, y, z in metres) set the size; procedural sources default to their
    generator's true size.
    """

    category: str
    model_id: str
    source: str = PROCEDURAL
    variant: int = 0
    up: Literal["y", "z", "auto"] = "y"
    yaw: float = 0.0
    scale: float | None = None
    size: tuple[float, float, float] | None = None
    flip: bool = False

    def folder(self, out: Path) -> Path:
        return Path(out) / self.category / self.model_id

    def geometry_options(self) -> dict[str, Any]:
        """The request's part of the cache key (everything that shapes the output)."""
        options = {"variant": self.variant, "up": self.up, "yaw": self.yaw, "scale": self.scale,
                   "size": list(self.size) if self.size is not None else None}
        if self.flip:  # only when set, so the keys of existing assets stay valid
            options["flip"] = True
        return options


@dataclass(frozen=True)
class BuildOptions:
    """Batch-wide settings. All but `ray_engine` are part of the cache key (both ray
    engines give the same map, so switching engines does not rebuild); the later fields
    only when they differ from their defaults, so the keys of existing assets stay valid.

    `max_faces` caps the processed mesh (decimated above it), `hull_faces` CoACD's input;
    `time_budget` is CoACD's seconds per asset (hulls.py); `grid` the height-map grid
    convention ("centres", ours, or "linspace", TokenHSI's; heightmap.py)."""

    coacd_threshold: float = 0.05
    max_hulls: int = 16
    max_hull_vertices: int = 64
    seed: int = 0
    ray_engine: str = "auto"
    max_faces: int = MAX_FACES
    hull_faces: int = HULL_FACES
    time_budget: float = TIME_BUDGET
    grid: str = "centres"

    def key_options(self) -> dict[str, Any]:
        defaults = BuildOptions()
        base = ("coacd_threshold", "max_hulls", "max_hull_vertices", "seed")
        return {k: v for k, v in asdict(self).items()
                if k in base or (k != "ray_engine" and v != getattr(defaults, k))}


@dataclass(frozen=True)
class BuildResult:
    request: AssetRequest
    status: Literal["built", "cached", "failed"]
    folder: Path
    error: str = ""
    """One line, `<file>: <problem>`, when status is 'failed'."""
    ray_engine: str = ""
    seconds: float = 0.0
    traceback: str = field(default="", repr=False)
    """Set only for failures that are bugs (not AssetError): print it."""
    warnings: tuple[str, ...] = ()
    """One line each, `<file>: <what looks wrong and what to do>`, for built assets."""
    summary: str = ""
    """A few words on what was built (hulls, decimation), for progress lines."""


@dataclass(frozen=True)
class Planned:
    """A request with its source identity resolved (cheap: hashing, no geometry)."""

    request: AssetRequest
    label: str
    sha256: str
    options: dict[str, Any]
    """Everything besides the source that shapes the output (request + batch options)."""
    key: str


def plan(request: AssetRequest, options: BuildOptions) -> Planned:
    """Resolve the source and compute the cache key; AssetError if the source is missing."""
    if request.scale is not None and request.size is not None:
        raise AssetError(f"{request.source}: give scale or size, not both")
    if request.scale is not None and not request.scale > 0:
        raise AssetError(f"{request.source}: scale must be > 0, got {request.scale}")
    if request.size is not None and not (len(request.size) == 3 and all(s > 0 for s in request.size)):
        raise AssetError(f"{request.source}: size must be 3 positive numbers (x y z metres), got {request.size}")
    if request.source == PROCEDURAL:
        try:
            name = procedural.resolve_category(request.category)
        except AssetError as e:
            raise AssetError(f"procedural:{request.category}: {e}") from None
        if request.variant < 0:
            raise AssetError(f"procedural:{name}: variant must be >= 0, got {request.variant}")
        label, sha = f"procedural:{name}:{request.variant}", procedural.generator_sha256(name, request.variant)
    else:
        mesh_path = resolve_mesh_path(Path(request.source))
        try:
            label, sha = str(mesh_path), sha256_file(mesh_path)
        except OSError as e:
            raise AssetError(f"{mesh_path}: cannot read ({e.strerror or e})") from None
    if request.up not in ("y", "z", "auto"):
        raise AssetError(f"{request.source}: up must be y, z or auto, got {request.up!r}")
    if options.grid not in GRIDS:
        raise AssetError(f"height-map grid: unknown '{options.grid}' (expected {', '.join(GRIDS)})")
    for name in ("max_faces", "hull_faces"):
        if getattr(options, name) < 4:
            raise AssetError(f"{name}: must be at least 4 faces, got {getattr(options, name)}")
    if not options.time_budget > 0:
        raise AssetError(f"time budget: must be > 0 seconds, got {options.time_budget}")
    key_options = {**request.geometry_options(), **options.key_options()}
    if request.source != PROCEDURAL:
        key_options["import_rules"] = IMPORT_RULES
    return Planned(request, label, sha, key_options, cache_key(sha, key_options))


def source_identity(p: Planned) -> str:
    """What makes two requests the same source for the overwrite check: the absolute path of
    a file (its content may change: that is a rebuild), or the procedural label."""
    return p.label if p.request.source == PROCEDURAL else os.path.abspath(p.label)


class _Stopwatch:
    """Seconds per build step, for config.json "seconds" (where a slow import spends its time)."""

    def __init__(self) -> None:
        self.laps: dict[str, float] = {}
        self._last = time.perf_counter()

    def lap(self, name: str) -> None:
        now = time.perf_counter()
        self.laps[name] = round(now - self._last, 3)
        self._last = now


def _source_mesh(p: Planned) -> tuple[trimesh.Trimesh, float | None]:
    """(raw mesh, default scale) for a planned request."""
    req = p.request
    if req.source == PROCEDURAL:
        gen = procedural.generate(req.category, req.variant)
        return gen.raw, gen.scale
    return load_mesh(Path(p.label)), None


def process(p: Planned, options: BuildOptions, progress: Progress | None = None) -> dict[str, Any]:
    """All outputs of one asset, in memory: {mesh, hmap, hulls, config, warnings, ...}.

    The bbox and the height-map grid come from the full-resolution mesh; the height map, the
    orientation evidence, mesh.obj and CoACD use the copy decimated to `options.max_faces`."""
    req, imported = p.request, p.request.source != PROCEDURAL
    clock = _Stopwatch()
    raw, default_scale = _source_mesh(p)
    clock.lap("load")
    raw_work, decimation = decimate(raw, options.max_faces, p.label)
    clock.lap("decimate")
    warnings: list[str] = []
    up, flip, orientation = ("y", False, None) if not imported else (req.up, req.flip, None)
    if imported:
        orientation = assess(raw_work, req.up, req.flip, p.label, options.ray_engine)
        up, flip = orientation.up, orientation.flip
        warnings += orientation.warnings
        clock.lap("orientation")
    scale = req.scale if (req.scale is not None or req.size is not None) else default_scale
    transform = frame_transform(raw, up=up, yaw=req.yaw, scale=scale, size=req.size, flip=flip)
    used = transform.apply(np.asarray(raw.vertices)[raw.referenced_vertices])  # what trimesh's bounds use
    full_bounds = np.array([used.min(axis=0), used.max(axis=0)])
    del raw, used  # from here on only the decimated copy: memory follows the cap
    mesh = trimesh.Trimesh(transform.apply(raw_work.vertices), np.asarray(raw_work.faces), process=False)
    del raw_work
    bbox = np.asarray(full_bounds[1] - full_bounds[0], dtype=np.float64)
    if imported and req.size is None:
        warnings += [w for w in [size_warning(bbox, p.label, scale)] if w]
    clock.lap("normalise")
    top, engine = surface_top(mesh, RESOLUTION, options.ray_engine, options.grid, full_bounds)
    hmap = heights_from_top(top, float(full_bounds[0, 2]))
    xs, ys = grid_points(full_bounds - (full_bounds[0] + full_bounds[1]) / 2.0, RESOLUTION, options.grid)
    cell = target_cell(hmap, ~np.isnan(top), xs, ys)
    if cell is None:
        raise AssetError(f"{p.label}: no downward ray hits the mesh; nothing to stand or sit on")
    sit, climb = cell.sit(bbox), cell.climb(bbox)
    if cell.moved:
        kind = "supporting surface" if cell.supporting else "surface (no flat patch found)"
        warnings.append(f"{p.label}: nothing under the bbox centre (a gap between parts?); sit/climb targets moved "
                        f"to the nearest {kind} at x={cell.x:+.3f} y={cell.y:+.3f} m, {cell.height:.3f} m high")
    clock.lap("height_map")
    hulls, report = convex_hulls(mesh, p.label, options.coacd_threshold, options.max_hulls, options.max_hull_vertices,
                                 options.seed, options.time_budget, options.hull_faces, progress)
    clock.lap("hulls")
    note = report.warning(options.coacd_threshold, len(hulls))
    if note:
        warnings.append(f"{p.label}: {note}")
    if decimation.applied:
        warnings.append(f"{p.label}: {decimation.faces_in} faces decimated to {decimation.faces_out} "
                        f"(--max-faces {options.max_faces}) for mesh.obj, the height map and the hulls")
    hull_files = [f"collision/hull_{i:03d}.obj" for i in range(len(hulls))]
    config = {
        "bbox": bbox.tolist(), "center": [0.0, 0.0, 0.0], "facing": [0.0, 1.0, 0.0], "up_facing": [0.0, 0.0, 1.0],
        "tarSitPos": sit, "tarClimbPos": climb,
        "source": p.label, "source_path": source_identity(p), "source_sha256": p.sha256,
        "pipeline_version": PIPELINE_VERSION, "cache_key": p.key,
        "category": req.category, "model_id": req.model_id,
        "options": p.options,
        "height_map": {"file": "height_map/map2d.npy", "resolution": RESOLUTION, "max": float(hmap.max()),
                       "grid": options.grid, "centre_cell": [RESOLUTION // 2, RESOLUTION // 2],
                       "centre_height": centre_height(hmap), "target_cell": [cell.row, cell.col],
                       "target_moved": cell.moved, "sit_offset": SIT_OFFSET, "averaging": "none (single cell)",
                       "ray_engine": engine},
        "ray_engine": engine,
        "collision": {"method": report.method, "hull_count": len(hulls), "files": hull_files,
                      "hull_vertices": [len(h.vertices) for h in hulls], **report.as_dict()},
        "mesh": {"vertices": len(mesh.vertices), "faces": len(mesh.faces), "watertight": bool(mesh.is_watertight),
                 "source_faces": decimation.faces_in, "decimated": decimation.applied,
                 "decimation": decimation.method},
        "vis": {"file": "vis/mesh.glb", "frame": "asset frame (Z up, metres), not glTF's usual Y up"},
        "warnings": warnings,
        "seconds": clock.laps,
    }
    if orientation is not None:
        config["orientation"] = orientation.as_dict()
    summary = f"{len(hulls)} hull{'s' * (len(hulls) != 1)} ({report.method}"
    summary += f" {report.threshold:g})" if report.threshold is not None else ")"
    if decimation.applied:
        summary += f", {decimation.faces_in} -> {decimation.faces_out} faces"
    return {"mesh": mesh, "bbox": bbox, "hmap": hmap, "hulls": hulls, "hull_files": hull_files,
            "config": config, "sit": sit, "climb": climb, "warnings": warnings, "summary": summary}


def _write(folder: Path, out: dict[str, Any]) -> None:
    obj = {"include_normals": False, "include_color": False, "include_texture": False, "header": None}
    for sub in ("height_map", "vis", "collision"):
        (folder / sub).mkdir()
    (folder / "mesh.obj").write_text(export_obj(out["mesh"], **obj))
    for name, hull in zip(out["hull_files"], out["hulls"], strict=True):
        (folder / name).write_text(export_obj(hull, **obj))
    np.save(folder / "height_map" / "map2d.npy", out["hmap"])
    height_map_image(out["hmap"], out["bbox"]).save(folder / "height_map" / "map2d.png")
    glb = vis_scene(out["mesh"], out["bbox"], out["sit"], out["climb"]).export(file_type="glb")
    (folder / "vis" / "mesh.glb").write_bytes(glb)
    (folder / "config.json").write_text(json.dumps(out["config"], indent=2) + "\n")  # last: marks completion


def check_cache(p: Planned, out: Path) -> bool:
    """True when the asset folder of `p` is complete and was built with the same cache key."""
    return is_current(p.request.folder(out), p.key)


def build_planned(p: Planned, out: Path, options: BuildOptions, progress: Progress | None = None) -> BuildResult:
    """Build one planned asset into `<out>/<category>/<model_id>/` (no cache check).

    Never raises: user errors come back as a failed result with a one-line message, bugs
    as a failed result carrying the traceback. Top-level so a process pool can run it
    (`progress` must then be a top-level function too, e.g. `print_line`).
    """
    t0, folder = time.perf_counter(), p.request.folder(out)
    try:
        result = process(p, options, progress)
        result["config"]["build_seconds"] = round(time.perf_counter() - t0, 3)
        try:
            with atomic_folder(folder) as tmp:
                _write(tmp, result)
        except OSError as e:
            if check_cache(p, out):  # a concurrent build of the same asset got there first
                return BuildResult(p.request, "cached", folder, seconds=time.perf_counter() - t0)
            raise AssetError(f"{folder}: cannot write asset ({e.strerror or e})") from None
    except AssetError as e:
        return BuildResult(p.request, "failed", folder, error=str(e), seconds=time.perf_counter() - t0)
    except Exception as e:  # a bug: keep the traceback, but do not lose the rest of the batch
        error = f"{p.label}: internal error ({type(e).__name__}: {e})"
        return BuildResult(p.request, "failed", folder, error=error,
                           seconds=time.perf_counter() - t0, traceback=traceback.format_exc())
    return BuildResult(p.request, "built", folder, ray_engine=result["config"]["ray_engine"],
                       seconds=time.perf_counter() - t0, warnings=tuple(result["warnings"]),
                       summary=result["summary"])


def print_line(line: str) -> None:
    """Progress sink for worker processes: one flushed line on stdout, which they share with
    the parent, so it shows in terminals and in redirected logs alike."""
    print(line, flush=True)
