"""Scene compilation: object placement, dynamic boxes at rest, the static height raster."""

from __future__ import annotations

import json
import math

import mujoco
import numpy as np
import pytest
import trimesh

from detach.character import make_character
from detach.config.schema import SceneObjectCfg, SimCfg, TaskCfg
from scene_builder.assets import load_asset
from scene_builder.scene import compile_scene


def write_box_asset(folder, size) -> None:
    """A minimal valid asset folder (docs/ARCHITECTURE.md, "Asset folder") for a box of `size`."""
    (folder / "collision").mkdir(parents=True)
    (folder / "height_map").mkdir()
    mesh = trimesh.creation.box(extents=size)
    mesh.export(folder / "mesh.obj")
    mesh.export(folder / "collision" / "hull_000.obj")
    h = np.full((128, 128), size[2], dtype=np.float32)
    np.save(folder / "height_map" / "map2d.npy", h)
    cfg = {"bbox": list(size), "center": [0, 0, 0], "facing": [0, 1, 0], "up_facing": [0, 0, 1],
           "tarSitPos": [0, 0, size[2] / 2 + 0.1], "tarClimbPos": [0, 0, size[2] / 2],
           "source": "test", "source_sha256": "0", "pipeline_version": "test", "category": "Box",
           "model_id": folder.name, "collision": {"files": ["collision/hull_000.obj"]}}
    (folder / "config.json").write_text(json.dumps(cfg))


@pytest.fixture(scope="module")
def box_assets(tmp_path_factory):
    root = tmp_path_factory.mktemp("assets")
    out = {}
    for name, size in (("small", (0.4, 0.3, 0.5)), ("table", (1.2, 0.8, 0.7))):
        write_box_asset(root / name, size)
        out[name] = load_asset(root / name)
    return out


def _task(**kw) -> TaskCfg:
    scene = (
        SceneObjectCfg(name="crate", category="Box", model_id="small", static=False,
                       pos3d=(1.0, -2.0, 0.55), z_rot_angle=0.4, mass=4.0),
        SceneObjectCfg(name="table", category="Box", model_id="table", static=True,
                       pos3d=(-1.5, 1.0, 0.35), z_rot_angle=math.pi / 2),
    )
    return TaskCfg(name="scene_test", scene=scene, humanoid=kw.get("humanoid", TaskCfg.humanoid),
                   plan=("carry",), target_object=(0,), sample_target_from=("tarpos_0",),
                   target_positions=((0.0, 0.0, 0.25),))


@pytest.mark.parametrize("character", ["humanoid", "puppet"])
def test_objects_placed_as_in_yaml(box_assets, character):
    task = _task()
    model, info = compile_scene(task, make_character(character), SimCfg(),
                                assets={0: box_assets["small"], 1: box_assets["table"]})
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    for obj, cfg in zip(info.objects, task.scene):
        np.testing.assert_allclose(data.xpos[obj.body_id], cfg.pos3d, atol=1e-9)
        yaw = 2 * math.atan2(data.xquat[obj.body_id][3], data.xquat[obj.body_id][0])
        assert abs(yaw - cfg.z_rot_angle) < 1e-9
        assert obj.static == cfg.static
    crate, table = info.objects
    assert crate.qpos_adr >= 0 and table.qpos_adr == -1
    assert model.body_mass[crate.body_id] == pytest.approx(4.0)
    np.testing.assert_allclose(table.tar_sit_world, [-1.5, 1.0, 0.35 + 0.35 + 0.1], atol=1e-9)
    assert (crate.link_eq >= 0) == (character == "puppet")
    assert info.dynamic == (0,)
    # visual meshes never collide, hulls do
    for g in range(model.ngeom):
        if model.geom_bodyid[g] in (crate.body_id, table.body_id) and model.geom_group[g] == 2:
            assert model.geom_contype[g] == 0 and model.geom_conaffinity[g] == 0


def test_box_dropped_rests_at_half_height(box_assets):
    model, info = compile_scene(_task(), make_character("humanoid"), SimCfg(),
                                assets={0: box_assets["small"], 1: box_assets["table"]})
    data = mujoco.MjData(model)
    crate = info.objects[0]
    data.qpos[info.root_qpos_adr:info.root_qpos_adr + 3] = (5.0, 5.0, 0.94)  # character out of the way
    data.qpos[crate.qpos_adr + 2] = 0.25 + 0.3  # 0.3 m above rest
    mujoco.mj_forward(model, data)
    for _ in range(240):
        mujoco.mj_step(model, data)
    assert data.xpos[crate.body_id][2] == pytest.approx(0.25, abs=0.005)
    np.testing.assert_allclose(data.xpos[crate.body_id][:2], (1.0, -2.0), atol=0.01)
    assert np.abs(data.qvel[crate.qvel_adr:crate.qvel_adr + 6]).max() < 0.05


def test_static_height_raster(box_assets):
    _, info = compile_scene(_task(), make_character("humanoid"), SimCfg(),
                            assets={0: box_assets["small"], 1: box_assets["table"]})
    r = info.raster
    # the table (rotated 90 deg: 0.8 x 1.2 footprint) is 0.7 m high; the dynamic crate is not in it
    assert r.sample(np.array([-1.5, 1.0])) == pytest.approx(0.7, abs=1e-3)
    assert r.sample(np.array([-1.5, 1.5])) == pytest.approx(0.7, abs=1e-3)  # along its long side
    assert r.sample(np.array([-2.0, 1.0])) == 0.0  # beyond its short side
    assert r.sample(np.array([1.0, -2.0])) == 0.0
    assert r.sample(np.array([100.0, 100.0])) == 0.0
