"""Asset pipeline speed: height-map ray engines side by side, cold vs warm LH builds, and
imports of large CAD-like meshes (time and peak memory bounded by the face caps and CoACD's
time budget).

Run from the repository root:  python benchmarks/bench_assets.py [--repeats N] [--large FACES]
                                [--budget S] [--skip-builds]
Goals (issue 4): 128x128 map <= 50 ms with Embree; warm rebuild of all LH assets <= 5 s.
Goals (issue 20): a multi-million-face import finishes in bounded time (load + decimation +
the CoACD budget) with memory proportional to the decimated mesh, not the source.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import trimesh

from scene_builder.heightmap import embree_available, height_map

ROOT = Path(__file__).resolve().parents[1]


def timed(fn, repeats: int) -> tuple[float, float]:
    """(first call, median of the following `repeats`) in seconds."""
    t0 = time.perf_counter()
    fn()
    first = time.perf_counter() - t0
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return first, statistics.median(times)


def bench_height_map(repeats: int) -> None:
    """Both engines on two ~50k-face meshes: a UV sphere (typical) and a cone whose 25k side
    triangles are long thin fans (the case that makes per-triangle casters slow)."""
    meshes = {
        "uv sphere": trimesh.creation.uv_sphere(radius=0.5, count=[113, 112]),
        "cone fan": trimesh.creation.cone(radius=0.5, height=0.8, sections=25000),
    }
    for name, mesh in meshes.items():
        print(f"height map 128x128, {name}, {len(mesh.faces)} faces")
        medians = {}
        for engine in ("embree", "numpy"):
            if engine == "embree" and not embree_available():
                print("  embree: embreex not installed, skipped")
                continue
            first, medians[engine] = timed(lambda e=engine: height_map(mesh, engine=e), repeats)
            print(f"  {engine:6s}: first {first * 1e3:8.1f} ms, median of {repeats} {medians[engine] * 1e3:8.1f} ms")
        if len(medians) == 2:
            print(f"  numpy / embree (median): {medians['numpy'] / medians['embree']:.2f}x")


def bench_builds() -> None:
    with tempfile.TemporaryDirectory() as out:
        cmd = [sys.executable, "-m", "scene_builder.cli", "build", "--out", out]
        for label in ("cold", "warm"):
            t0 = time.perf_counter()
            proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
            dt = time.perf_counter() - t0
            summary = " | ".join(line for line in proc.stdout.splitlines() if line.startswith(("built", "ray")))
            print(f"LH assets {label} build (fresh process, --jobs {os.cpu_count()}): {dt:6.2f} s  "
                  f"[{summary}] rc={proc.returncode}")


def cad_table(faces: int) -> trimesh.Trimesh:
    """A CAD-like table of about `faces` faces: a finely subdivided top and four legs whose
    caps are fans of thin triangles, concatenated (overlapping solids, as CAD exports are)."""
    top = trimesh.creation.box((1.2, 0.8, 0.03))
    while len(top.faces) * 2 < faces:
        top = top.subdivide()
    top.apply_translation((0, 0, 0.735))
    sections = max(16, (faces - len(top.faces)) // 16)
    legs = [trimesh.creation.cylinder(radius=0.03, height=0.72, sections=sections).apply_translation((x, y, 0.36))
            for x in (-0.55, 0.55) for y in (-0.35, 0.35)]
    return trimesh.util.concatenate([top, *legs])


def bench_large_import(faces: int, budget: float) -> None:
    """One `detach-scene build` of a ~`faces`-face CAD-like table in a fresh process: wall time,
    peak memory of the build and of its CoACD child, and what the build did."""
    with tempfile.TemporaryDirectory() as tmp:
        mesh = cad_table(faces)
        src = Path(tmp) / "cad_table.ply"
        mesh.export(src)
        size_mb = src.stat().st_size / 2**20
        del mesh
        cmd = [sys.executable, "-m", "scene_builder.cli", "build", "--source", str(src), "--up", "z",
               "--out", str(Path(tmp) / "out"), "--jobs", "1", "--time-budget", str(budget)]
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
        wall = time.perf_counter() - t0
        peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
        cfg_path = Path(tmp) / "out" / "imported" / "cad_table" / "config.json"
        print(f"large import: {faces / 1e6:.2f}M-face CAD-like table ({size_mb:.0f} MB PLY), --time-budget {budget:g}: "
              f"{wall:.1f} s wall, peak RSS {peak:.0f} MB (largest process), rc={proc.returncode}")
        if not cfg_path.is_file():
            print("  " + (proc.stderr.strip().splitlines() or ["no output"])[-1])
            return
        cfg = json.loads(cfg_path.read_text())
        col = cfg["collision"]
        tries = ", ".join(f"{a['threshold']:g}: {a['outcome']} {a['seconds']:.1f} s"
                          + (f" ({a['peak_rss_mb']:.0f} MB)" if a.get("peak_rss_mb") else "") for a in col["attempts"])
        print(f"  mesh {cfg['mesh']['source_faces']} -> {cfg['mesh']['faces']} faces; CoACD input {col['input_faces']} "
              f"faces; {col['hull_count']} hulls by {col['method']}; tries: {tries or 'none (convex)'}; "
              f"build {cfg['build_seconds']:.1f} s")
        print("  seconds per step: " + ", ".join(f"{k} {v:.1f}" for k, v in cfg.get("seconds", {}).items()))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--large", type=int, nargs="*", default=[], metavar="FACES",
                        help="also import CAD-like tables of these face counts (e.g. 2600000)")
    parser.add_argument("--budget", type=float, default=120.0, help="CoACD --time-budget for --large (s)")
    parser.add_argument("--skip-builds", action="store_true", help="skip the height-map and LH build benchmarks")
    args = parser.parse_args()
    print(f"python {sys.version.split()[0]}, {os.cpu_count()} cores")
    if not args.skip_builds:
        bench_height_map(args.repeats)
        bench_builds()
    for faces in args.large:
        bench_large_import(faces, args.budget)


if __name__ == "__main__":
    main()
