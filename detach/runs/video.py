"""Offscreen rendering of a running env to an mp4: MuJoCo's `Renderer` on EGL or OSMesa,
frames encoded with PyAV (H.264 in an mp4 container).

MuJoCo picks its OpenGL platform once, when `mujoco` is first imported, from `MUJOCO_GL`.
`choose_gl` must therefore run before anything imports mujoco: it keeps a `MUJOCO_GL` the user
set, else tries `egl` then `osmesa`, each in a short child process, and sets the first that
can create a context. This module imports only the standard library at load time.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from typing import Any, Sequence

GL_BACKENDS = ("egl", "osmesa")
"""Headless OpenGL platforms of MuJoCo, in the order tried."""

_PROBE = "import mujoco; c = mujoco.GLContext(16, 16); c.make_current(); c.free()"


class VideoError(RuntimeError):
    """No headless OpenGL, or no encoder: a one-line user error."""


def gl_works(backend: str, timeout_s: float = 120.0) -> bool:
    """Whether MuJoCo can create an offscreen context with MUJOCO_GL=`backend` (child process)."""
    env = {**os.environ, "MUJOCO_GL": backend}
    env.pop("PYOPENGL_PLATFORM", None)
    try:
        return subprocess.run([sys.executable, "-c", _PROBE], env=env, capture_output=True,
                              timeout=timeout_s).returncode == 0
    except (OSError, subprocess.TimeoutExpired):
        return False


def choose_gl(candidates: Sequence[str] = GL_BACKENDS) -> str:
    """The OpenGL platform for offscreen rendering, set in MUJOCO_GL; VideoError when none
    works, or when mujoco was already imported with another (or no) headless platform."""
    chosen = os.environ.get("MUJOCO_GL", "").strip().lower()
    if not chosen:
        if "mujoco" in sys.modules:
            raise VideoError("mujoco was imported before an OpenGL platform was chosen; "
                             "set MUJOCO_GL=egl (or osmesa)")
        chosen = next((gl for gl in candidates if gl_works(gl)), "")
        if not chosen:
            raise VideoError(f"no headless OpenGL for MuJoCo: tried MUJOCO_GL={' and '.join(candidates)} "
                             "(install libegl1 and libegl-mesa0, or libosmesa6)")
        os.environ["MUJOCO_GL"] = chosen
    return chosen


class VideoWriter:
    """mp4 (H.264, yuv420p) through PyAV; frames are [H, W, 3] uint8 RGB."""

    def __init__(self, path: Path, fps: float, width: int, height: int) -> None:
        try:
            import av
        except ImportError:
            raise VideoError("--video needs PyAV: pip install 'detach[video]'") from None
        from fractions import Fraction

        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._container = av.open(str(self.path), mode="w")
        self._stream = self._container.add_stream("libx264", rate=Fraction(fps).limit_denominator(1000))
        self._stream.width, self._stream.height = width - width % 2, height - height % 2
        self._stream.pix_fmt = "yuv420p"
        self.frames = 0

    def add(self, rgb: Any) -> None:
        import av

        frame = av.VideoFrame.from_ndarray(rgb[: self._stream.height, : self._stream.width], format="rgb24")
        for packet in self._stream.encode(frame):
            self._container.mux(packet)
        self.frames += 1

    def close(self) -> None:
        for packet in self._stream.encode():
            self._container.mux(packet)
        self._container.close()

    def __enter__(self) -> "VideoWriter":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class FollowRenderer:
    """MuJoCo's offscreen Renderer with a tracking camera on a body (the character's root):
    the camera keeps its distance and angles and looks at the body."""

    def __init__(self, model: Any, width: int, height: int, body: int, distance: float = 4.0,
                 azimuth: float = 135.0, elevation: float = -20.0) -> None:
        import mujoco

        model.vis.global_.offwidth = max(int(model.vis.global_.offwidth), width)
        model.vis.global_.offheight = max(int(model.vis.global_.offheight), height)
        self.renderer = mujoco.Renderer(model, height=height, width=width)
        self.camera = mujoco.MjvCamera()
        self.camera.type = mujoco.mjtCamera.mjCAMERA_TRACKING
        self.camera.trackbodyid = int(body)
        self.camera.distance, self.camera.azimuth, self.camera.elevation = distance, azimuth, elevation
        self._scene_geoms = 0

    def render(self, data: Any, markers: Sequence[Any] = ()) -> Any:
        """One RGB frame of `data`, with the task markers (`detach.eval.task_markers`) drawn
        into the scene and their text as a caption."""
        self.renderer.update_scene(data, camera=self.camera)
        self._scene_geoms = self.renderer.scene.ngeom
        return self.render_again(markers)

    def render_again(self, markers: Sequence[Any] = ()) -> Any:
        """The last rendered state again with other markers (the verdict at an episode's end,
        after the env has already reset)."""
        from detach.runs.marker_render import add_marker_geoms, draw_captions

        self.renderer.scene.ngeom = self._scene_geoms
        add_marker_geoms(self.renderer.scene, markers)
        return draw_captions(self.renderer.render(), markers)

    def close(self) -> None:
        self.renderer.close()
