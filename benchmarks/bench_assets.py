"""Asset pipeline speed: height-map ray engines side by side, and cold vs warm LH builds.

Run from the repository root:  python benchmarks/bench_assets.py [--repeats N]
Goals (issue 4): 128x128 map <= 50 ms with Embree; warm rebuild of all LH assets <= 5 s.
"""

from __future__ import annotations

import argparse
import os
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
            print(f"LH assets {label} build (fresh process, --jobs {os.cpu_count()}): {dt:6.2f} s  [{summary}] rc={proc.returncode}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    print(f"python {sys.version.split()[0]}, {os.cpu_count()} cores")
    bench_height_map(args.repeats)
    bench_builds()


if __name__ == "__main__":
    main()
