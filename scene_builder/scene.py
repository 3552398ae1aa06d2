"""Scene compilation: a task's objects + the character -> one MjModel and a `SceneInfo`.

Every object comes from its asset folder (docs/ARCHITECTURE.md, "Asset folder"), which must
have been built already (`detach-scene build`, or the runner before it makes an
environment): compiling a scene only reads files. The processed mesh is an object's visual
geom, its CoACD hulls are its collision geoms, and its body sits at the task's `pos3d` (bbox
centre, world) rotated by `z_rot_angle` about +Z. Static objects are welded to the world;
dynamic ones (boxes) get a free joint and the configured mass with the inertia of a solid box.
The character (`detach.character`) is added under the world body, and may link itself to the
dynamic objects (`Character.link_objects`; the puppet's grasp welds).

Geom groups: 0 floor, 1 character, 2 visual meshes (shown by default viewers), 3 collision
hulls. A static height raster of the scene (world Z of the first surface hit by a ray cast
straight down from the camera height onto the static objects' visual meshes; 0 = floor) is
computed once here and sampled by the env's local height-map observation, which adds the
moving objects itself.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np
import trimesh

from detach.character import Character, add_character
from detach.character.body import BODY_NAMES, DOF_NAMES, add_floor, configure_options
from detach.config.schema import SimCfg, TaskCfg
from scene_builder.assets import AssetInfo, read_assets

GROUP_FLOOR, GROUP_CHARACTER, GROUP_VISUAL, GROUP_COLLISION = 0, 1, 2, 3
RASTER_SPACING = 0.05
"""Cell size (m) of the static scene height raster (half the 0.1 m observation spacing)."""
RASTER_MARGIN = 3.0
"""Margin (m) of the raster around everything the task mentions (objects, paths, targets)."""


@dataclass(frozen=True)
class SceneObject:
    """One compiled object. Positions are world frame at the start; `*_local` are in the
    object frame (bbox centre at the origin, facing +Y before `z_rot`)."""

    index: int
    name: str
    category: str
    static: bool
    body_id: int
    body_name: str
    pos: np.ndarray
    z_rot: float
    bbox: np.ndarray
    """Full bounding-box sizes (x, y, z), metres, object frame."""
    tar_sit_local: np.ndarray
    tar_climb_local: np.ndarray
    mass: float
    qpos_adr: int = -1
    """Address of the free joint in qpos (dynamic objects), else -1."""
    qvel_adr: int = -1
    link_eq: int = -1
    """Equality id of the character's link to this object (`Character.link_objects`), else -1."""

    def to_world(self, local: np.ndarray) -> np.ndarray:
        c, s = math.cos(self.z_rot), math.sin(self.z_rot)
        x, y, z = local
        return self.pos + np.array([c * x - s * y, s * x + c * y, z])

    @property
    def tar_sit_world(self) -> np.ndarray:
        return self.to_world(self.tar_sit_local)


@dataclass(frozen=True)
class HeightRaster:
    """Static scene heights: `heights[i, j]` is the world Z of the surface at
    (origin_x + i * spacing, origin_y + j * spacing); 0 off the raster (floor)."""

    origin: tuple[float, float]
    spacing: float
    heights: np.ndarray

    def sample(self, xy: np.ndarray) -> np.ndarray:
        """Nearest-cell heights at world points xy [..., 2] (tests and tools; the env
        interpolates bilinearly on torch)."""
        ij = np.rint((np.asarray(xy) - np.asarray(self.origin)) / self.spacing).astype(int)
        nx, ny = self.heights.shape
        ok = (ij[..., 0] >= 0) & (ij[..., 0] < nx) & (ij[..., 1] >= 0) & (ij[..., 1] < ny)
        out = np.zeros(ij.shape[:-1], dtype=np.float32)
        out[ok] = self.heights[ij[..., 0][ok], ij[..., 1][ok]]
        return out


@dataclass(frozen=True)
class SceneInfo:
    """What the env needs to know about a compiled scene beyond the MjModel."""

    task_name: str
    character: str
    objects: tuple[SceneObject, ...]
    trajectories: dict[int, np.ndarray]
    target_positions: np.ndarray
    """[K, 3] world positions (`tarpos_K`)."""
    body_ids: np.ndarray
    """[15] MuJoCo body ids of the character's bodies, `body.BODY_NAMES` order."""
    dof_qpos_adr: np.ndarray
    """[32] qpos addresses of the character's hinges, `body.DOF_NAMES` order."""
    dof_qvel_adr: np.ndarray
    root_qpos_adr: int
    """Address of the character's root joint (`Character.root_joint`)."""
    root_qvel_adr: int
    raster: HeightRaster
    dynamic: tuple[int, ...] = field(default=())
    """Indices of dynamic objects."""


def yaw_quat(a: float) -> np.ndarray:
    """wxyz quaternion of a rotation by `a` radians about +Z (an object's `z_rot_angle`)."""
    return np.array([math.cos(a / 2), 0.0, 0.0, math.sin(a / 2)])


def _load_obj(path: Path) -> tuple[np.ndarray, np.ndarray]:
    mesh = trimesh.load(str(path), force="mesh", process=False)
    return np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int32)


def compile_scene(task: TaskCfg, character: Character, sim: SimCfg | None = None,
                  assets: dict[int, AssetInfo] | None = None, assets_root: str | Path | None = None,
                  camera_height: float = 10.0) -> tuple[mujoco.MjModel, SceneInfo]:
    """Compile `task`'s scene with the character; returns (model, SceneInfo).

    `assets` maps object index -> AssetInfo; when None they are read from `assets_root`
    (default `$DETACH_ASSETS` or ./assets), and a missing asset is an AssetError that says
    how to build it.
    """
    sim = sim or SimCfg()
    if assets is None:
        assets = read_assets(task, assets_root)
    spec = mujoco.MjSpec()
    spec.modelname = f"{task.name}_{character.name}"
    configure_options(spec, sim.physics_dt, sim.solver_iterations)
    if sim.sleep is not False:  # None: not resolved by a backend (detach.sim.sim_settings); on
        spec.option.enableflags |= int(mujoco.mjtEnableBit.mjENBL_SLEEP)
    add_floor(spec, sim.friction)
    mu = (sim.friction, 0.005, 0.0001)

    meshes: dict[str, tuple[str, list[str]]] = {}
    bodies = []
    for i, obj in enumerate(task.scene):
        asset = assets[i]
        folder = str(asset.folder)
        if folder not in meshes:
            k = len(meshes)
            v, f = _load_obj(Path(asset.mesh_path))
            vis = spec.add_mesh(name=f"asset{k}_visual", uservert=v.ravel(), userface=f.ravel())
            vis.inertia = mujoco.mjtMeshInertia.mjMESH_INERTIA_SHELL
            hulls = []
            for h, hp in enumerate(asset.hull_paths):
                hv, hf = _load_obj(Path(hp))
                m = spec.add_mesh(name=f"asset{k}_hull{h}", uservert=hv.ravel(), userface=hf.ravel())
                m.maxhullvert = 64
                m.inertia = mujoco.mjtMeshInertia.mjMESH_INERTIA_CONVEX
                hulls.append(m.name)
            meshes[folder] = (vis.name, hulls)
        vis_name, hull_names = meshes[folder]
        bbox = np.asarray(asset.bbox, dtype=np.float64)
        body = spec.worldbody.add_body(name=f"obj{i}_{obj.name}", pos=list(obj.pos3d),
                                       quat=list(yaw_quat(obj.z_rot_angle)))
        if not obj.static:
            body.add_freejoint(name=f"obj{i}_{obj.name}_free")
            body.explicitinertial = True
            body.mass = obj.mass
            body.ipos = [0.0, 0.0, 0.0]  # the asset is centred on its bbox: COM at the origin
            body.iquat = [1.0, 0.0, 0.0, 0.0]
            sx, sy, sz = bbox
            body.inertia = [obj.mass / 12 * (sy**2 + sz**2), obj.mass / 12 * (sx**2 + sz**2),
                            obj.mass / 12 * (sx**2 + sy**2)]
        g = body.add_geom(name=f"obj{i}_visual", type=mujoco.mjtGeom.mjGEOM_MESH, meshname=vis_name)
        g.contype, g.conaffinity = 0, 0
        g.group = GROUP_VISUAL
        g.rgba = (0.7, 0.55, 0.35, 1.0) if not obj.static else (0.6, 0.62, 0.7, 1.0)
        g.mass = 0.0
        for h, hn in enumerate(hull_names):
            c = body.add_geom(name=f"obj{i}_hull{h}", type=mujoco.mjtGeom.mjGEOM_MESH, meshname=hn)
            c.group = GROUP_COLLISION
            c.friction = mu
            c.rgba = (0.3, 0.6, 0.3, 0.4)
            c.mass = 0.0 if obj.static else 1e-6
        bodies.append((obj, asset, bbox))

    add_character(character, spec.worldbody, spec, friction=sim.friction)
    links = character.link_objects(spec, {i: f"obj{i}_{obj.name}" for i, obj in enumerate(task.scene)
                                          if not obj.static})
    model = spec.compile()

    objects = []
    for i, (obj, asset, bbox) in enumerate(bodies):
        bid = model.body(f"obj{i}_{obj.name}").id
        qadr = vadr = geq = -1
        if not obj.static:
            jid = model.joint(f"obj{i}_{obj.name}_free").id
            qadr, vadr = int(model.jnt_qposadr[jid]), int(model.jnt_dofadr[jid])
        if i in links:
            geq = model.equality(links[i]).id
        objects.append(SceneObject(
            index=i, name=obj.name, category=obj.category, static=obj.static, body_id=bid,
            body_name=f"obj{i}_{obj.name}", pos=np.asarray(obj.pos3d, dtype=np.float64),
            z_rot=float(obj.z_rot_angle), bbox=bbox,
            tar_sit_local=np.asarray(asset.tar_sit_pos, dtype=np.float64),
            tar_climb_local=np.asarray(asset.tar_climb_pos, dtype=np.float64),
            mass=float(obj.mass), qpos_adr=qadr, qvel_adr=vadr, link_eq=geq))

    body_ids = np.array([model.body(n).id for n in BODY_NAMES])
    jids = [model.joint(n).id for n in DOF_NAMES]
    root_j = model.joint(character.root_joint).id
    info = SceneInfo(
        task_name=task.name, character=character.name, objects=tuple(objects),
        trajectories={int(k): np.asarray(v, dtype=np.float64) for k, v in task.trajectories.items()},
        target_positions=np.asarray(task.target_positions, dtype=np.float64).reshape(-1, 3),
        body_ids=body_ids,
        dof_qpos_adr=np.array([model.jnt_qposadr[j] for j in jids]),
        dof_qvel_adr=np.array([model.jnt_dofadr[j] for j in jids]),
        root_qpos_adr=int(model.jnt_qposadr[root_j]), root_qvel_adr=int(model.jnt_dofadr[root_j]),
        raster=static_height_raster(model, task, objects, camera_height),
        dynamic=tuple(o.index for o in objects if not o.static),
    )
    return model, info


def _extent(task: TaskCfg, objects: list[SceneObject]) -> tuple[float, float, float, float]:
    pts = [np.asarray(task.humanoid.init_pos2d, dtype=np.float64)[None]]
    for o in objects:
        r = 0.5 * float(np.hypot(o.bbox[0], o.bbox[1]))
        pts.append(o.pos[None, :2] + np.array([[-r, -r], [r, r]]))
    for v in task.trajectories.values():
        pts.append(np.asarray(v, dtype=np.float64).reshape(-1, 2))
    if task.target_positions:
        pts.append(np.asarray(task.target_positions, dtype=np.float64).reshape(-1, 3)[:, :2])
    p = np.concatenate(pts)
    lo, hi = p.min(0) - RASTER_MARGIN, p.max(0) + RASTER_MARGIN
    return float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])


def static_height_raster(model: mujoco.MjModel, task: TaskCfg, objects: list[SceneObject],
                         camera_height: float = 10.0, spacing: float = RASTER_SPACING) -> HeightRaster:
    """World-Z surface heights of the static objects on a regular grid (0 where a ray hits
    nothing but the floor), by casting rays straight down from `camera_height` (m) onto the
    static visual meshes (exact triangles), all rays in one threaded batch call."""
    x0, y0, x1, y1 = _extent(task, objects)
    nx, ny = int(math.ceil((x1 - x0) / spacing)) + 1, int(math.ceil((y1 - y0) / spacing)) + 1
    if not any(o.static for o in objects):
        return HeightRaster((x0, y0), spacing, np.zeros((nx, ny), dtype=np.float32))
    from mujoco import batch as mjbatch

    xs, ys = x0 + spacing * np.arange(nx), y0 + spacing * np.arange(ny)
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    pnt = np.stack((gx.ravel(), gy.ravel(), np.full(gx.size, camera_height)), axis=-1)
    groups = np.zeros(6, dtype=np.uint8)
    groups[GROUP_VISUAL] = 1
    b = mjbatch.Batch(model, 1, nthread=0, persistent=True)  # persistent: sleep may be enabled
    qpos = b.bind("qpos")
    for o in objects:  # dynamic objects move: park them far below the floor for the static map
        if not o.static:
            qpos[0, o.qpos_adr + 2] = -1000.0
    dist, _ = b.ray(pnt[None], np.array([0.0, 0.0, -1.0]), geomgroup=groups)
    h = np.where(dist[0] >= 0, camera_height - dist[0], 0.0).clip(min=0.0)
    return HeightRaster((x0, y0), spacing, h.reshape(nx, ny).astype(np.float32))
