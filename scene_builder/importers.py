"""Reading user meshes: single files trimesh reads, 3D-FUTURE and TokenHSI model folders.

Every problem with the input becomes an `AssetError` whose message names the file, because
a user importing a hundred models needs to know which one to fix, not a trimesh traceback.

Asset ids (`<category>/<model_id>`, the output folder) come from the source's folder structure,
because datasets name every file alike (every TokenHSI object is `mesh.obj`, every 3D-FUTURE
model `normalized_model.obj`) and two of them must never land in the same folder:
- a 3D-FUTURE model folder `<jid>/normalized_model.obj`: `<category>/<jid>`, the category from
  `model_info.json` (in the folder or the dataset's list one level up), else `imported`;
- a file with a generic name (`GENERIC_STEMS`: mesh.obj, model.glb, ...), e.g. TokenHSI's
  `objects/<category>/<model_id>/mesh.obj`: `<category>/<model_id>` from the two folders above it;
- any other file: `imported/<file name>` (`--category` replaces `imported`);
- `--name [CATEGORY/]MODEL_ID` overrides all of this for a single model.
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
GENERIC_STEMS = ("normalized_model", "mesh", "model", "textured_mesh", "textured", "object", "raw_model")
"""File names (without suffix) that say nothing about the model: its folders name it instead.
In this order of preference when one folder holds several (3D-FUTURE folders hold both
normalized_model.obj and raw_model.obj: the first is the model)."""
SKIP_FOLDERS = frozenset({"collision", "vis", "height_map"})
"""Sub-folders of our own asset folders, never scanned for sources."""
SCAN_DEPTH = 3
"""Folder levels below --source searched for generically named meshes (objects/<cat>/<id>/mesh.obj)."""
_ID_PART = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]*")


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


def parse_name(name: str) -> tuple[str | None, str]:
    """`--name` as (category or None, model_id); AssetError unless each part is a plain name."""
    parts = name.split("/")
    if len(parts) > 2 or not all(_ID_PART.fullmatch(p) for p in parts):
        raise AssetError(f"--name {name!r}: expected MODEL_ID or CATEGORY/MODEL_ID (letters, digits, '_', '-', '.', "
                         "not starting with '.')")
    return (parts[0], parts[1]) if len(parts) == 2 else (None, parts[0])


def _model_from_file(mesh_path: Path, category: str | None) -> FoundModel:
    """The id of one mesh file by the rules of the module docstring."""
    stem = mesh_path.stem
    if stem.lower() not in GENERIC_STEMS:
        return FoundModel(mesh_path, slug(category or "imported"), slug(stem))
    folder = mesh_path.parent.resolve()
    model_id = folder.name
    if not _ID_PART.fullmatch(model_id):
        raise AssetError(f"{mesh_path}: cannot name this model after its folder '{model_id}' "
                         "(a generic file name takes <category>/<model_id> from its folders); pass --name")
    if category is None:
        category = _category_from_info(folder)
    if category is None:
        category = "imported" if mesh_path.name == FUTURE_MESH else (folder.parent.name or "imported")
    return FoundModel(mesh_path, slug(category), model_id)


def _scan(source: Path) -> list[Path]:
    """Mesh files under a folder: 3D-FUTURE model folders one level down, generically named
    meshes up to SCAN_DEPTH levels down, and other mesh files directly in it."""
    named, generic = [], {}
    for path in sorted(source.rglob("*")):
        rel = path.relative_to(source)
        if (not path.is_file() or path.suffix.lower() not in MESH_SUFFIXES or len(rel.parts) > SCAN_DEPTH + 1
                or any(p.startswith(".") or p in SKIP_FOLDERS for p in rel.parts)):
            continue
        if path.stem.lower() in GENERIC_STEMS:
            generic.setdefault(path.parent, []).append(path)
        elif len(rel.parts) == 1:
            named.append(path)
    first = [min(paths, key=lambda p: (GENERIC_STEMS.index(p.stem.lower()), p.name)) for paths in generic.values()]
    return sorted(named + first)


def discover(source: Path, category: str | None = None, name: str | None = None) -> list[FoundModel]:
    """Models under `source` (a mesh file, a 3D-FUTURE model folder, or a folder of models)
    with their ids (module docstring); `name` renames a single model."""
    if not source.exists():
        raise AssetError(f"{source}: no such file or directory")
    if source.is_dir() and not (source / FUTURE_MESH).exists():
        files = _scan(source)
        if not files:
            raise AssetError(f"{source}: no models found (looked for 3D-FUTURE model folders <jid>/{FUTURE_MESH}, "
                             f"<category>/<model_id>/mesh.obj up to {SCAN_DEPTH} levels down, and mesh files "
                             f"{', '.join(MESH_SUFFIXES)} in the folder)")
        models = [_model_from_file(f, category) for f in files]
    else:
        models = [_model_from_file(resolve_mesh_path(source), category)]
    if name is not None:
        if len(models) != 1:
            raise AssetError(f"{source}: --name needs a single model, found {len(models)}")
        cat, model_id = parse_name(name)
        models = [FoundModel(models[0].mesh_path, slug(cat) if cat else models[0].category, model_id)]
    return models


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
    v, faces = np.array(mesh.vertices, dtype=np.float64), np.array(mesh.faces)
    del mesh  # the parser's object and its caches: ~5x the arrays on a multi-million-face file
    used = np.unique(faces)
    if used.max() >= len(v):
        raise AssetError(f"{path}: faces index missing vertices")
    bad = ~np.isfinite(v[used]).all(axis=1)
    del used
    if bad.any():
        raise AssetError(f"{path}: {int(bad.sum())} vertices have NaN/inf coordinates")
    mesh = trimesh.Trimesh(v, faces, process=True)  # merge UV-seam duplicates for CoACD
    extents = mesh.extents
    if extents.min() <= FLAT_RATIO * extents.max():
        axis = "xyz"[int(extents.argmin())]
        raise AssetError(f"{path}: mesh is flat (extent {extents.min():.3g} along {axis} "
                         f"vs {extents.max():.3g}); need a solid")
    return mesh
