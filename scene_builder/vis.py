"""Pictures of an asset for humans: the height map as a PNG and a GLB to check targets in 3D.

The GLB is a scene with separate, vertex-coloured nodes (object, sit/climb markers, bbox
wireframe, ground): concatenating them into one mesh would lose the colours.
"""

from __future__ import annotations

import numpy as np
import trimesh
from PIL import Image, ImageDraw

_VIRIDIS = np.array([
    [68, 1, 84], [72, 40, 120], [62, 74, 137], [49, 104, 142], [38, 130, 142],
    [31, 158, 137], [53, 183, 121], [109, 205, 89], [180, 222, 44], [253, 231, 37],
], dtype=np.float64)
"""Anchor colours of matplotlib's viridis (perceptually uniform, readable in grey)."""


def colormap(t: np.ndarray) -> np.ndarray:
    """uint8 RGB for values in [0, 1] by linear interpolation between the viridis anchors."""
    x = np.clip(t, 0.0, 1.0) * (len(_VIRIDIS) - 1)
    i = np.minimum(x.astype(int), len(_VIRIDIS) - 2)
    f = (x - i)[..., None]
    return (_VIRIDIS[i] * (1 - f) + _VIRIDIS[i + 1] * f).round().astype(np.uint8)


def height_map_image(hmap: np.ndarray, bbox: np.ndarray, cell_px: int = 4) -> Image.Image:
    """The map (row 0 = max Y at the top, +X to the right) scaled by its own max, with a
    colour bar labelled in metres (a fixed 0-1 scale would clip tall furniture)."""
    hmax = float(hmap.max()) or 1.0
    rgb = np.repeat(np.repeat(colormap(hmap / hmax), cell_px, axis=0), cell_px, axis=1)
    size = rgb.shape[0]
    img = Image.new("RGB", (size + 120, size + 44), "white")
    img.paste(Image.fromarray(rgb), (0, 30))
    draw = ImageDraw.Draw(img)
    draw.text((4, 8), f"height map {bbox[0]:.2f} x {bbox[1]:.2f} m (top = +Y, right = +X)", fill="black")
    bar = colormap(np.linspace(1.0, 0.0, size))[:, None, :].repeat(20, axis=1)
    img.paste(Image.fromarray(bar), (size + 12, 30))
    for frac in (0.0, 0.25, 0.5, 0.75, 1.0):
        y = 30 + int(round((1 - frac) * (size - 1)))
        draw.line([(size + 32, y), (size + 38, y)], fill="black")
        draw.text((size + 42, max(y - 6, 30)), f"{frac * hmax:.2f} m", fill="black")
    return img


def _coloured(mesh: trimesh.Trimesh, rgba: tuple[int, int, int, int]) -> trimesh.Trimesh:
    mesh = mesh.copy()
    mesh.visual = trimesh.visual.ColorVisuals(mesh, vertex_colors=np.tile(rgba, (len(mesh.vertices), 1)))
    return mesh


def _wireframe(bbox: np.ndarray, radius: float = 0.005) -> trimesh.Trimesh:
    """The 12 bbox edges as thin cylinders (GLB line primitives render 1 px wide at best)."""
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * bbox / 2
    edges = [(i, j) for i in range(8) for j in range(i + 1, 8) if np.count_nonzero(corners[i] != corners[j]) == 1]
    bars = [trimesh.creation.cylinder(radius, segment=corners[[i, j]], sections=8) for i, j in edges]
    return trimesh.util.concatenate(bars)


def vis_scene(mesh: trimesh.Trimesh, bbox: np.ndarray, sit: list[float], climb: list[float]) -> trimesh.Scene:
    """Object (grey), sit target (red), climb target (blue), bbox (black), ground (light)."""
    ground = trimesh.creation.box((bbox[0] * 1.5 + 0.5, bbox[1] * 1.5 + 0.5, 0.002))
    ground.apply_translation((0, 0, -bbox[2] / 2 - 0.001))
    scene = trimesh.Scene()
    scene.add_geometry(_coloured(mesh, (170, 170, 170, 255)), node_name="object", geom_name="object")
    for name, pos, rgba in (("sit_target", sit, (220, 40, 40, 255)), ("climb_target", climb, (40, 80, 220, 255))):
        marker = trimesh.creation.icosphere(subdivisions=2, radius=0.04)
        marker.apply_translation(pos)
        scene.add_geometry(_coloured(marker, rgba), node_name=name, geom_name=name)
    scene.add_geometry(_coloured(_wireframe(bbox), (20, 20, 20, 255)), node_name="bbox", geom_name="bbox")
    scene.add_geometry(_coloured(ground, (225, 225, 210, 255)), node_name="ground", geom_name="ground")
    return scene
