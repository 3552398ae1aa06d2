"""Reading user meshes: single files trimesh reads, and 3D-FUTURE model folders.

Every problem with the input becomes an `AssetError` whose message names the file, because
a user importing a hundred models needs to know which one to fix, not a trimesh traceback.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from scene_builder.errors import AssetError

MESH_SUFFIXES = (".obj", ".glb", ".gltf", ".ply", ".stl", ".off")
FUTURE_MESH = "normalized_model.obj"
"""The mesh file of a 3D-FUTURE model folder `<jid>/`."""
FLAT_RATIO = 1e-4
"""A mesh whose smallest bbox extent is below this fraction of its largest is flat."""


@dataclass(frozen=True)
class FoundModel:
    """One importable model: where its mesh is and what it should be called."""

    mesh_path: Path
    category: str
    model_id: str


def slug(text: str) -> str:
    """Folder-safe lower-case name: 'Dining Chair' -> 'dining_chair'."""
    return re.sub(r"[^a-z0-9]+", "_", text.strip().lower()).strip("_") or "imported"


def resolve_mesh_path(source: Path) -> Path:
    """The mesh file of `source`: the file itself, or `<dir>/normalized_model.obj`."""
    if not source.exists():
        raise AssetError(f"{source}: no such file or directory")
    if source.is_dir():
        mesh = source / FUTURE_MESH
        if not mesh.is_file():
            raise AssetError(f"{source}: not a 3D-FUTURE model folder (no {FUTURE_MESH})")
        return mesh
    if source.suffix.lower() not in MESH_SUFFIXES:
        raise AssetError(f"{source}: unsupported file type '{source.suffix}' "
                         f"(expected one of {', '.join(MESH_SUFFIXES)})")
    return source


def _category_from_info(folder: Path) -> str | None:
    """Category from `<jid>/model_info.json` (a dict), or from the dataset's top-level
    `model_info.json` (a list of {model_id, category, ...}) one folder up."""
    for info_path in (folder / "model_info.json", folder.parent / "model_info.json"):
        if not info_path.is_file():
            continue
        try:
            info = json.loads(info_path.read_text())
        except (OSError, ValueError) as e:
            raise AssetError(f"{info_path}: unreadable model_info.json ({e})") from None
        if isinstance(info, list):
            info = next((i for i in info if isinstance(i, dict) and i.get("model_id") == folder.name), None)
        if isinstance(info, dict) and info.get("category"):
            return slug(str(info["category"]))
    return None


def discover(source: Path, category: str | None = None) -> list[FoundModel]:
    """Models under `source`: a mesh file, one 3D-FUTURE folder, or a folder of them.

    Category: `category` if given, else the model_info.json category, else 'imported'.
    """
    if source.is_dir() and not (source / FUTURE_MESH).exists():
        folders = sorted(p for p in source.iterdir() if p.is_dir() and (p / FUTURE_MESH).exists())
        if not folders:
            raise AssetError(f"{source}: no 3D-FUTURE model folders (<jid>/{FUTURE_MESH}) found")
        return [m for f in folders for m in discover(f, category)]
    mesh_path = resolve_mesh_path(source)
    if source.is_dir():
        cat = category or _category_from_info(source) or "imported"
        return [FoundModel(mesh_path, slug(cat), source.name)]
    return [FoundModel(mesh_path, slug(category or "imported"), slug(source.stem))]


def load_mesh(path: Path) -> trimesh.Trimesh:
    """Read and validate one mesh file (positions and triangles only; materials dropped).

    Raises AssetError for: unreadable / non-mesh files, no faces, NaN/inf vertices, and flat
    (zero-thickness) meshes, none of which can give a bbox, height map or collision hulls.
    """
    try:
        mesh = trimesh.load(path, force="mesh", process=False)
    except Exception as e:  # trimesh's parsers raise anything from ValueError to IndexError
        first_line = str(e).splitlines()[0] if str(e) else ""
        raise AssetError(f"{path}: not a readable mesh ({type(e).__name__}: {first_line})") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise AssetError(f"{path}: mesh has no faces (empty, or not a mesh)")
    v = np.asarray(mesh.vertices, dtype=np.float64)
    used = np.unique(np.asarray(mesh.faces))
    if used.max() >= len(v):
        raise AssetError(f"{path}: faces index missing vertices")
    bad = ~np.isfinite(v[used]).all(axis=1)
    if bad.any():
        raise AssetError(f"{path}: {int(bad.sum())} vertices have NaN/inf coordinates")
    mesh = trimesh.Trimesh(v, mesh.faces, process=True)  # merge UV-seam duplicates for CoACD
    extents = mesh.extents
    if extents.min() <= FLAT_RATIO * extents.max():
        axis = "xyz"[int(extents.argmin())]
        raise AssetError(f"{path}: mesh is flat (extent {extents.min():.3g} along {axis} "
                         f"vs {extents.max():.3g}); need a solid")
    return mesh
