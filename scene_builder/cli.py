"""`detach-scene`: build, inspect and list the assets that scenes are made of.

Exit codes: 0 success; 2 bad input (any asset failed, bad arguments, bad task file), with one
line per problem on stderr; 1 a bug (printed with its traceback). Warnings (orientation, size,
a moved target, a coarser CoACD threshold, decimation) are `warning: ...` lines on stderr and
leave the exit code at 0; progress lines go to stdout, one per asset, also into logs.

Imports of numpy, trimesh and the pipeline happen inside the commands, so `--help` starts in
a fraction of a second.
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from scene_builder.cache import PIPELINE_VERSION
from scene_builder.errors import AssetError
from scene_builder.settings import ENGINES, GRIDS, HULL_FACES, MAX_FACES, TIME_BUDGET, UP_CHOICES

if TYPE_CHECKING:
    from scene_builder.assets import AssetRequest

DEFAULT_TASKS = "configs/tasks/lh*.yaml"

EPILOG = f"""\
examples:
  detach-scene build                         every asset of {DEFAULT_TASKS} (procedural library)
  detach-scene build --tasks configs/tasks/lh2.yaml --jobs 2
  detach-scene build --source ~/3D-FUTURE-model/            a folder of <jid>/normalized_model.obj
  detach-scene build --source tokenhsi/objects/ --up z      TokenHSI's <category>/<model_id>/mesh.obj
  detach-scene build --source chair.glb --size 0.5 0.5 0.9  one mesh, stretched to that bbox
  detach-scene build --source scan.ply --up auto --scale 0.01  up axis from the geometry, centimetres
  detach-scene build --source table.stl --name table/cad_01 --flip   an upside-down CAD part, named
  detach-scene inspect assets/chair/chair_v0
  detach-scene list [--source DIR]

Assets go to <out>/<category>/<model_id>/ (out: --out, else $DETACH_ASSETS, else ./assets)
and are rebuilt only when the source, the options or the pipeline version
({PIPELINE_VERSION}) change; an id already holding a different asset is an error unless --force.
Ids, orientation checks, budgets and height-map grids: docs/ASSET_IMPORT.md.
Exit code 2 when any asset failed (each failure is one line on stderr).
"""


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="detach-scene", description="Build, inspect and list the asset folders "
                                "(processed mesh, height map, targets, collision hulls) that scenes are made of.",
                                epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="command", required=True, metavar="{build,inspect,list}")

    b = sub.add_parser("build", help="build asset folders (cached)", epilog=EPILOG,
                       formatter_class=argparse.RawDescriptionHelpFormatter,
                       description="Build every asset the given tasks reference, or import meshes with --source.")
    b.add_argument("--tasks", nargs="+", metavar="YAML",
                   help=f"task files whose scenes to build (default: {DEFAULT_TASKS} under the cwd)")
    b.add_argument("--source", metavar="DIR|FILE",
                   help="without --tasks: a mesh file (OBJ, GLB, PLY, STL, OFF), a 3D-FUTURE model folder "
                        "(<jid>/normalized_model.obj) or a folder of them, to import; with --tasks: the root that "
                        "non-procedural `source` paths of scene objects are relative to")
    b.add_argument("--out", metavar="DIR", help="asset root (default: $DETACH_ASSETS or ./assets)")
    b.add_argument("--force", action="store_true",
                   help="rebuild even when the cached asset is current, and replace an existing asset of the same "
                        "id that was built from a different source")
    b.add_argument("--jobs", type=int, metavar="N", help="parallel worker processes (default: all cores)")
    b.add_argument("--up", choices=UP_CHOICES, default="y",
                   help="up axis of imported meshes: y = 3D-FUTURE convention (Y up, front +Z; default), "
                        "z = already Z up and facing +Y (TokenHSI), auto = chosen from the geometry (feet below, "
                        "a closed top, stable); an explicit axis is checked and warned about")
    b.add_argument("--flip", action="store_true",
                   help="turn imported meshes upside down (180 deg about Y, after the up conversion)")
    b.add_argument("--yaw", type=float, default=0.0, metavar="DEG",
                   help="extra rotation about +Z (degrees, after the up conversion) to make the object face +Y")
    b.add_argument("--name", metavar="[CATEGORY/]MODEL_ID",
                   help="asset id of a single imported model (default: from its folders, docs/ASSET_IMPORT.md)")
    size = b.add_mutually_exclusive_group()
    size.add_argument("--scale", type=float, metavar="S", help="uniform scale to metres (imports only)")
    size.add_argument("--size", type=float, nargs=3, metavar=("X", "Y", "Z"),
                      help="stretch to this bbox in metres (imports only)")
    b.add_argument("--category", metavar="NAME",
                   help="category folder for imports (default: model_info.json's category, else 'imported')")
    b.add_argument("--coacd-threshold", type=float, default=0.05, metavar="T",
                   help="CoACD concavity threshold; smaller = more, tighter hulls (default 0.05)")
    b.add_argument("--max-hulls", type=int, default=16, metavar="N",
                   help="cap on collision hulls per object (default 16)")
    b.add_argument("--max-hull-vertices", type=int, default=64, metavar="N",
                   help="vertices per hull (default 64)")
    b.add_argument("--coacd-seed", "--seed", dest="seed", type=int, default=0, metavar="N",
                   help="CoACD seed (default 0; --seed is the earlier spelling: detach-run's --seed is the run seed)")
    b.add_argument("--ray-engine", choices=("auto", *ENGINES), default="auto",
                   help="height-map ray caster: auto = embree when embreex is installed, else numpy")
    b.add_argument("--grid", choices=GRIDS, default="centres",
                   help="height-map rays: centres = through the centres of 128x128 cells (default), "
                        "linspace = TokenHSI's linspace(min, max, 128), on the bbox edges")
    b.add_argument("--max-faces", type=int, default=MAX_FACES, metavar="N",
                   help=f"decimate meshes above N faces before anything else (default {MAX_FACES})")
    b.add_argument("--hull-faces", type=int, default=HULL_FACES, metavar="N",
                   help=f"decimate CoACD's input to N faces (default {HULL_FACES})")
    b.add_argument("--time-budget", type=float, default=TIME_BUDGET, metavar="S",
                   help=f"seconds of CoACD per asset; past it the threshold is raised, then part hulls are used "
                        f"(default {TIME_BUDGET:g})")
    b.set_defaults(func=_cmd_build)

    i = sub.add_parser("inspect", help="print an asset folder's summary as JSON")
    i.add_argument("asset_dir", metavar="ASSET_DIR")
    i.set_defaults(func=_cmd_inspect)

    ls = sub.add_parser("list", help="list procedural categories and variants (or models under --source)")
    ls.add_argument("--source", metavar="DIR|FILE", help="list the importable models found here instead")
    ls.add_argument("--variants", type=int, default=4, metavar="N", help="procedural variants to show (default 4)")
    ls.set_defaults(func=_cmd_list)
    return p


def _import_requests(args: argparse.Namespace) -> list[AssetRequest]:
    from scene_builder.assets import AssetRequest
    from scene_builder.importers import discover

    size = tuple(args.size) if args.size else None
    return [AssetRequest(m.category, m.model_id, str(m.mesh_path), 0, args.up, args.yaw, args.scale, size, args.flip)
            for m in discover(Path(args.source), args.category, args.name)]


def _task_requests(args: argparse.Namespace) -> list[AssetRequest]:
    if args.scale is not None or args.size or args.yaw or args.category or args.name or args.flip:
        raise AssetError("--scale/--size/--yaw/--category/--name/--flip apply to --source imports; "
                         "with tasks, set `size` per scene object in the task YAML")
    from detach.config import ConfigError, load_task
    from scene_builder.assets import request_diff, requests_from_task

    files = args.tasks or sorted(glob.glob(DEFAULT_TASKS))
    if not files:
        raise AssetError(f"{DEFAULT_TASKS}: no task files found (run from the repository root, or pass --tasks)")
    merged: dict[tuple[str, str], tuple[AssetRequest, str]] = {}
    for f in files:
        try:
            task = load_task(f)
        except ConfigError as e:
            raise AssetError(str(e)) from None
        for req in requests_from_task(task, args.source, args.up):
            key = (req.category, req.model_id)
            if key in merged and merged[key][0] != req:
                raise AssetError(f"{f}: {key[0]}/{key[1]} differs from the one in {merged[key][1]} "
                                 f"({request_diff(merged[key][0], req)}); give them different model_ids")
            merged.setdefault(key, (req, f))
    return [req for req, _ in merged.values()]


def _cmd_build(args: argparse.Namespace) -> int:
    from scene_builder.assets import BuildOptions, build_assets, default_assets_root
    from scene_builder.heightmap import pick_engine

    out = Path(args.out) if args.out else default_assets_root()
    engine = pick_engine(args.ray_engine)
    if args.name and args.tasks:
        raise AssetError("--name applies to a single --source model, not to --tasks")
    requests = _import_requests(args) if args.source and not args.tasks else _task_requests(args)
    options = BuildOptions(args.coacd_threshold, args.max_hulls, args.max_hull_vertices, args.seed,
                           args.ray_engine, args.max_faces, args.hull_faces, args.time_budget, args.grid)
    results = build_assets(requests, out, options, args.jobs, args.force, progress=True)
    failed = [r for r in results if r.status == "failed"]
    for r in results:
        for warning in r.warnings:
            print(f"warning: {warning}", file=sys.stderr)
    for r in failed:
        if r.traceback:
            print(r.traceback, file=sys.stderr, end="")
        print(f"error: {r.error}", file=sys.stderr)
    ran = sorted({r.ray_engine for r in results if r.status == "built"})
    print(f"ray engine: {', '.join(ran) if ran else f'none ran (nothing built; would use {engine})'}")
    count = {s: sum(r.status == s for r in results) for s in ("built", "cached", "failed")}
    print(f"built {count['built']}, cached {count['cached']}, failed {count['failed']} -> {out}")
    if failed:
        print("failed: " + ", ".join(f"{r.request.category}/{r.request.model_id}" for r in failed))
    return 1 if any(r.traceback for r in failed) else 2 if failed else 0


def _cmd_inspect(args: argparse.Namespace) -> int:
    from scene_builder.assets import load_asset

    info = load_asset(args.asset_dir)
    h = info.height_map
    summary = {
        "folder": str(info.folder), **info.config,
        "height_map_stats": {"shape": list(h.shape), "dtype": str(h.dtype), "min": float(h.min()),
                             "max": float(h.max()), "mean": float(h.mean()), "miss_fraction": float((h == 0).mean())},
        "files": sorted(str(p.relative_to(info.folder)) for p in info.folder.rglob("*") if p.is_file()),
        "current_pipeline": info.config.get("pipeline_version") == PIPELINE_VERSION,
    }
    print(json.dumps(summary, indent=2))
    return 0


def _cmd_list(args: argparse.Namespace) -> int:
    from scene_builder import procedural
    from scene_builder.importers import discover

    if args.source:
        for m in discover(Path(args.source)):
            print(f"{m.category}/{m.model_id}\t{m.mesh_path}")
        return 0
    for name, cat in procedural.CATEGORIES.items():
        kind = "parametric (sized by the task)" if cat.parametric else "furniture"
        print(f"{name}: {cat.description} [{kind}]")
        for v in range(args.variants):
            x, y, z = procedural.generate(name, v).size
            print(f"  variant {v}: {x:.2f} x {y:.2f} x {z:.2f} m")
    aliases = ", ".join(f"{a} -> {c}" for a, c in procedural.ALIASES.items())
    print(f"aliases (case, spaces and dashes ignored): {aliases}")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of `detach-scene`; returns the exit code instead of exiting (testable)."""
    try:
        args = _parser().parse_args(argv)
    except SystemExit as e:  # --help (0) or a usage error (2), already printed by argparse
        return e.code if isinstance(e.code, int) else 2
    try:
        return args.func(args)
    except AssetError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # output piped into e.g. `head`, which stopped reading
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0


if __name__ == "__main__":
    sys.exit(main())
