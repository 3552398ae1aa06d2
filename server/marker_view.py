"""The task markers (`detach.eval.task_markers`) as viser primitives: the dashboard's replay and
`detach-run play`'s live viewer draw the same markers as the video and Foxglove.

`MarkerView.show(markers)` keeps one scene node per marker name under a prefix: a marker seen
before is updated in place (positions, line points, label text), one whose look changed is
drawn again, and one no longer in the list is removed, so a replay frame sends only what moved.
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from detach import Disc, Marker, Polyline, Sphere, Text
from server.scene_geometry import node_name


def _segments(points: np.ndarray) -> np.ndarray:
    pts = np.asarray(points, dtype=np.float32)
    return np.stack([pts[:-1], pts[1:]], axis=1)


def _colors(color: Sequence[int], n: int) -> np.ndarray:
    return np.broadcast_to(np.asarray(color[:3], dtype=np.uint8), (n, 2, 3)).copy()


class MarkerView:
    """The markers of the shown frame under the scene node `prefix` (e.g. `/a/task`)."""

    def __init__(self, scene_api: Any, prefix: str) -> None:
        self.scene, self.prefix = scene_api, prefix
        self._nodes: dict[str, tuple[tuple, Any]] = {}
        """marker name -> (its look: what cannot be updated in place, the viser handle)."""

    def show(self, markers: Sequence[Marker]) -> None:
        """Draw these markers (call inside the client's `atomic()`); others are removed."""
        seen = set()
        for m in markers:
            seen.add(m.name)
            look = self._look(m)
            old = self._nodes.get(m.name)
            if old is not None and old[0] != look:
                self._remove(m.name)
                old = None
            if old is None:
                handle = self._add(m)
                if handle is not None:
                    self._nodes[m.name] = (look, handle)
            else:
                self._update(m, old[1])
        for name in [n for n in self._nodes if n not in seen]:
            self._remove(name)

    def clear(self) -> None:
        for name in list(self._nodes):
            self._remove(name)

    @property
    def names(self) -> list[str]:
        return sorted(self._nodes)

    def _node(self, m: Marker) -> str:
        return f"{self.prefix}/{node_name(m.name.replace('/', '_'))}"

    @staticmethod
    def _look(m: Marker) -> tuple:
        if isinstance(m, Polyline):
            return ("line", m.width)
        if isinstance(m, Sphere):
            return ("sphere", m.radius, m.color, m.opacity)
        if isinstance(m, Disc):
            return ("disc", m.radius, m.color, m.opacity)
        return ("text", m.color)

    def _add(self, m: Marker) -> Any | None:
        node = self._node(m)
        if isinstance(m, Polyline):
            if len(m.points) < 2:
                return None
            segs = _segments(m.points)
            return self.scene.add_line_segments(node, segs, _colors(m.color, len(segs)), thickness=m.width)
        if isinstance(m, Sphere):
            return self.scene.add_icosphere(node, radius=m.radius, color=m.color, subdivisions=2,
                                            opacity=None if m.opacity >= 1.0 else m.opacity,
                                            position=tuple(float(v) for v in m.pos))
        if isinstance(m, Disc):
            return self.scene.add_cylinder(node, radius=m.radius, height=0.01, color=m.color, opacity=m.opacity,
                                           position=(float(m.pos[0]), float(m.pos[1]), 0.015), cast_shadow=False)
        if isinstance(m, Text):
            return self.scene.add_label(node, m.text, position=tuple(float(v) for v in m.pos),
                                        anchor="bottom-center")
        return None

    def _update(self, m: Marker, handle: Any) -> None:
        if isinstance(m, Polyline):
            segs = _segments(m.points)
            if handle.points.shape != segs.shape or not np.array_equal(handle.points, segs):
                handle.points = segs
                handle.colors = _colors(m.color, len(segs))
        elif isinstance(m, Disc):
            handle.position = (float(m.pos[0]), float(m.pos[1]), 0.015)
        elif isinstance(m, (Sphere, Text)):
            pos = tuple(float(v) for v in m.pos)
            if tuple(handle.position) != pos:
                handle.position = pos
            if isinstance(m, Text) and handle.text != m.text:
                handle.text = m.text

    def _remove(self, name: str) -> None:
        _look, handle = self._nodes.pop(name)
        try:
            handle.remove()
        except Exception:  # noqa: BLE001 - already gone with its parent
            pass
