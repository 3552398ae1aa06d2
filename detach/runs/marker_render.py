"""The task markers (`detach.eval.task_markers`) in MuJoCo's offscreen video.

Shapes become user geoms appended to the `mjvScene` after `update_scene` (lines as capsule
connectors, spheres, discs as flat cylinders), so MuJoCo renders them with the scene's depth
and lighting. Text is drawn onto the finished RGB frame with Pillow, as a caption in the
top-left corner: MuJoCo's own text (`mjr_overlay`) needs the renderer's private GL context,
and label geoms are drawn small and only where the scene's label flag is on.
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from detach.eval.task_markers import Disc, Marker, Polyline, Sphere, Text

DISC_HALF_HEIGHT = 0.004
EMISSION = 0.6
"""Markers glow a little, so their colour reads the same in shadow."""


def _rgba(color: Sequence[int], opacity: float = 1.0) -> np.ndarray:
    return np.array([*(float(c) / 255 for c in color[:3]), float(opacity)], dtype=np.float32)


def add_marker_geoms(scene: Any, markers: Sequence[Marker]) -> int:
    """Append the markers' shapes to an `mjvScene` (after `update_scene`, before `render`);
    returns the number of geoms added (it stops quietly at the scene's `maxgeom`)."""
    import mujoco

    eye = np.eye(3).reshape(-1)
    added = 0

    def geom(kind: int, size: Sequence[float], pos: Sequence[float], rgba: np.ndarray) -> Any | None:
        """One user geom; `size` as a model geom's (mjv_initGeom expands it)."""
        nonlocal added
        if scene.ngeom >= scene.maxgeom:
            return None
        g = scene.geoms[scene.ngeom]
        mujoco.mjv_initGeom(g, kind, np.asarray(size, dtype=np.float64), np.asarray(pos, dtype=np.float64),
                            eye, rgba)
        g.emission = EMISSION
        g.category = int(mujoco.mjtCatBit.mjCAT_DECOR)
        scene.ngeom += 1
        added += 1
        return g

    for m in markers:
        if isinstance(m, Polyline):
            rgba = _rgba(m.color)
            pts = np.asarray(m.points, dtype=np.float64)
            for a, b in zip(pts[:-1], pts[1:]):
                if np.linalg.norm(b - a) < 1e-6:
                    continue
                g = geom(mujoco.mjtGeom.mjGEOM_CAPSULE, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), rgba)
                if g is None:
                    break
                mujoco.mjv_connector(g, mujoco.mjtGeom.mjGEOM_CAPSULE, m.width / 2, a, b)
        elif isinstance(m, Sphere):
            geom(mujoco.mjtGeom.mjGEOM_SPHERE, (m.radius,) * 3, m.pos, _rgba(m.color, m.opacity))
        elif isinstance(m, Disc):
            pos = (float(m.pos[0]), float(m.pos[1]), 0.012)
            geom(mujoco.mjtGeom.mjGEOM_CYLINDER, (m.radius, DISC_HALF_HEIGHT, 0.0), pos,
                 _rgba(m.color, m.opacity))
    return added


def draw_captions(rgb: np.ndarray, markers: Sequence[Marker]) -> np.ndarray:
    """The markers' text lines in the frame's top-left corner, on a dark band (a new array)."""
    texts = [m for m in markers if isinstance(m, Text)]
    if not texts:
        return rgb
    from PIL import Image, ImageDraw, ImageFont

    image = Image.fromarray(np.ascontiguousarray(rgb))
    size = max(12, image.height // 24)
    try:
        font: Any = ImageFont.load_default(size=size)
    except TypeError:  # a Pillow without FreeType: the fixed bitmap font
        font = ImageFont.load_default()
    draw = ImageDraw.Draw(image, "RGBA")
    pad, y = size // 3, size // 3
    for t in texts:
        left, top, right, bottom = draw.textbbox((pad, y), t.text, font=font)
        draw.rectangle((left - pad, top - pad // 2, right + pad, bottom + pad // 2), fill=(0, 0, 0, 150))
        draw.text((pad, y), t.text, font=font, fill=tuple(t.color[:3]))
        y = bottom + pad
    return np.asarray(image)
