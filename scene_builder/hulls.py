"""Collision shapes: CoACD convex decomposition of the processed mesh, within a time budget.

MuJoCo collides each mesh geom through its convex hull, so a concave chair needs several
convex pieces as geoms of one body. Convex inputs (boxes, walls, cushions) skip CoACD: their
hull is the exact decomposition.

CoACD's time is not bounded by its hull cap: real 25-29k-face CAD parts ran past 300 s at the
default threshold 0.05 (0.1: ~60 s, 0.2: ~35 s, 0.5: 2-3 s). So every run happens in a child
process (`scene_builder.coacd_worker`) that is killed when its share of the per-asset budget
is spent, and the next try raises the threshold (coarser, fewer hulls, much faster):
threshold t, 2t, 4t, ... up to `MAX_THRESHOLD` (0.05, 0.1, 0.2, 0.5) and, for inputs that need
CoACD's manifold remeshing (not watertight), a coarser remeshing (resolution 50 down to 20: on
real CAD the remeshing, not the threshold, is most of the time); a quarter of the budget is
kept for the last try, and each earlier try gets half of the rest that is left. When every try
runs out of time, the fallback is bounded by construction: the convex hulls of the mesh's
connected parts, or of `max_hulls` spatial clusters of its faces (k-means), merged down to
`max_hulls`. What happened is returned as a `HullReport`
(config.json "collision") and, when it is not plain CoACD at the requested threshold, as a
warning. The input is decimated to `hull_faces` first, so memory follows that cap.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from scene_builder.decimate import HULL_FACES, decimate
from scene_builder.errors import AssetError
from scene_builder.settings import TIME_BUDGET  # default seconds per asset; the procedural library needs ~1-2 s

MAX_THRESHOLD = 0.5
"""Coarsest CoACD threshold tried before the fallback (~2-3 s on real CAD parts)."""
PREPROCESS_RESOLUTION = 50
"""CoACD's default resolution of its manifold remeshing (non-watertight inputs only)."""
PREPROCESS_RESOLUTION_MIN = 20
"""Its resolution in the last try (CoACD's documented range is 20-100)."""
FINAL_SHARE = 0.25
"""Share of the budget kept for the last, coarsest try (it usually needs a few seconds, which a
halving schedule would not leave it on a loaded machine)."""
HEARTBEAT = 15.0
"""Seconds between progress lines while CoACD runs."""


@dataclass
class HullReport:
    """How the collision hulls were made (written to config.json "collision")."""

    method: str = "convex"
    """'convex' (the mesh is its own hull), 'coacd', or 'clusters' (fallback after the budget)."""
    threshold: float | None = None
    """CoACD threshold of the hulls that were kept (None unless method is 'coacd')."""
    attempts: list[dict[str, Any]] = field(default_factory=list)
    """One entry per CoACD try: threshold, seconds, timeout, outcome (ok/timeout), peak_rss_mb."""
    input_faces: int = 0
    """Faces CoACD saw (after decimation to the hull face cap)."""
    budget_s: float = TIME_BUDGET

    def warning(self, requested: float, hull_count: int) -> str | None:
        """One clause saying what the budget changed, or None when nothing did."""
        if self.method == "clusters":
            tries = ", ".join(f"{a['threshold']:g}" for a in self.attempts) or "none started"
            return (f"CoACD ran out of its {self.budget_s:g} s budget at every threshold ({tries}); "
                    f"collision uses {hull_count} convex hulls of the mesh's parts instead "
                    "(coarse; raise --time-budget for CoACD hulls)")
        if self.method == "coacd" and self.threshold is not None and self.threshold > requested:
            spent = sum(a["seconds"] for a in self.attempts if a["outcome"] == "timeout")
            remesh = self.attempts[-1].get("preprocess_resolution", PREPROCESS_RESOLUTION)
            coarser = f" and remeshing resolution {remesh}" if remesh != PREPROCESS_RESOLUTION else ""
            return (f"CoACD at threshold {requested:g} did not finish within the {self.budget_s:g} s budget "
                    f"({spent:.0f} s spent on finer thresholds); used threshold {self.threshold:g}{coarser} "
                    "(coarser hulls; raise --time-budget to keep the finer threshold)")
        return None

    def as_dict(self) -> dict[str, Any]:
        return {"method": self.method, "threshold": self.threshold, "attempts": self.attempts,
                "input_faces": self.input_faces, "budget_s": self.budget_s}


Progress = Callable[[str], None]


def _preprocess_resolution(i: int, tries: int) -> int:
    """CoACD's manifold-remeshing resolution for try i of `tries`: its default (50) first, down to
    PREPROCESS_RESOLUTION_MIN for the last try (on a non-watertight CAD table the remeshing took
    51 s of a 0.5-threshold run at 50 and 14 s at 20, so a coarser threshold alone saves little)."""
    if tries <= 1 or i == 0:
        return PREPROCESS_RESOLUTION
    step = (PREPROCESS_RESOLUTION - PREPROCESS_RESOLUTION_MIN) / (tries - 1)
    return int(round(PREPROCESS_RESOLUTION - step * i))


def thresholds(start: float) -> list[float]:
    """The escalation ladder: start, 2*start, 4*start, ..., MAX_THRESHOLD last (a doubling that
    would land within 2x of it is replaced by it: 0.05, 0.1, 0.2, 0.5)."""
    out = [float(start)]
    while out[-1] * 2.0 < MAX_THRESHOLD:
        out.append(out[-1] * 2.0)
    if out[-1] < MAX_THRESHOLD:
        if len(out) > 1 and out[-1] * 2.0 > MAX_THRESHOLD * 1.5:
            out[-1] = MAX_THRESHOLD
        else:
            out.append(MAX_THRESHOLD)
    return out


@dataclass(frozen=True)
class Attempt:
    outcome: str
    """'ok' or 'timeout'."""
    parts: list[tuple[np.ndarray, np.ndarray]]
    seconds: float
    peak_rss_mb: float | None = None


def run_attempt(mesh: trimesh.Trimesh, params: dict[str, Any], timeout: float, label: str,
                progress: Progress | None = None) -> Attempt:
    """One CoACD run in a child process, killed after `timeout` seconds. AssetError (one line)
    if CoACD fails or the child dies; a timeout is an Attempt with outcome 'timeout'."""
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="detach-coacd-") as tmp:
        job = Path(tmp)
        np.savez(job / "input.npz", vertices=np.asarray(mesh.vertices, dtype=np.float64),
                 faces=np.asarray(mesh.faces, dtype=np.int32), params=np.str_(json.dumps(params)))
        with open(job / "stderr.txt", "wb") as err:
            proc = subprocess.Popen([sys.executable, "-m", "scene_builder.coacd_worker", str(job)],
                                    stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=err)
            try:
                while True:
                    left = timeout - (time.perf_counter() - t0)
                    try:
                        proc.wait(timeout=max(0.0, min(HEARTBEAT, left)))
                        break
                    except subprocess.TimeoutExpired:
                        spent = time.perf_counter() - t0
                        if spent >= timeout:
                            proc.kill()
                            proc.wait()
                            return Attempt("timeout", [], spent)
                        if progress is not None:
                            progress(f"{label}: CoACD threshold {params['threshold']:g} running for {spent:.0f} s "
                                     f"(this try stops at {timeout:.0f} s)")
            finally:
                if proc.poll() is None:  # interrupted (Ctrl-C): do not leave CoACD running
                    proc.kill()
                    proc.wait()
        seconds = time.perf_counter() - t0
        if (job / "error.txt").is_file():
            raise AssetError(f"{label}: CoACD convex decomposition failed ({(job / 'error.txt').read_text().strip()})")
        if proc.returncode != 0 or not (job / "output.npz").is_file():
            tail = (job / "stderr.txt").read_text(errors="replace").strip().splitlines()[-1:] or [""]
            raise AssetError(f"{label}: CoACD process died (exit code {proc.returncode}) {tail[0]}".rstrip())
        with np.load(job / "output.npz") as out:
            parts = [(out[f"v{i}"], out[f"f{i}"]) for i in range(int(out["count"]))]
            peak = float(out["peak_rss_mb"])
    return Attempt("ok", parts, seconds, peak)


def _to_hulls(parts: list[tuple[np.ndarray, np.ndarray]]) -> list[trimesh.Trimesh]:
    return [trimesh.Trimesh(v, f, process=True) for v, f in parts if len(f) >= 4]


def cluster_hulls(mesh: trimesh.Trimesh, max_hulls: int, seed: int = 0) -> list[trimesh.Trimesh]:
    """Fallback decomposition, bounded in time (one split, one k-means, convex hulls): the hulls
    of the mesh's connected parts when there are 2 to `max_hulls` of them, else of `max_hulls`
    k-means clusters of points on its surface (flat clusters merge into their nearest
    neighbour: a flat hull collides with nothing). Coarser than CoACD, never empty, never slow.
    Written here because CoACD is the only decomposition library we depend on and it is what
    ran out of time."""
    from scipy.cluster.vq import kmeans2

    parts = mesh.split(only_watertight=False)
    if 1 < len(parts) <= max_hulls:
        groups = [np.asarray(p.vertices) for p in parts]
    else:
        surface, _ = trimesh.sample.sample_surface(mesh, 4000, seed=seed)
        points = np.concatenate([np.asarray(mesh.vertices), surface])
        _, labels = kmeans2(points, max(1, max_hulls), seed=seed, minit="++")
        groups = [points[labels == i] for i in range(max_hulls) if np.any(labels == i)]
    hulls = _solid_hulls(groups, tolerance=1e-9 * float(mesh.scale) ** 3)
    return hulls or [mesh.convex_hull]


def _solid_hulls(groups: list[np.ndarray], tolerance: float) -> list[trimesh.Trimesh]:
    """Convex hulls of point groups; a group whose hull has no volume joins the group with the
    nearest centroid until every hull is solid (or one group is left)."""
    groups = [g for g in groups if len(g)]
    while groups:
        hulls, flat = [], None
        for k, points in enumerate(groups):
            try:
                hull = trimesh.Trimesh(points).convex_hull
            except Exception:  # qhull refuses a coplanar or collinear group
                hull = None
            if hull is None or len(hull.faces) < 4 or not hull.volume > tolerance:
                flat = k
                break
            hulls.append(hull)
        if flat is None:
            return hulls
        if len(groups) == 1:
            return []
        centres = np.array([g.mean(axis=0) for g in groups])
        dist = np.linalg.norm(centres - centres[flat], axis=1)
        dist[flat] = np.inf
        nearest = int(np.argmin(dist))
        groups[nearest] = np.concatenate([groups[nearest], groups[flat]])
        del groups[flat]
    return []


def convex_hulls(
    mesh: trimesh.Trimesh,
    label: str,
    threshold: float = 0.05,
    max_hulls: int = 16,
    max_hull_vertices: int = 64,
    seed: int = 0,
    budget_s: float = TIME_BUDGET,
    hull_faces: int = HULL_FACES,
    progress: Progress | None = None,
) -> tuple[list[trimesh.Trimesh], HullReport]:
    """(hulls in the mesh's frame, report) within `budget_s` seconds of CoACD (plus ~0.3 s of
    process start per try).

    `threshold` is CoACD's concavity tolerance (smaller = more, tighter hulls); `max_hulls`
    caps the count (CoACD merges beyond it) to keep MuJoCo's contact work bounded;
    `max_hull_vertices` decimates each hull. Watertight meshes run with CoACD's preprocessing
    off (measured ~1 s vs ~12 s for a manifold chair); others need its manifold remeshing
    ('auto'). `label` names the source in messages; `progress` hears heartbeat lines.
    """
    report = HullReport(budget_s=float(budget_s))
    if mesh.is_watertight and mesh.is_convex:
        report.input_faces = len(mesh.faces)
        return [mesh.convex_hull], report
    if not budget_s > 0:
        raise AssetError(f"{label}: time budget must be > 0 s, got {budget_s}")
    work, _ = decimate(mesh, hull_faces, label)
    report.input_faces = len(work.faces)
    preprocess = "off" if work.is_watertight else "auto"
    ladder = thresholds(threshold)
    deadline = time.perf_counter() + budget_s
    reserve = FINAL_SHARE * budget_s if len(ladder) > 1 else 0.0  # kept for the coarsest, fast try
    for i, t in enumerate(ladder):
        left = deadline - time.perf_counter()
        if left <= 0:
            break
        timeout = left if i == len(ladder) - 1 else (left - reserve) / 2.0
        if timeout <= 0:
            continue
        params = {"threshold": t, "max_convex_hull": max_hulls, "preprocess_mode": preprocess,
                  "decimate": True, "max_ch_vertex": max_hull_vertices, "seed": seed}
        entry: dict[str, Any] = {"threshold": t}
        if preprocess != "off":
            params["preprocess_resolution"] = entry["preprocess_resolution"] = _preprocess_resolution(i, len(ladder))
        attempt = run_attempt(work, params, timeout, label, progress)
        report.attempts.append({**entry, "seconds": round(attempt.seconds, 2), "timeout": round(timeout, 2),
                                "outcome": attempt.outcome, "peak_rss_mb": attempt.peak_rss_mb})
        if attempt.outcome == "ok":
            hulls = _to_hulls(attempt.parts)
            if not hulls:
                raise AssetError(f"{label}: CoACD convex decomposition returned no hulls")
            report.method, report.threshold = "coacd", t
            return hulls, report
        if progress is not None:
            progress(f"{label}: CoACD threshold {t:g} stopped after {attempt.seconds:.0f} s (budget); "
                     f"{'trying a coarser threshold' if i + 1 < len(ladder) else 'using part hulls'}")
    report.method = "clusters"
    return cluster_hulls(work, max_hulls, seed), report
