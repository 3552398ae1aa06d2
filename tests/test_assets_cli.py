"""Asset pipeline through `detach-scene` (scene_builder.cli.main) and the files it writes."""

from __future__ import annotations

import json
from pathlib import Path

import manifold3d as m3
import numpy as np
import pytest
import trimesh
from PIL import Image

from scene_builder.cli import main
from scene_builder.normalize import Y_UP_TO_Z_UP, yaw_matrix


def solid(manifold: m3.Manifold) -> trimesh.Trimesh:
    mesh = manifold.to_mesh64()
    return trimesh.Trimesh(np.asarray(mesh.vert_properties)[:, :3], np.asarray(mesh.tri_verts), process=False)


def wedge() -> trimesh.Trimesh:
    """Convex and asymmetric in x, y and z (Z up): 0.8 x 0.5, rising to 0.3 towards +X."""
    pts = [(x, y, z) for y in (-0.25, 0.25) for (x, z) in ((-0.4, 0.0), (0.4, 0.0), (0.4, 0.3))] + [(0.4, 0.25, 0.35)]
    return trimesh.Trimesh(pts).convex_hull


def step() -> trimesh.Trimesh:
    """Non-convex (needs CoACD): a 1 x 1 x 0.2 slab with a 0.3 m block on its +Y half."""
    return solid(m3.Manifold.cube((1.0, 1.0, 0.2)) + m3.Manifold.cube((1.0, 0.5, 0.5)).translate((0, 0.5, 0)))


def save(mesh: trimesh.Trimesh, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    mesh.export(path)
    return path


def build(*args: str | Path) -> int:
    return main(["build", "--jobs", "1", *map(str, args)])


def outputs(folder: Path) -> dict:
    config = json.loads((folder / "config.json").read_text())
    return {"config": config, "hmap": np.load(folder / "height_map" / "map2d.npy"),
            "mesh": trimesh.load(folder / "mesh.obj", force="mesh", process=False)}


# ---- geometry contract -----------------------------------------------------------------------


@pytest.mark.parametrize("up", ["y", "z"])
def test_axis_aligned_box(tmp_path, up):
    a, b, c = 0.6, 0.4, 0.3
    given = (a, c, b) if up == "y" else (a, b, c)  # a Y-up file has the height along y
    src = save(trimesh.creation.box(given), tmp_path / "box.stl")
    assert build("--source", src, "--up", up, "--out", tmp_path / "out") == 0
    folder = tmp_path / "out" / "imported" / "box"
    out = outputs(folder)
    cfg = out["config"]
    assert cfg["bbox"] == pytest.approx([a, b, c])
    assert cfg["tarSitPos"] == pytest.approx([0, 0, c / 2 + 0.1]) and cfg["tarClimbPos"] == pytest.approx([0, 0, c / 2])
    assert cfg["center"] == [0, 0, 0] and cfg["facing"] == [0, 1, 0] and cfg["up_facing"] == [0, 0, 1]
    assert cfg["pipeline_version"] and len(cfg["source_sha256"]) == 64 and cfg["source"].endswith("box.stl")
    assert out["hmap"].dtype == np.float32 and out["hmap"].shape == (128, 128) and np.allclose(out["hmap"], c)
    assert np.allclose(out["mesh"].bounds, [[-a / 2, -b / 2, -c / 2], [a / 2, b / 2, c / 2]])
    assert cfg["collision"]["hull_count"] == 1 and (folder / "collision" / "hull_000.obj").is_file()
    assert Image.open(folder / "height_map" / "map2d.png").size[0] >= 128
    glb = trimesh.load(folder / "vis" / "mesh.glb")
    assert {"object", "sit_target", "climb_target", "bbox", "ground"} <= set(glb.graph.nodes_geometry)


def test_y_up_and_z_up_versions_of_a_mesh_give_the_same_asset(tmp_path):
    canonical = wedge()
    y_up = trimesh.Trimesh(canonical.vertices @ Y_UP_TO_Z_UP, canonical.faces)  # inverse rotation
    assert build("--source", save(y_up, tmp_path / "y" / "w.obj"), "--up", "y", "--out", tmp_path / "oy") == 0
    assert build("--source", save(canonical, tmp_path / "z" / "w.obj"), "--up", "z", "--out", tmp_path / "oz") == 0
    y, z = outputs(tmp_path / "oy" / "imported" / "w"), outputs(tmp_path / "oz" / "imported" / "w")
    for key in ("bbox", "tarSitPos", "tarClimbPos"):
        assert y["config"][key] == pytest.approx(z["config"][key], abs=1e-9)
    assert np.array_equal(y["hmap"], z["hmap"])
    assert np.allclose(y["mesh"].vertices, z["mesh"].vertices, atol=1e-9)
    assert np.all(np.diff(z["hmap"][64]) >= 0) and z["hmap"][64, -1] > z["hmap"][64, 0]  # rises towards +X


def test_yawed_offset_scaled_input_recovers_bbox_and_targets(tmp_path):
    canonical = wedge()
    moved = canonical.copy()
    moved.apply_transform(np.block([[2.0 * yaw_matrix(90), np.array([[5.0], [-3.0], [2.0]])], [np.zeros((1, 3)), 1.0]]))
    assert build("--source", save(canonical, tmp_path / "a" / "w.ply"), "--up", "z", "--out", tmp_path / "oa") == 0
    assert build("--source", save(moved, tmp_path / "b" / "w.ply"), "--up", "z", "--yaw", "-90", "--scale", "0.5",
                 "--out", tmp_path / "ob") == 0
    stretched = canonical.copy()
    stretched.apply_scale((3.0, 0.5, 2.0))
    assert build("--source", save(stretched, tmp_path / "c" / "w.glb"), "--up", "z", "--size", "0.8", "0.5", "0.35",
                 "--out", tmp_path / "oc") == 0
    ref = outputs(tmp_path / "oa" / "imported" / "w")
    for other in ("ob", "oc"):
        got = outputs(tmp_path / other / "imported" / "w")
        for key in ("bbox", "tarSitPos", "tarClimbPos"):
            assert got["config"][key] == pytest.approx(ref["config"][key], abs=1e-6)
        assert np.allclose(got["hmap"], ref["hmap"], atol=1e-5)


def test_non_convex_mesh_gets_coacd_hulls_and_the_map_shows_plus_y_in_row_zero(tmp_path):
    src = save(step(), tmp_path / "step.obj")
    assert build("--source", src, "--up", "z", "--max-hulls", "3", "--out", tmp_path / "o") == 0
    folder = tmp_path / "o" / "imported" / "step"
    out = outputs(folder)
    assert out["config"]["collision"]["method"] == "coacd" and 1 <= out["config"]["collision"]["hull_count"] <= 3
    assert np.allclose(out["hmap"][:64], 0.5) and np.allclose(out["hmap"][64:], 0.2)
    hulls = [trimesh.load(p, force="mesh") for p in sorted((folder / "collision").glob("hull_*.obj"))]
    assert len(hulls) == out["config"]["collision"]["hull_count"]
    lo, hi = np.min([h.bounds[0] for h in hulls], axis=0), np.max([h.bounds[1] for h in hulls], axis=0)
    assert np.allclose(lo, [-0.5, -0.5, -0.25], atol=0.03) and np.allclose(hi, [0.5, 0.5, 0.25], atol=0.03)


def test_3dfuture_folders_use_model_info_category(tmp_path):
    root = tmp_path / "future"
    save(trimesh.creation.box((1.0, 0.5, 0.8)), root / "0a1b-c" / "normalized_model.obj")
    (root / "0a1b-c" / "model_info.json").write_text(json.dumps({"category": "Dining Chair"}))
    save(trimesh.creation.box((0.5, 1.0, 0.4)), root / "ffee" / "normalized_model.obj")
    assert build("--source", root, "--scale", "2", "--out", tmp_path / "o") == 0
    cfg = json.loads((tmp_path / "o" / "dining_chair" / "0a1b-c" / "config.json").read_text())
    assert cfg["bbox"] == pytest.approx([2.0, 1.6, 1.0])  # Y-up (x, y, z) -> Z-up (x, z, y), x2
    assert (tmp_path / "o" / "imported" / "ffee" / "mesh.obj").is_file()


# ---- cache -----------------------------------------------------------------------------------


def test_cache_hit_skips_work_and_option_changes_rebuild(tmp_path, capsys):
    src = save(trimesh.creation.box((0.5, 0.5, 0.5)), tmp_path / "b.obj")
    config = tmp_path / "o" / "imported" / "b" / "config.json"
    assert build("--source", src, "--out", tmp_path / "o") == 0
    first = config.stat().st_mtime_ns
    capsys.readouterr()
    assert build("--source", src, "--out", tmp_path / "o") == 0
    assert "built 0, cached 1, failed 0" in capsys.readouterr().out
    assert config.stat().st_mtime_ns == first
    assert build("--source", src, "--out", tmp_path / "o", "--force") == 0
    assert "built 1, cached 0" in capsys.readouterr().out and config.stat().st_mtime_ns != first
    assert build("--source", src, "--out", tmp_path / "o", "--scale", "2") == 0
    assert "built 1, cached 0" in capsys.readouterr().out
    assert json.loads(config.read_text())["bbox"] == pytest.approx([1.0, 1.0, 1.0])
    src.write_text(src.read_text().replace("v 0.25", "v 0.3", 1))  # new source bytes
    assert build("--source", src, "--out", tmp_path / "o", "--scale", "2") == 0
    assert "built 1, cached 0" in capsys.readouterr().out
    assert not [p for p in config.parent.parent.iterdir() if p.name.startswith(".")]  # no temp/old folders


# ---- bad input: one line on stderr naming the file, exit 2, nothing written ----------------------


BAD_FILES = {
    "missing.obj": None,
    "notes.txt": "just text",
    "garbage.ply": "\x00\x01 not a ply",
    "empty.obj": "",
    "nan.obj": "v nan 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n",
    "inf.obj": "v inf 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n",
    "flat.obj": "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3\nf 1 3 4\n",
}


def assert_one_line_error(capsys, name: str, out: Path) -> None:
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and name in lines[0] and "Traceback" not in err, err
    assert not out.exists() or not any(out.rglob("*")), list(out.rglob("*"))


@pytest.mark.parametrize("name", sorted(BAD_FILES))
def test_bad_input_is_one_line_exit_2_and_leaves_nothing(tmp_path, capsys, name):
    path = tmp_path / name
    if BAD_FILES[name] is not None:
        path.write_text(BAD_FILES[name])
    assert build("--source", path, "--out", tmp_path / "out", "--up", "z") == 2
    assert_one_line_error(capsys, name, tmp_path / "out")


def test_coacd_failure_is_one_line_exit_2_and_leaves_nothing(tmp_path, capsys, monkeypatch):
    from scene_builder import hulls
    from scene_builder.errors import AssetError

    def boom(mesh, params, timeout, label, progress=None):
        raise AssetError(f"{label}: CoACD convex decomposition failed (RuntimeError: simulated CoACD crash)")

    monkeypatch.setattr(hulls, "run_attempt", boom)
    src = save(step(), tmp_path / "step.obj")
    assert build("--source", src, "--out", tmp_path / "out", "--up", "z") == 2
    assert_one_line_error(capsys, "step.obj", tmp_path / "out")


def test_one_bad_model_in_a_batch_keeps_the_good_ones(tmp_path, capsys):
    root = tmp_path / "future"
    save(trimesh.creation.box((1.0, 1.0, 1.0)), root / "good" / "normalized_model.obj")
    (root / "bad").mkdir()
    (root / "bad" / "normalized_model.obj").write_text(BAD_FILES["nan.obj"])
    assert main(["build", "--source", str(root), "--out", str(tmp_path / "o"), "--jobs", "2"]) == 2
    captured = capsys.readouterr()
    assert (tmp_path / "o" / "imported" / "good" / "config.json").is_file()
    assert not (tmp_path / "o" / "imported" / "bad").exists()
    assert len(captured.err.strip().splitlines()) == 1 and "bad/normalized_model.obj" in captured.err
    assert "built 1, cached 0, failed 1" in captured.out and "imported/bad" in captured.out


def test_usage_errors_exit_2(tmp_path, capsys):
    assert main(["build", "--scale", "2", "--size", "1", "1", "1", "--source", str(tmp_path)]) == 2
    assert main(["build", "--tasks", "configs/tasks/lh1.yaml", "--scale", "2"]) == 2
    assert "apply to --source imports" in capsys.readouterr().err
    assert main(["build", "--source", str(tmp_path), "--out", str(tmp_path / "o")]) == 2  # empty folder
    assert "no models found (looked for 3D-FUTURE model folders" in capsys.readouterr().err


# ---- tasks, inspect, list, help ----------------------------------------------------------------


def test_build_from_a_task_yaml_then_inspect(tmp_path, capsys, monkeypatch):
    task = tmp_path / "tasks" / "mini.yaml"
    task.parent.mkdir()
    task.write_text("name: mini\nplan: [climb]\ntarget_object: [0]\nsample_target_from: [scene_0]\nscene:\n"
                    "  - {name: box, category: Box, model_id: box_a, pos3d: [0, 0, 0.25], size: [0.5, 0.5, 0.5]}\n"
                    "  - {name: seat, category: cushion, model_id: cushion_v0, pos3d: [1, 0, 0.1]}\n")
    monkeypatch.setenv("DETACH_ASSETS", str(tmp_path / "assets"))
    assert main(["build", "--tasks", str(task), "--jobs", "1"]) == 0
    out = capsys.readouterr().out
    assert "ray engine: " in out and "built 2, cached 0, failed 0" in out
    assert main(["inspect", str(tmp_path / "assets" / "Box" / "box_a")]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["bbox"] == pytest.approx([0.5, 0.5, 0.5]) and summary["height_map_stats"]["shape"] == [128, 128]
    assert "collision/hull_000.obj" in summary["files"]
    assert main(["inspect", str(tmp_path)]) == 2


def test_list_and_help(tmp_path, capsys):
    assert main(["list", "--variants", "2"]) == 0
    out = capsys.readouterr().out
    for name in ("box", "obstacle", "chair", "armchair", "sofa", "bed", "table", "nightstand", "tv_stand",
                 "television", "toy_car", "wardrobe", "cushion", "platform", "wall"):
        assert f"\n{name}:" in "\n" + out
    save(trimesh.creation.box((1, 1, 1)), tmp_path / "m1" / "normalized_model.obj")
    assert main(["list", "--source", str(tmp_path)]) == 0
    assert "imported/m1" in capsys.readouterr().out
    assert main(["--help"]) == 0 and main(["build", "--help"]) == 0
    assert "--size X Y Z" in capsys.readouterr().out


@pytest.mark.slow
def test_all_lh_assets_build_and_rebuild_warm(tmp_path, capsys):
    root = Path(__file__).resolve().parents[1]
    tasks = [str(p) for p in sorted((root / "configs" / "tasks").glob("lh*.yaml"))]
    assert main(["build", "--tasks", *tasks, "--out", str(tmp_path), "--jobs", "2"]) == 0
    assert ", failed 0" in capsys.readouterr().out
    assert main(["build", "--tasks", *tasks, "--out", str(tmp_path)]) == 0
    assert "built 0" in capsys.readouterr().out


def test_help_starts_without_the_heavy_imports():
    """`detach-scene --help` must answer in well under a second: the CLI imports numpy, trimesh,
    manifold3d and the pipeline only inside its commands (measured 0.3 s, was ~2 s)."""
    import subprocess
    import sys

    code = ("import sys; from scene_builder.cli import main; code = main(['build', '--help']); "
            "heavy = sorted(m for m in ('numpy', 'trimesh', 'manifold3d', 'coacd', 'scene_builder.assets') "
            "if m in sys.modules); print(heavy); sys.exit(code)")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0 and "--time-budget" in proc.stdout, proc.stderr
    assert proc.stdout.strip().splitlines()[-1] == "[]"
