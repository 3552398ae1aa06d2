"""Asset ids (issue 20, item 3): from the source's folders or --name; never a silent overwrite."""

from __future__ import annotations

import json

import pytest
import trimesh

from scene_builder.cli import main
from tests.test_assets_cli import build, save


def box(x: float, y: float, z: float) -> trimesh.Trimesh:
    return trimesh.creation.box((x, y, z))


def source_of(folder) -> str:
    return json.loads((folder / "config.json").read_text())["source"]


def errors(err: str) -> list[str]:
    return [line for line in err.splitlines() if line.startswith("error: ")]


def test_tokenhsi_objects_named_mesh_obj_get_ids_from_their_folders(tmp_path, capsys):
    root = tmp_path / "objects"
    save(box(0.5, 0.5, 0.45), root / "chair" / "a1" / "mesh.obj")
    save(box(1.2, 0.8, 0.75), root / "table" / "b2" / "mesh.obj")
    (root / "table" / "b2" / "config.json").write_text("{}")  # TokenHSI's own files are ignored
    assert main(["build", "--source", str(root), "--up", "z", "--out", str(tmp_path / "o"), "--jobs", "1"]) == 0
    assert "built 2, cached 0, failed 0" in capsys.readouterr().out
    assert source_of(tmp_path / "o" / "chair" / "a1").endswith("chair/a1/mesh.obj")
    assert source_of(tmp_path / "o" / "table" / "b2").endswith("table/b2/mesh.obj")
    # one file given directly is named the same way
    assert build("--source", root / "chair" / "a1" / "mesh.obj", "--up", "z", "--out", tmp_path / "one") == 0
    assert (tmp_path / "one" / "chair" / "a1" / "config.json").is_file()


def test_a_different_asset_of_the_same_id_is_an_error_unless_force(tmp_path, capsys):
    first, second = tmp_path / "set1" / "chair" / "a1" / "mesh.obj", tmp_path / "set2" / "chair" / "a1" / "mesh.obj"
    save(box(0.5, 0.5, 0.45), first)
    save(box(0.6, 0.6, 0.40), second)
    out = tmp_path / "o"
    assert build("--source", first, "--up", "z", "--out", out) == 0
    capsys.readouterr()
    assert build("--source", second, "--up", "z", "--out", out) == 2
    captured = capsys.readouterr()
    (line,) = errors(captured.err)
    assert "set2/chair/a1/mesh.obj" in line and "already holds a different asset" in line and "set1" in line
    assert "--force" in line and "--name" in line
    assert "built 0, cached 0, failed 1" in captured.out
    assert source_of(out / "chair" / "a1") == str(first)  # untouched
    assert build("--source", second, "--up", "z", "--out", out, "--force") == 0
    assert source_of(out / "chair" / "a1") == str(second)
    # the same file again, edited: a rebuild, not a clash; the same bytes elsewhere: the same asset
    save(box(0.6, 0.6, 0.42), second)
    assert build("--source", second, "--up", "z", "--out", out) == 0
    copy = save(box(0.6, 0.6, 0.42), tmp_path / "copy" / "chair" / "a1" / "mesh.obj")
    capsys.readouterr()
    assert build("--source", copy, "--up", "z", "--out", out) == 0
    assert "cached 1" in capsys.readouterr().out


def test_name_gives_an_explicit_id(tmp_path, capsys):
    src = save(box(0.5, 0.5, 0.45), tmp_path / "mesh.obj")
    assert build("--source", src, "--up", "z", "--name", "stool/cad_7", "--out", tmp_path / "o") == 0
    assert (tmp_path / "o" / "stool" / "cad_7" / "config.json").is_file()
    assert build("--source", src, "--up", "z", "--name", "plain", "--category", "seat", "--out", tmp_path / "o") == 0
    assert (tmp_path / "o" / "seat" / "plain" / "config.json").is_file()
    capsys.readouterr()
    for bad in ("../x", "a/b/c", ".hidden"):
        assert build("--source", src, "--name", bad, "--out", tmp_path / "o") == 2
        assert "--name" in capsys.readouterr().err
    save(box(1, 1, 1), tmp_path / "many" / "a.obj")
    save(box(1, 1, 1), tmp_path / "many" / "b.obj")
    assert build("--source", tmp_path / "many", "--name", "x", "--out", tmp_path / "o") == 2
    assert "--name needs a single model, found 2" in capsys.readouterr().err


def test_two_sources_with_one_id_in_a_batch_both_fail(tmp_path, capsys):
    root = tmp_path / "mixed"
    save(box(0.5, 0.5, 0.5), root / "table.obj")
    save(box(0.5, 0.5, 0.6), root / "table.stl")
    save(box(0.4, 0.4, 0.4), root / "stool.obj")
    assert build("--source", root, "--up", "z", "--out", tmp_path / "o") == 2
    captured = capsys.readouterr()
    lines = errors(captured.err)
    assert len(lines) == 2 and all("imported/table is also claimed by" in line for line in lines)
    assert "built 1, cached 0, failed 2" in captured.out
    assert not (tmp_path / "o" / "imported" / "table").exists()


def test_3dfuture_folder_uses_normalized_model_not_raw_model(tmp_path, capsys):
    folder = tmp_path / "3D-FUTURE-model" / "0a1b-c"
    save(box(1.0, 0.8, 0.5), folder / "normalized_model.obj")
    save(box(90.0, 80.0, 50.0), folder / "raw_model.obj")
    assert build("--source", tmp_path / "3D-FUTURE-model", "--out", tmp_path / "o") == 0
    assert "built 1, cached 0, failed 0" in capsys.readouterr().out
    assert source_of(tmp_path / "o" / "imported" / "0a1b-c").endswith("normalized_model.obj")


def test_list_shows_the_ids_a_build_would_use(tmp_path, capsys):
    save(box(0.5, 0.5, 0.45), tmp_path / "objects" / "sofa" / "s9" / "mesh.obj")
    assert main(["list", "--source", str(tmp_path / "objects")]) == 0
    assert "sofa/s9\t" in capsys.readouterr().out


def test_name_is_refused_with_tasks(capsys):
    assert main(["build", "--tasks", "configs/tasks/lh1.yaml", "--name", "x"]) == 2
    assert "--name applies to a single --source model, not to --tasks" in capsys.readouterr().err


@pytest.mark.parametrize("variant", [0, 2])
def test_task_objects_keep_their_ids_and_a_changed_variant_is_a_clash(tmp_path, capsys, variant):
    """Procedural assets keep <category>/<model_id>; another variant under the same id is refused."""
    task = tmp_path / "t.yaml"
    task.write_text("name: t\nplan: [sit]\ntarget_object: [0]\nsample_target_from: [scene_0]\nscene:\n"
                    "  - {name: c, category: cushion, model_id: cushion_a, pos3d: [0, 0, 0.1], "
                    f"variant: {variant}}}\n")
    out = tmp_path / "o"
    assert main(["build", "--tasks", str(task), "--out", str(out), "--jobs", "1"]) == 0
    assert source_of(out / "cushion" / "cushion_a") == f"procedural:cushion:{variant}"
    task.write_text(task.read_text().replace(f"variant: {variant}", f"variant: {variant + 1}"))
    capsys.readouterr()
    assert main(["build", "--tasks", str(task), "--out", str(out), "--jobs", "1"]) == 2
    assert "already holds a different asset (built from procedural:cushion:" in capsys.readouterr().err
