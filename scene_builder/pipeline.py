"""One asset, end to end: source -> normalise -> height map -> targets -> hulls -> folder.

Everything is computed in memory first and written last, into a temporary folder renamed
into place, so bad input (an AssetError at any step) leaves nothing behind.
"""

from __future__ import annotations

import json
import time
import traceback
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
import trimesh
from trimesh.exchange.obj import export_obj

from scene_builder import procedural
from scene_builder.cache import PIPELINE_VERSION, atomic_folder, cache_key, is_current, sha256_file
from scene_builder.errors import AssetError
from scene_builder.heightmap import RESOLUTION, height_map
from scene_builder.hulls import convex_hulls
from scene_builder.importers import load_mesh, resolve_mesh_path
from scene_builder.normalize import normalize
from scene_builder.targets import SIT_OFFSET, centre_height, climb_target, sit_target
from scene_builder.vis import height_map_image, vis_scene

PROCEDURAL = "procedural"


@dataclass(frozen=True)
class AssetRequest:
    """What to build and where: `<out>/<category>/<model_id>/` from `source`.

    `source` is "procedural" (generator `category`, seed `variant`) or a path to a mesh file
    or a 3D-FUTURE model folder. `up` is the source's up axis ("y": 3D-FUTURE convention,
    front +Z; "z": already Z up, facing +Y; procedural sources are always "y"). `yaw` (deg)
    turns the object about +Z after that. `scale` (uniform) or `size` (exact bbox x, y, z in
    metres) set the size; procedural sources default to their generator's true size.
    """

    category: str
    model_id: str
    source: str = PROCEDURAL
    variant: int = 0
    up: Literal["y", "z"] = "y"
    yaw: float = 0.0
    scale: float | None = None
    size: tuple[float, float, float] | None = None

    def folder(self, out: Path) -> Path:
        return Path(out) / self.category / self.model_id

    def geometry_options(self) -> dict[str, Any]:
        """The request's part of the cache key (everything that shapes the output)."""
        return {"variant": self.variant, "up": self.up, "yaw": self.yaw, "scale": self.scale,
                "size": list(self.size) if self.size is not None else None}


@dataclass(frozen=True)
class BuildOptions:
    """Batch-wide settings. All but `ray_engine` are part of the cache key (both ray
    engines give the same map, so switching engines does not rebuild)."""

    coacd_threshold: float = 0.05
    max_hulls: int = 16
    max_hull_vertices: int = 64
    seed: int = 0
    ray_engine: str = "auto"

    def key_options(self) -> dict[str, Any]:
        return {k: v for k, v in asdict(self).items() if k != "ray_engine"}


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
    key_options = {**request.geometry_options(), **options.key_options()}
    return Planned(request, label, sha, key_options, cache_key(sha, key_options))


def _source_mesh(p: Planned) -> tuple[trimesh.Trimesh, str, float | None]:
    """(raw mesh, its up axis, default scale) for a planned request."""
    req = p.request
    if req.source == PROCEDURAL:
        gen = procedural.generate(req.category, req.variant)
        return gen.raw, "y", gen.scale
    return load_mesh(Path(p.label)), req.up, None


def process(p: Planned, options: BuildOptions) -> dict[str, Any]:
    """All outputs of one asset, in memory: {mesh, hmap, hulls, config, ...}."""
    req = p.request
    raw, up, default_scale = _source_mesh(p)
    scale = req.scale if (req.scale is not None or req.size is not None) else default_scale
    mesh = normalize(raw, up=up, yaw=req.yaw, scale=scale, size=req.size)
    bbox = np.asarray(mesh.extents, dtype=np.float64)
    hmap, engine = height_map(mesh, RESOLUTION, options.ray_engine)
    sit, climb = sit_target(hmap, bbox), climb_target(hmap, bbox)
    hulls, method = convex_hulls(mesh, p.label, options.coacd_threshold, options.max_hulls,
                                 options.max_hull_vertices, options.seed)
    hull_files = [f"collision/hull_{i:03d}.obj" for i in range(len(hulls))]
    config = {
        "bbox": bbox.tolist(), "center": [0.0, 0.0, 0.0], "facing": [0.0, 1.0, 0.0], "up_facing": [0.0, 0.0, 1.0],
        "tarSitPos": sit, "tarClimbPos": climb,
        "source": p.label, "source_sha256": p.sha256, "pipeline_version": PIPELINE_VERSION, "cache_key": p.key,
        "category": req.category, "model_id": req.model_id,
        "options": p.options,
        "height_map": {"file": "height_map/map2d.npy", "resolution": RESOLUTION, "max": float(hmap.max()),
                       "centre_cell": [RESOLUTION // 2, RESOLUTION // 2], "centre_height": centre_height(hmap),
                       "sit_offset": SIT_OFFSET, "averaging": "none (single cell)", "ray_engine": engine},
        "ray_engine": engine,
        "collision": {"method": method, "hull_count": len(hulls), "files": hull_files,
                      "hull_vertices": [len(h.vertices) for h in hulls]},
        "mesh": {"vertices": len(mesh.vertices), "faces": len(mesh.faces), "watertight": bool(mesh.is_watertight)},
        "vis": {"file": "vis/mesh.glb", "frame": "asset frame (Z up, metres), not glTF's usual Y up"},
    }
    return {"mesh": mesh, "bbox": bbox, "hmap": hmap, "hulls": hulls, "hull_files": hull_files,
            "config": config, "sit": sit, "climb": climb}


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


def build_planned(p: Planned, out: Path, options: BuildOptions) -> BuildResult:
    """Build one planned asset into `<out>/<category>/<model_id>/` (no cache check).

    Never raises: user errors come back as a failed result with a one-line message, bugs
    as a failed result carrying the traceback. Top-level so a process pool can run it.
    """
    t0, folder = time.perf_counter(), p.request.folder(out)
    try:
        result = process(p, options)
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
                       seconds=time.perf_counter() - t0)
