"""Defaults and choices of the asset pipeline, importable without numpy or trimesh.

`detach-scene --help` must start in well under a second, so the command line reads its
defaults from here instead of from the modules that use them (which import numpy, trimesh
and manifold3d). Each value is explained where it is used.
"""

from __future__ import annotations

RESOLUTION = 128
"""Height-map cells per side (heightmap.py)."""
ENGINES = ("embree", "numpy")
"""Height-map ray casters (heightmap.py)."""
GRIDS = ("centres", "linspace")
"""Height-map grid conventions: ours (cell centres) and TokenHSI's (heightmap.py)."""
MAX_FACES = 100_000
"""Face cap of the processed mesh (decimate.py)."""
HULL_FACES = 20_000
"""Face cap of CoACD's input (decimate.py, hulls.py)."""
TIME_BUDGET = 120.0
"""Seconds of CoACD per asset, all tries together (hulls.py)."""
UP_CHOICES = ("y", "z", "auto")
"""--up: 3D-FUTURE's Y up, Z up, or chosen from the geometry (orientation.py)."""
