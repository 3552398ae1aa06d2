"""Targets, height-map grids and sizes of imported objects (issue 20, items 4-6)."""

from __future__ import annotations

import json

import manifold3d as m3
import numpy as np
import pytest
import trimesh

from scene_builder.heightmap import embree_available, height_map
from scene_builder.size_check import size_warning, suggested_scale
from scene_builder.targets import target_cell
from tests.test_assets_cli import build, save, solid

ENGINES = ["numpy"] + (["embree"] if embree_available() else [])


def config(folder) -> dict:
    return json.loads((folder / "config.json").read_text())


def two_stools() -> trimesh.Trimesh:
    """Two 0.4 x 0.4 x 0.45 m stools 0.2 m apart: nothing under the bbox centre."""
    left = m3.Manifold.cube((0.4, 0.4, 0.45)).translate((-0.5, -0.2, 0.0))
    return solid(left + left.translate((0.6, 0.0, 0.0)))


# ---- item 4: targets in empty space ----------------------------------------------------------


def test_a_gap_under_the_centre_moves_the_targets_onto_the_nearest_seat(tmp_path, capsys):
    src = save(two_stools(), tmp_path / "stools.obj")
    assert build("--source", src, "--up", "z", "--out", tmp_path / "o") == 0
    warned = [line for line in capsys.readouterr().err.splitlines() if line.startswith("warning: ")]
    assert len(warned) == 1 and "nothing under the bbox centre" in warned[0] and "stools.obj" in warned[0]
    cfg = config(tmp_path / "o" / "imported" / "stools")
    x, y, z_sit = cfg["tarSitPos"]
    assert 0.1 + 0.1 - 0.01 <= abs(x) <= 0.5 - 0.1 + 0.01 and abs(y) < 0.01  # 0.1 m inside a stool's top
    assert z_sit == pytest.approx(0.45 + 0.1 - 0.225, abs=1e-6)  # on the seat, not the floor
    assert cfg["tarClimbPos"] == pytest.approx([x, y, 0.225], abs=1e-6)
    assert cfg["height_map"]["target_moved"] is True


def test_target_cell_prefers_the_centre_and_falls_back_to_any_hit():
    hmap = np.zeros((9, 9), dtype=np.float32)
    hit = np.zeros((9, 9), dtype=bool)
    xs, ys = np.linspace(-0.4, 0.4, 9), np.linspace(0.4, -0.4, 9)
    hit[4, 4], hmap[4, 4] = True, 0.3
    assert target_cell(hmap, hit, xs, ys).moved is False
    hit[4, 4] = False
    hit[0, 8], hmap[0, 8] = True, 0.7  # a lone spike in a corner: no flat patch anywhere
    cell = target_cell(hmap, hit, xs, ys)
    assert cell.moved and not cell.supporting and (cell.x, cell.y, cell.height) == pytest.approx((0.4, 0.4, 0.7))
    assert target_cell(hmap, np.zeros_like(hit), xs, ys) is None


# ---- item 5: height-map grid conventions -----------------------------------------------------


def ramp() -> trimesh.Trimesh:
    """Wedge 1 x 1, height 0 at x = -0.5 rising to 0.5 at x = +0.5."""
    pts = [(x, y, z) for y in (-0.5, 0.5) for (x, z) in ((-0.5, 0.0), (0.5, 0.0), (0.5, 0.5))]
    return trimesh.Trimesh(pts).convex_hull


@pytest.mark.parametrize("engine", ENGINES)
def test_linspace_grid_samples_the_bbox_edges_like_tokenhsi(engine):
    lin, _ = height_map(ramp(), engine=engine, grid="linspace")
    cen, _ = height_map(ramp(), engine=engine, grid="centres")
    # TokenHSI: x = linspace(min, max, 128): the last column is on the bbox edge (h = 0.5), the
    # first on the other (h = 0); ours samples cell centres, half a cell in from each edge
    assert lin[0, -1] == pytest.approx(0.5, abs=1e-6) and lin[0, 0] == pytest.approx(0.0, abs=1e-6)
    assert np.allclose(lin[0], 0.5 * np.arange(128) / 127, atol=1e-6)
    assert np.allclose(cen[0], 0.5 * (np.arange(128) + 0.5) / 128, atol=1e-6)
    box, _ = height_map(trimesh.creation.box((0.6, 0.4, 0.3)), engine=engine, grid="linspace")
    assert np.allclose(box, 0.3, atol=1e-6)  # edge rays hit the top face, none miss


def test_grid_option_reaches_the_asset_and_its_cache_key(tmp_path, capsys):
    src = save(ramp(), tmp_path / "ramp.obj")
    assert build("--source", src, "--up", "z", "--out", tmp_path / "o") == 0
    assert build("--source", src, "--up", "z", "--grid", "linspace", "--out", tmp_path / "o") == 0
    assert "built 1, cached 0" in capsys.readouterr().out.splitlines()[-1]  # a different asset: rebuilt
    folder = tmp_path / "o" / "imported" / "ramp"
    assert config(folder)["height_map"]["grid"] == "linspace"
    assert np.load(folder / "height_map" / "map2d.npy")[5, -1] == pytest.approx(0.5, abs=1e-6)


# ---- item 6: scale sanity --------------------------------------------------------------------


def test_a_cad_part_in_the_wrong_units_is_warned_about_with_a_scale_to_try(tmp_path, capsys):
    part = save(trimesh.creation.box((0.16, 0.10, 0.12)), tmp_path / "bracket.stl")
    assert build("--source", part, "--up", "z", "--out", tmp_path / "o") == 0
    err = capsys.readouterr().err
    assert "bracket.stl: 0.16 x 0.1 x 0.12 m (largest side 0.16 m) is outside furniture range" in err
    assert "--scale 10 " in err and "--size X Y Z" in err
    cfg = config(tmp_path / "o" / "imported" / "bracket")
    assert any("outside furniture range" in w for w in cfg["warnings"])
    assert build("--source", part, "--up", "z", "--scale", "10", "--out", tmp_path / "o10") == 0
    assert build("--source", part, "--up", "z", "--size", "0.8", "0.5", "0.6", "--out", tmp_path / "os") == 0
    assert "outside furniture range" not in capsys.readouterr().err


def test_size_warning_suggests_a_power_of_ten():
    assert size_warning(np.array([0.5, 0.4, 0.9]), "chair.obj", None) is None
    assert "--scale 0.001 " in size_warning(np.array([1200.0, 800.0, 750.0]), "table.obj", None)
    assert "--scale 0.01 " in size_warning(np.array([12.0, 8.0, 7.5]), "table.obj", 0.1)  # on top of --scale 0.1
    assert suggested_scale(0.16) == 10.0 and suggested_scale(45.0) == 0.01
