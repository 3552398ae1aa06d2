"""Built-in procedural furniture: the default asset source, so everything runs with no dataset.

Each generator builds one object from boxes and cylinders united with manifold3d (a manifold
union keeps CoACD fast: ~1 s instead of ~20 s for the same boxes merely concatenated), in
metres, Z up, front towards +Y, floor at z = 0. `generate` then hands it out in 3D-FUTURE's
`normalized_model.obj` convention (Y up, front +Z, centred, largest extent 1) together with its
true size, so procedural and real models go through exactly the same pipeline.

Variant 0 of every category is the canonical model (the middle of every size range); other
variants draw sizes and styles from a generator seeded by (category, variant).
"""

from __future__ import annotations

import difflib
import hashlib
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache
from importlib.metadata import version
from pathlib import Path

import manifold3d as m3
import numpy as np
import trimesh

from scene_builder.errors import AssetError
from scene_builder.normalize import Y_UP_TO_Z_UP

M = m3.Manifold
EPS = 0.005
"""Overlap (m) between touching parts so the union is one solid, not faces meeting exactly."""


class _Dims:
    """Size and style choices of one variant: midpoints for variant 0, seeded draws otherwise."""

    def __init__(self, category: str, variant: int):
        self.rng = None if variant == 0 else np.random.default_rng([zlib.crc32(category.encode()), variant])

    def u(self, lo: float, hi: float) -> float:
        return (lo + hi) / 2.0 if self.rng is None else float(self.rng.uniform(lo, hi))

    def pick(self, *options):
        return options[0] if self.rng is None else options[int(self.rng.integers(len(options)))]


def _span(x0: float, x1: float, y0: float, y1: float, z0: float, z1: float) -> M:
    """Axis-aligned box given by its extents (m)."""
    return M.cube((x1 - x0, y1 - y0, z1 - z0)).translate((x0, y0, z0))


def _cyl(r: float, h: float, center: tuple[float, float, float], axis: str = "z", seg: int = 24) -> M:
    c = M.cylinder(h, r, r, seg, True)
    if axis == "x":
        c = c.rotate((0.0, 90.0, 0.0))
    elif axis == "y":
        c = c.rotate((90.0, 0.0, 0.0))
    return c.translate(center)


def _union(parts: list[M]) -> M:
    return M.batch_boolean(parts, m3.OpType.Add)


def _legs(x: float, y: float, h: float, t: float, round_: bool = False) -> list[M]:
    """Four legs of thickness t at the corners of the rectangle |x|, |y|, from floor to h+EPS."""
    out = []
    for sx in (-1, 1):
        for sy in (-1, 1):
            cx, cy = sx * (x - t / 2), sy * (y - t / 2)
            if round_:
                out.append(_cyl(t / 2, h + EPS, (cx, cy, (h + EPS) / 2)))
            else:
                out.append(_span(cx - t / 2, cx + t / 2, cy - t / 2, cy + t / 2, 0.0, h + EPS))
    return out


def _fronts(w: float, y: float, z0: float, z1: float, n: int, rows: bool) -> list[M]:
    """n door/drawer panels 12 mm proud of the face at y, split across x (or z when rows)."""
    gap, out = 0.006, []
    for i in range(n):
        if rows:
            a, b = z0 + (z1 - z0) * i / n, z0 + (z1 - z0) * (i + 1) / n
            out.append(_span(-w / 2 + gap, w / 2 - gap, y - EPS, y + 0.012, a + gap, b - gap))
        else:
            a, b = -w / 2 + w * i / n, -w / 2 + w * (i + 1) / n
            out.append(_span(a + gap, b - gap, y - EPS, y + 0.012, z0 + gap, z1 - gap))
    return out


# ---- parametric shapes (usually sized by the task's `size`) ---------------------------------


def _box(d: _Dims) -> M:
    return _span(0, d.u(0.3, 0.5), 0, d.u(0.3, 0.5), 0, d.u(0.3, 0.5))


def _obstacle(d: _Dims) -> M:
    w, dep, h = d.u(0.5, 1.0), d.u(0.5, 1.0), d.u(0.2, 0.4)
    style = d.pick("block", "steps", "ramp")
    if style == "steps":  # two steps rising away from the front (towards -Y)
        return _union([_span(-w / 2, w / 2, -dep / 2, dep / 2, 0, h / 2), _span(-w / 2, w / 2, -dep / 2, 0, 0, h)])
    if style == "ramp":  # wedge: 0 at the front edge, h at the back
        pts = [(x, y, z) for x in (-w / 2, w / 2) for (y, z) in ((dep / 2, 0), (-dep / 2, 0), (-dep / 2, h))]
        return M.hull_points(pts)
    return _span(-w / 2, w / 2, -dep / 2, dep / 2, 0, h)


def _platform(d: _Dims) -> M:
    w, dep, h = d.u(1.5, 2.5), d.u(1.5, 2.5), d.u(0.2, 0.4)
    top = _span(-w / 2, w / 2, -dep / 2, dep / 2, h - 0.05, h)
    if d.pick("slab", "plinth") == "plinth":  # recessed base: a toe kick all round
        return _union([top, _span(-w / 2 + 0.05, w / 2 - 0.05, -dep / 2 + 0.05, dep / 2 - 0.05, 0, h - 0.05 + EPS)])
    return _span(-w / 2, w / 2, -dep / 2, dep / 2, 0, h)


def _wall(d: _Dims) -> M:
    length, t, h = d.u(3.0, 5.0), d.u(0.15, 0.25), d.u(2.5, 3.0)
    wall = _span(-length / 2, length / 2, -t / 2, t / 2, 0, h)
    if d.pick("plain", "baseboard") == "baseboard":
        return _union([wall, _span(-length / 2, length / 2, t / 2 - EPS, t / 2 + 0.015, 0, 0.1)])
    return wall


# ---- seating ---------------------------------------------------------------------------------


def _chair(d: _Dims) -> M:
    w, dep, sh, st = d.u(0.42, 0.50), d.u(0.42, 0.50), d.u(0.42, 0.48), d.u(0.04, 0.06)
    top, leg, bt = d.u(0.85, 1.0), d.u(0.035, 0.045), d.u(0.03, 0.05)
    round_legs, slats = d.pick(False, True), d.pick(False, True)
    parts = [_span(-w / 2, w / 2, -dep / 2, dep / 2, sh - st, sh)]
    parts += _legs(w / 2, dep / 2, sh - st, leg, round_legs)
    y0, y1 = -dep / 2, -dep / 2 + bt
    if slats:  # two posts, a top rail and three slats
        for sx in (-1, 1):
            parts.append(_span(sx * w / 2 - (sx > 0) * leg, sx * w / 2 + (sx < 0) * leg, y0, y1, sh - EPS, top))
        parts.append(_span(-w / 2, w / 2, y0, y1, top - 0.08, top))
        for x in (-w / 4, 0.0, w / 4):
            parts.append(_span(x - 0.02, x + 0.02, y0 + 0.005, y1 - 0.005, sh - EPS, top - 0.08 + EPS))
    else:
        parts.append(_span(-w / 2, w / 2, y0, y1, sh - EPS, top))
    return _union(parts)


def _upholstered(d: _Dims, w: float, dep: float) -> M:
    """Armchair and sofa: base, seat cushion, arms, back; on short legs or a skirt."""
    sh, ah, top = d.u(0.40, 0.45), d.u(0.58, 0.66), d.u(0.80, 0.92)
    aw, bt = d.u(0.10, 0.18), d.u(0.15, 0.22)
    lh = d.pick(d.u(0.08, 0.12), 0.0)
    parts = [
        _span(-w / 2, w / 2, -dep / 2, dep / 2, lh, sh - 0.12),  # base
        _span(-w / 2 + aw - EPS, w / 2 - aw + EPS, -dep / 2 + bt - EPS, dep / 2, sh - 0.12 - EPS, sh),  # cushion
        _span(-w / 2, w / 2, -dep / 2, -dep / 2 + bt, lh, top),  # back
    ]
    for sx in (-1, 1):
        parts.append(_span(sx * w / 2 - (sx > 0) * aw, sx * w / 2 + (sx < 0) * aw, -dep / 2, dep / 2, lh, ah))
    if lh > 0:
        for sx in (-1, 1):
            for sy in (-1, 1):
                centre = (sx * (w / 2 - 0.05), sy * (dep / 2 - 0.05), (lh + EPS) / 2)
                parts.append(_cyl(0.025, lh + EPS, centre, seg=16))
    return _union(parts)


def _armchair(d: _Dims) -> M:
    return _upholstered(d, d.u(0.72, 0.86), d.u(0.75, 0.88))


def _sofa(d: _Dims) -> M:
    return _upholstered(d, d.u(1.7, 2.2), d.u(0.85, 0.95))


def _bed(d: _Dims) -> M:
    w, length, mt, mth = d.u(1.4, 1.8), d.u(2.0, 2.2), d.u(0.48, 0.55), d.u(0.18, 0.25)
    hh, hbt, lh = d.u(0.9, 1.2), 0.08, d.u(0.10, 0.15)
    legs, footboard = d.pick(True, False), d.pick(False, True)
    y0 = -length / 2 + hbt
    fz0 = lh if legs else 0.0
    parts = [
        _span(-w / 2, w / 2, y0 - EPS, length / 2, fz0, mt - mth + 0.02),  # frame
        _span(-w / 2 + 0.03, w / 2 - 0.03, y0 - EPS, length / 2 - 0.03, mt - mth, mt),  # mattress
        _span(-w / 2, w / 2, -length / 2, y0, 0, hh),  # headboard
    ]
    if legs:
        parts += _legs(w / 2, length / 2, lh, 0.06)
    n_pillows = 2 if w > 1.5 else 1
    for i in range(n_pillows):
        cx = (i - (n_pillows - 1) / 2) * w / 2
        parts.append(_span(cx - 0.3, cx + 0.3, y0 + 0.05, y0 + 0.40, mt - EPS, mt + 0.12))
    if footboard:
        parts.append(_span(-w / 2, w / 2, length / 2 - 0.06, length / 2, 0, mt + 0.1))
    return _union(parts)


# ---- tables and cabinets ---------------------------------------------------------------------


def _table(d: _Dims) -> M:
    h, tt = d.u(0.72, 0.76), d.u(0.03, 0.05)
    if d.pick("rect", "rect", "round") == "round":
        r = d.u(0.45, 0.6)
        return _union([
            _cyl(r, tt, (0, 0, h - tt / 2), seg=48),
            _cyl(0.06, h - tt + EPS, (0, 0, (h - tt + EPS) / 2)),
            _cyl(0.25, 0.03, (0, 0, 0.015), seg=32),
        ])
    w, dep, leg = d.u(1.1, 1.6), d.u(0.7, 0.9), d.u(0.05, 0.07)
    parts = [_span(-w / 2, w / 2, -dep / 2, dep / 2, h - tt, h)]
    parts += _legs(w / 2 - 0.03, dep / 2 - 0.03, h - tt, leg)
    parts.append(_span(-w / 2 + 0.05, w / 2 - 0.05, -dep / 2 + 0.05, dep / 2 - 0.05, h - tt - 0.08, h - tt + EPS))
    return _union(parts)


def _cabinet(d: _Dims, w: float, dep: float, h: float, n: int, rows: bool, lh: float) -> M:
    """Carcass on legs with a slightly overhanging top and n fronts with knobs on +Y."""
    parts = [
        _span(-w / 2, w / 2, -dep / 2, dep / 2, lh, h - 0.025 + EPS),
        _span(-w / 2 - 0.01, w / 2 + 0.01, -dep / 2 - 0.01, dep / 2 + 0.01, h - 0.025, h),
    ]
    parts += _legs(w / 2 - 0.02, dep / 2 - 0.02, lh, 0.04)
    parts += _fronts(w, dep / 2, lh, h - 0.025, n, rows)
    for i in range(n):  # one knob per front
        if rows:
            x, z = 0.0, lh + (h - 0.025 - lh) * (i + 0.5) / n
        else:
            x, z = -w / 2 + w * (i + 0.5) / n, (lh + h) / 2
        parts.append(_cyl(0.012, 0.03, (x, dep / 2 + 0.02, z), axis="y", seg=12))
    return _union(parts)


def _nightstand(d: _Dims) -> M:
    return _cabinet(d, d.u(0.42, 0.55), d.u(0.36, 0.45), d.u(0.50, 0.62), d.pick(2, 1, 3), True, d.u(0.05, 0.10))


def _tv_stand(d: _Dims) -> M:
    return _cabinet(d, d.u(1.2, 1.8), d.u(0.38, 0.45), d.u(0.45, 0.55), d.pick(3, 2, 4), False, d.u(0.06, 0.12))


def _wardrobe(d: _Dims) -> M:
    w, dep, h, n = d.u(1.0, 1.6), d.u(0.55, 0.62), d.u(1.9, 2.2), d.pick(2, 3)
    parts = [
        _span(-w / 2 + 0.03, w / 2 - 0.03, -dep / 2 + 0.03, dep / 2 - 0.03, 0, 0.08 + EPS),  # plinth
        _span(-w / 2, w / 2, -dep / 2, dep / 2, 0.08, h - 0.03 + EPS),  # carcass
        _span(-w / 2 - 0.02, w / 2 + 0.02, -dep / 2, dep / 2 + 0.02, h - 0.03, h),  # crown
    ]
    parts += _fronts(w, dep / 2, 0.08, h - 0.03, n, rows=False)
    for i in range(n):  # vertical bar handle near each door's inner edge
        x = -w / 2 + w * (i + 0.5) / n + (0.08 if i < n / 2 else -0.08)
        parts.append(_span(x - 0.01, x + 0.01, dep / 2 + 0.012 - EPS, dep / 2 + 0.04, h / 2 - 0.15, h / 2 + 0.15))
    return _union(parts)


# ---- small things ----------------------------------------------------------------------------


def _television(d: _Dims) -> M:
    sw, pt, neck = d.u(0.9, 1.3), d.u(0.04, 0.06), d.u(0.08, 0.12)
    sh = sw * 9 / 16
    z0 = 0.02 + neck
    parts = [
        _span(-sw / 2, sw / 2, -pt / 2, pt / 2, z0, z0 + sh),  # panel, screen towards +Y
        _span(-sw * 0.3, sw * 0.3, -pt / 2 - 0.04, -pt / 2 + EPS, z0 + sh * 0.2, z0 + sh * 0.8),  # back box
        _span(-0.04, 0.04, -pt / 2 - 0.04, -pt / 2 + 0.01, 0.02 - EPS, z0 + 0.05),  # neck
    ]
    if d.pick("plate", "feet") == "plate":
        parts.append(_span(-sw * 0.18, sw * 0.18, -0.11, 0.11, 0, 0.02))
    else:
        for sx in (-1, 1):
            parts.append(_span(sx * sw * 0.4 - 0.03, sx * sw * 0.4 + 0.03, -0.1, 0.1, 0, z0 + 0.05))
    return _union(parts)


def _toy_car(d: _Dims) -> M:
    length, w, h, r = d.u(0.8, 1.1), d.u(0.5, 0.65), d.u(0.45, 0.6), d.u(0.09, 0.13)
    zb = h * 0.55
    parts = [_span(-w / 2 + 0.06, w / 2 - 0.06, -length / 2, length / 2, r * 0.6, zb)]  # body
    for sx in (-1, 1):
        for sy in (-1, 1):
            parts.append(_cyl(r, 0.06, (sx * (w / 2 - 0.03), sy * (length / 2 - r - 0.04), r), axis="x", seg=20))
    yb = -length / 2 + 0.05
    if d.pick("cabin", "open") == "cabin":  # closed cabin over the rear half, hood at +Y
        parts.append(_span(-w / 2 + 0.1, w / 2 - 0.1, yb, yb + length * 0.45, zb - EPS, h))
    else:  # seat back and steering column
        parts.append(_span(-w / 2 + 0.1, w / 2 - 0.1, yb, yb + 0.06, zb - EPS, h))
        parts.append(_cyl(0.02, h - zb, (0, length * 0.1, (h + zb) / 2), seg=12))
    return _union(parts)


def _cushion(d: _Dims) -> M:
    s, t = d.u(0.40, 0.50), d.u(0.12, 0.18)
    if d.pick("square", "round") == "round":
        return M.batch_hull([_cyl(s / 2, t * 0.6, (0, 0, t / 2), seg=48), _cyl(s * 0.3, t, (0, 0, t / 2), seg=48)])
    rc, c = 0.06, s / 2 - 0.06
    corners = [_cyl(rc, t * 0.6, (sx * c, sy * c, t / 2), seg=16) for sx in (-1, 1) for sy in (-1, 1)]
    return M.batch_hull(corners + [_span(-s * 0.3, s * 0.3, -s * 0.3, s * 0.3, 0, t)])


# ---- registry --------------------------------------------------------------------------------


@dataclass(frozen=True)
class Category:
    name: str
    description: str
    build: Callable[[_Dims], M]
    parametric: bool = False
    """True for shapes meant to be sized by the task (`size`): box, obstacle, platform, wall."""


CATEGORIES: dict[str, Category] = {c.name: c for c in (
    Category("box", "carriable box (cuboid)", _box, True),
    Category("obstacle", "block / two steps / ramp to climb", _obstacle, True),
    Category("platform", "slab or stage on a recessed plinth", _platform, True),
    Category("wall", "wall along X, 0.1 m baseboard variant", _wall, True),
    Category("chair", "four-legged chair, seat 0.42-0.48 m", _chair),
    Category("armchair", "upholstered armchair, seat 0.40-0.45 m", _armchair),
    Category("sofa", "upholstered sofa 1.7-2.2 m wide, seat 0.40-0.45 m", _sofa),
    Category("bed", "bed with headboard at -Y, mattress top 0.48-0.55 m", _bed),
    Category("table", "rectangular (0.72-0.76 m) or round pedestal table", _table),
    Category("nightstand", "bedside cabinet with drawers", _nightstand),
    Category("tv_stand", "low TV cabinet with doors", _tv_stand),
    Category("television", "flat screen on a foot plate or two feet", _television),
    Category("toy_car", "ride-on toy car, front +Y", _toy_car),
    Category("wardrobe", "wardrobe 1.9-2.2 m with doors and handles", _wardrobe),
    Category("cushion", "square or round cushion", _cushion),
)}

ALIASES = {"tvstand": "tv_stand", "tv_cabinet": "tv_stand", "television_cabinet": "tv_stand",
           "tv": "television", "car": "toy_car", "toycar": "toy_car", "pillow": "cushion",
           "bedside_table": "nightstand", "stool": "obstacle", "closet": "wardrobe"}


def resolve_category(name: str) -> str:
    """Canonical procedural category for `name` (case, spaces and dashes ignored; aliases)."""
    key = name.strip().lower().replace("-", "_").replace(" ", "_")
    key = ALIASES.get(key, key)
    if key in CATEGORIES:
        return key
    close = difflib.get_close_matches(key, list(CATEGORIES) + list(ALIASES), n=1)
    hint = f" (did you mean '{close[0]}'?)" if close else f" (known: {', '.join(CATEGORIES)})"
    raise AssetError(f"unknown procedural category '{name}'{hint}")


@dataclass(frozen=True)
class ProceduralMesh:
    raw: trimesh.Trimesh
    """3D-FUTURE convention: Y up, front +Z, bbox centred at 0, largest extent 1."""
    scale: float
    """Metres per raw unit (the model's largest extent in metres)."""
    size: tuple[float, float, float]
    """Bbox (x, y, z) in metres in the asset frame (Z up, facing +Y)."""


def build_zup(category: str, variant: int = 0) -> trimesh.Trimesh:
    """The model in metres, Z up, facing +Y, floor at z = 0 (before the 3D-FUTURE conversion).

    `variant` >= 0; variant 0 is the canonical model."""
    name = resolve_category(category)
    mesh = CATEGORIES[name].build(_Dims(name, variant)).to_mesh64()
    return trimesh.Trimesh(np.asarray(mesh.vert_properties)[:, :3], np.asarray(mesh.tri_verts), process=False)


def generate(category: str, variant: int = 0) -> ProceduralMesh:
    """One deterministic model, as a raw mesh in 3D-FUTURE's convention plus its true size."""
    zup = build_zup(category, variant)
    v = np.asarray(zup.vertices) @ Y_UP_TO_Z_UP  # inverse (= transpose) of Y-up -> Z-up
    lo, hi = v.min(axis=0), v.max(axis=0)
    scale = float((hi - lo).max())
    raw = trimesh.Trimesh((v - (lo + hi) / 2) / scale, np.asarray(zup.faces), process=False)
    size = tuple(float(s) for s in zup.extents)
    return ProceduralMesh(raw=raw, scale=scale, size=size)  # type: ignore[arg-type]


@lru_cache(maxsize=1)
def _code_digest() -> bytes:
    return hashlib.sha256(Path(__file__).read_bytes() + version("manifold3d").encode()).digest()


def generator_sha256(category: str, variant: int) -> str:
    """Identity of a procedural source without building it: this module's code + (category,
    variant). Any edit to the generators invalidates the cached procedural assets."""
    return hashlib.sha256(_code_digest() + f"\0{resolve_category(category)}\0{variant}".encode()).hexdigest()
