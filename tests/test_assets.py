"""Asset pipeline, library level: procedural generators, height maps, requests, load/ensure."""

from __future__ import annotations

import manifold3d as m3
import numpy as np
import pytest
import trimesh

from detach.config.schema import SceneObjectCfg, TaskCfg
from scene_builder import procedural
from scene_builder.assets import (AssetError, AssetInfo, default_assets_root, ensure_assets, load_asset,
                                  requests_from_task)
from scene_builder.heightmap import embree_available, height_map
from scene_builder.normalize import normalize

ENGINES = ["numpy"] + (["embree"] if embree_available() else [])


def zup(category: str, variant: int = 0) -> trimesh.Trimesh:
    """A procedural model through the real pipeline's normalisation (metres, Z up, +Y)."""
    gen = procedural.generate(category, variant)
    return normalize(gen.raw, "y", scale=gen.scale)


# ---- procedural library ----------------------------------------------------------------------


@pytest.mark.parametrize("category", sorted(procedural.CATEGORIES))
def test_every_category_is_a_deterministic_solid_in_3dfuture_convention(category):
    a, b = procedural.generate(category, 0), procedural.generate(category, 0)
    assert np.array_equal(a.raw.vertices, b.raw.vertices) and np.array_equal(a.raw.faces, b.raw.faces)
    assert a.raw.is_watertight and a.raw.is_volume
    assert np.isclose(a.raw.extents.max(), 1.0) and np.allclose(a.raw.bounds.sum(axis=0), 0.0, atol=1e-9)
    # raw Y-up extents are the true (x, z, y) sizes divided by the scale
    assert np.allclose(a.raw.extents * a.scale, np.array(a.size)[[0, 2, 1]])
    variants = {tuple(np.round(procedural.generate(category, v).size, 6)) for v in range(4)}
    assert len(variants) >= 2, "variants should differ"


@pytest.mark.parametrize(("category", "lo", "hi"), [
    ("chair", 0.40, 0.50), ("armchair", 0.40, 0.50), ("sofa", 0.40, 0.50), ("bed", 0.45, 0.56), ("table", 0.70, 0.78),
])
def test_seat_and_surface_heights_are_plausible(category, lo, hi):
    for v in range(4):
        mesh = zup(category, v)
        h, _ = height_map(mesh)
        assert lo <= h[64, 64] <= hi, (category, v, h[64, 64])


def test_procedural_objects_face_plus_y():
    """Chair and sofa backs are at -Y: the bottom rows of the map (min Y) are the tallest."""
    for category in ("chair", "sofa", "armchair"):
        h, _ = height_map(zup(category))
        assert h[-1, 64] > h[64, 64] + 0.2 and h[0, 64] < h[-1, 64]


def test_category_names_are_forgiving_and_errors_suggest():
    assert procedural.resolve_category("TV Stand") == "tv_stand"
    assert procedural.resolve_category("toycar") == "toy_car"
    assert procedural.resolve_category("Box") == "box"
    with pytest.raises(AssetError, match="did you mean 'sofa'"):
        procedural.resolve_category("sofaa")


# ---- height map ------------------------------------------------------------------------------


def ramp_rising_to_plus_x() -> trimesh.Trimesh:
    """Wedge 1 x 1, height 0 at x = -0.5 rising to 0.5 at x = +0.5."""
    pts = [(x, y, z) for y in (-0.5, 0.5) for (x, z) in ((-0.5, 0.0), (0.5, 0.0), (0.5, 0.5))]
    return trimesh.Trimesh(pts).convex_hull


@pytest.mark.parametrize("engine", ENGINES)
def test_height_map_columns_rise_towards_plus_x(engine):
    h, ran = height_map(ramp_rising_to_plus_x(), engine=engine)
    assert ran == engine and h.shape == (128, 128) and h.dtype == np.float32
    assert np.all(np.diff(h, axis=1) > 0)  # rising columns in every row
    assert np.allclose(h, h[0])  # no change along Y
    assert np.isclose(h[0, -1], 0.5 * 127.5 / 128, atol=1e-6)  # sampled at cell centres


@pytest.mark.parametrize("engine", ENGINES)
def test_height_map_row_zero_is_plus_y(engine):
    """A low slab everywhere plus a tall block only at y > 0.25: the block is in the top rows."""
    slab = m3.Manifold.cube((1.0, 1.0, 0.1))
    block = m3.Manifold.cube((1.0, 0.25, 0.5)).translate((0.0, 0.75, 0.0))
    mesh = (slab + block).to_mesh64()
    tri = trimesh.Trimesh(np.asarray(mesh.vert_properties)[:, :3], np.asarray(mesh.tri_verts))
    h, _ = height_map(tri, engine=engine)
    assert np.allclose(h[:32], 0.5) and np.allclose(h[32:], 0.1)


def test_height_map_misses_are_zero_and_heights_start_at_the_lowest_point():
    ring = trimesh.creation.annulus(r_min=0.3, r_max=0.5, height=0.2)
    ring.apply_translation((0, 0, 3.0))
    h, _ = height_map(ring)
    assert h[64, 64] == 0.0 and h[0, 0] == 0.0  # hole and corner: misses
    assert np.isclose(h.max(), 0.2, atol=1e-6)


@pytest.mark.skipif(not embree_available(), reason="embreex not installed")
@pytest.mark.parametrize("category", ["chair", "sofa", "table", "toy_car", "television", "obstacle"])
def test_embree_and_numpy_engines_agree_pixel_for_pixel(category):
    mesh = zup(category, 1)
    a, _ = height_map(mesh, engine="embree")
    b, _ = height_map(mesh, engine="numpy")
    assert np.allclose(a, b, atol=1e-5)


# ---- requests from tasks ---------------------------------------------------------------------


def obj(name: str, category: str = "chair", model_id: str = "chair_v0", **kw) -> SceneObjectCfg:
    return SceneObjectCfg(name=name, category=category, model_id=model_id, pos3d=(0.0, 0.0, 0.0), **kw)


def test_requests_from_task_dedupes_identical_objects():
    task = TaskCfg(name="t", scene=(obj("a"), obj("b"), obj("box", "Box", "box_1", size=(1, 1, 1))))
    reqs = requests_from_task(task, None)
    assert [(r.category, r.model_id) for r in reqs] == [("chair", "chair_v0"), ("Box", "box_1")]
    assert reqs[1].size == (1, 1, 1) and reqs[0].source == "procedural"


def test_requests_from_task_conflict_names_both_objects():
    task = TaskCfg(name="t", scene=(obj("left"), obj("right", variant=2)))
    with pytest.raises(AssetError, match=r"scene\[0\] 'left' and scene\[1\] 'right'.*variant 0 vs 2"):
        requests_from_task(task, None)


def test_requests_from_task_rejects_unknown_category_and_resolves_file_sources(tmp_path):
    with pytest.raises(AssetError, match=r"scene\[0\] 'x'.*unknown procedural category 'sofaa'"):
        requests_from_task(TaskCfg(name="t", scene=(obj("x", "sofaa", "s"),)), None)
    reqs = requests_from_task(TaskCfg(name="t", scene=(obj("c", source="abc/normalized_model.obj"),)), tmp_path)
    assert reqs[0].source == str(tmp_path / "abc" / "normalized_model.obj")


def test_requests_for_the_lh_tasks_resolve():
    from pathlib import Path

    from detach.config import load_task

    root = Path(__file__).resolve().parents[1]
    for name in ("lh1", "lh2", "lh3"):
        for req in requests_from_task(load_task(root / "configs" / "tasks" / f"{name}.yaml"), None):
            procedural.resolve_category(req.category)


# ---- load_asset / ensure_assets --------------------------------------------------------------


def test_default_assets_root_honours_environment(monkeypatch, tmp_path):
    monkeypatch.setenv("DETACH_ASSETS", str(tmp_path))
    assert default_assets_root() == tmp_path
    monkeypatch.delenv("DETACH_ASSETS")
    assert str(default_assets_root()) == "assets"


def test_ensure_assets_builds_missing_then_reuses(tmp_path):
    size = (0.6, 0.4, 0.2)
    task = TaskCfg(name="t", scene=(obj("b0", "Box", "box_a", size=size), obj("b1", "Box", "box_a", size=size),
                                    obj("cushion", "cushion", "cushion_v1", variant=1)))
    infos = ensure_assets(task, tmp_path, jobs=1)
    assert set(infos) == {0, 1, 2} and infos[0] is infos[1]
    info = infos[0]
    assert isinstance(info, AssetInfo) and info.bbox == pytest.approx((0.6, 0.4, 0.2))
    assert info.tar_sit_pos == pytest.approx((0, 0, 0.2)) and info.tar_climb_pos == pytest.approx((0, 0, 0.1))
    assert info.mesh_path.is_file() and len(info.hull_paths) == 1 and info.height_map.shape == (128, 128)
    stamp = (info.folder / "config.json").stat().st_mtime_ns
    again = ensure_assets(task, tmp_path, jobs=1)
    assert (again[0].folder / "config.json").stat().st_mtime_ns == stamp


def test_ensure_assets_reports_failures_in_one_line(tmp_path):
    task = TaskCfg(name="t", scene=(obj("m", "chair", "missing", source="nope.obj"),))
    with pytest.raises(AssetError) as err:
        ensure_assets(task, tmp_path, source_root=tmp_path, jobs=1)
    assert "nope.obj" in str(err.value) and "\n" not in str(err.value)


def test_load_asset_rejects_non_asset_folders(tmp_path):
    with pytest.raises(AssetError, match="not an asset folder"):
        load_asset(tmp_path)


def test_default_options_keep_the_cache_keys_of_existing_procedural_assets():
    """New options enter a cache key only when set, and procedural sources get no import-rules
    stamp: the assets built before them stay current (no rebuild of ./assets for everyone)."""
    from scene_builder.pipeline import AssetRequest, BuildOptions, plan

    assert BuildOptions().key_options() == {"coacd_threshold": 0.05, "max_hulls": 16, "max_hull_vertices": 64,
                                            "seed": 0}
    assert BuildOptions(time_budget=30.0, grid="linspace").key_options()["grid"] == "linspace"
    planned = plan(AssetRequest("chair", "chair_v0"), BuildOptions())
    assert planned.options == {"variant": 0, "up": "y", "yaw": 0.0, "scale": None, "size": None,
                               "coacd_threshold": 0.05, "max_hulls": 16, "max_hull_vertices": 64, "seed": 0}
