"""Orientation checks (issue 20, item 1): upside-down furniture and a wrong --up are warned
about with the evidence; --flip and --up auto fix them; correct furniture is never flagged."""

from __future__ import annotations

import json

import manifold3d as m3
import numpy as np
import pytest
import trimesh

from scene_builder import procedural
from scene_builder.normalize import Y_UP_TO_Z_UP
from scene_builder.orientation import MARGIN, assess, decide, measure
from tests.test_assets_cli import build, save, solid


def span(x0: float, x1: float, y0: float, y1: float, z0: float, z1: float) -> m3.Manifold:
    return m3.Manifold.cube((x1 - x0, y1 - y0, z1 - z0)).translate((x0, y0, z0))


def cad_table_top() -> trimesh.Trimesh:
    """A CAD table top, Z up: a 1.2 x 0.8 plate 2.5 cm thick on a 2.5 cm apron frame 4 cm wide
    (top surface 5 cm above the floor, the apron below it)."""
    plate = span(-0.6, 0.6, -0.4, 0.4, 0.025, 0.05)
    apron = span(-0.6, 0.6, -0.4, 0.4, 0.0, 0.03) - span(-0.56, 0.56, -0.36, 0.36, -1, 1)
    return solid(plate + apron)


def upside_down(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """The same part as a CAD export with its large flat face pointing down (180 deg about X)."""
    return trimesh.Trimesh(mesh.vertices @ np.diag([1.0, -1.0, -1.0]), mesh.faces)


def config(folder) -> dict:
    return json.loads((folder / "config.json").read_text())


def warnings_of(err: str) -> list[str]:
    return [line for line in err.splitlines() if line.startswith("warning: ")]


def test_upside_down_table_top_is_warned_with_evidence_and_flip_fixes_it(tmp_path, capsys):
    src = save(upside_down(cad_table_top()), tmp_path / "table_top.stl")
    assert build("--source", src, "--up", "z", "--out", tmp_path / "as_is") == 0
    warned = warnings_of(capsys.readouterr().err)
    assert len(warned) == 1 and "table_top.stl: looks like it is upside down" in warned[0] and "--flip" in warned[0]
    assert "support polygon" in warned[0] and "closed top 15%" in warned[0]  # the evidence, in numbers
    as_is = config(tmp_path / "as_is" / "imported" / "table_top")
    assert as_is["tarClimbPos"][2] == pytest.approx(0.0, abs=1e-6)  # the plate's underside: 2.5 cm low
    assert as_is["warnings"] == [w.removeprefix("warning: ") for w in warned]

    for flag in (["--flip"], ["--up", "auto"]):
        out = tmp_path / flag[-1].strip("-")
        args = ["--source", src, *flag, "--out", out] + (["--up", "z"] if flag == ["--flip"] else [])
        assert build(*args) == 0
        assert not warnings_of(capsys.readouterr().err)
        fixed = config(out / "imported" / "table_top")
        assert fixed["tarClimbPos"] == pytest.approx([0, 0, 0.025], abs=1e-6)  # on the top surface
        assert fixed["bbox"] == pytest.approx([1.2, 0.8, 0.05], abs=1e-6)
        assert fixed["orientation"]["flip"] is True and fixed["orientation"]["up"] == "z"


def test_z_up_chair_given_as_y_up_is_warned_and_up_auto_picks_z(tmp_path, capsys):
    chair = procedural.build_zup("chair", 0)
    src = save(chair, tmp_path / "chair" / "c1" / "mesh.obj")  # TokenHSI-style: Z up
    assert build("--source", src, "--out", tmp_path / "o") == 0  # default --up y: wrong
    warned = warnings_of(capsys.readouterr().err)
    assert any("looks like its up axis is z, not y" in w and "rebuild with --up z" in w for w in warned), warned
    assert build("--source", src, "--up", "auto", "--out", tmp_path / "auto") == 0
    assert not warnings_of(capsys.readouterr().err)
    auto = config(tmp_path / "auto" / "chair" / "c1")
    assert auto["orientation"]["up"] == "z" and auto["orientation"]["chosen"] == "auto"
    assert auto["bbox"] == pytest.approx(chair.extents, abs=1e-6)
    assert auto["tarSitPos"][2] == pytest.approx(0.45 + 0.1 - chair.extents[2] / 2, abs=0.01)  # seat + 0.1


@pytest.mark.parametrize("category", sorted(procedural.CATEGORIES))
def test_correct_furniture_is_not_flagged_and_auto_keeps_it(category):
    """The procedural library, as 3D-FUTURE files (Y up) and as TokenHSI files (Z up): no warning
    for the right axis, and --up auto never turns it over or onto its side."""
    for variant in (0, 1):
        zup = procedural.build_zup(category, variant)
        yup = trimesh.Trimesh(zup.vertices @ Y_UP_TO_Z_UP, zup.faces, process=False)
        for raw, up in ((yup, "y"), (zup, "z")):
            evidence = measure(raw, engine="numpy")
            given = decide(evidence, up, False, category)
            assert given.warnings == (), (category, variant, up, given.warnings)
            auto = decide(evidence, "auto", False, category)
            scores = auto.as_dict()["scores"]
            assert not auto.flip, (category, variant, up, scores)
            if auto.up != up:  # only where the geometry gives no evidence either way
                assert abs(scores[auto.up] - scores[up]) <= MARGIN, (category, variant, up, scores)


@pytest.mark.parametrize("category", ["chair", "table", "nightstand", "tv_stand", "bed", "toy_car"])
def test_upside_down_and_wrong_axis_furniture_is_detected(category):
    zup = procedural.build_zup(category, 0)
    turned, upright = measure(upside_down(zup), engine="numpy"), measure(zup, engine="numpy")
    over = decide(turned, "z", False, category)
    assert len(over.warnings) == 1 and "looks like it is upside down" in over.warnings[0]
    assert decide(turned, "auto", False, category).flip
    lying = decide(upright, "y", False, category)  # a Z-up file read as Y up
    assert len(lying.warnings) == 1 and "its up axis is z, not y" in lying.warnings[0]
    assert decide(upright, "auto", False, category).up == "z"


def test_a_wedge_balancing_on_its_edge_is_unstable():
    """The flipped ramp stands on a line: its score is the unstable one, whatever its flat top."""
    profile = ((0.5, 0), (-0.5, 0), (-0.5, 0.4))
    ramp = solid(m3.Manifold.hull_points([(x, y, z) for x in (-0.5, 0.5) for (y, z) in profile]))
    result = assess(upside_down(ramp), "z", False, "ramp", engine="numpy")
    assert not result.evidence["z"].stable and result.evidence["z+flip"].stable
