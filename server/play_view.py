"""`detach-run play RUN_DIR`: a trained policy live in the viser viewer.

`play_live` is the `live` entry point of the group `detach.viewers` (pyproject.toml), through
which `detach.runs.actions.play` finds it: the runs package sits below the dashboard and never
imports it.

The scene is drawn once with the dashboard's own drawing code (`server.scene_view.RunScene`,
the /scene message of the rollout's env); every control step poses the character and the
dynamic objects and draws the task markers (`detach.eval.task_markers`, as in the video and
the replay; an episode's end holds its verdict for `VERDICT_HOLD_S`), paced at the control
rate, and every connected browser's camera follows the character (keeping the distance and
angle the user chose).
"""

from __future__ import annotations

import time
import numpy as np

from detach import PolicyRollout, TaskState, VERDICT_HOLD_S
from server.episode import Episode
from server.markup import md_text
from server.scene_view import RunScene


def snapshot_episode(rollout: PolicyRollout) -> Episode:
    """The env's current state as a one-frame `Episode` (what `RunScene.set_frame` draws)."""
    snap = rollout.snapshot()
    objects = {o["name"]: (np.asarray([o["pos"]], dtype=float), np.asarray([o["quat"]], dtype=float))
               for o in snap.objects}
    return Episode(rollout.episode, list(snap.bodies), np.array([rollout.frame * rollout.dt]),
                   np.asarray(snap.body_pos, dtype=float)[None], np.asarray(snap.body_quat, dtype=float)[None],
                   np.array([snap.subtask]), [snap.skill], objects,
                   task=[TaskState(rollout.frame * rollout.dt, snap.subtask, snap.skill, snap.body_pos[0], snap.target,
                                   snap.path, snap.path_index)])


def follow_camera(server, point: np.ndarray, distance: float = 4.0) -> None:
    """Every client's camera looks at the character, at the offset it had (or a default)."""
    look = np.array([point[0], point[1], 0.9])
    for client in server.get_clients().values():
        camera = client.camera
        offset = np.asarray(camera.position, dtype=float) - np.asarray(camera.look_at, dtype=float)
        if not np.isfinite(offset).all() or np.linalg.norm(offset) < 1e-3 or \
                np.linalg.norm(offset) > 50 * distance:
            offset = distance * np.array([0.55, -0.75, 0.45])
        with client.atomic():
            camera.look_at = tuple(float(v) for v in look)
            camera.position = tuple(float(v) for v in look + offset)


def play_live(rollout: PolicyRollout, host: str = "127.0.0.1", port: int = 8081, episodes: int | None = None,
              steps: int | None = None, realtime: bool = True, server=None) -> int:
    """Serve the viewer and run the policy until `episodes`/`steps` (None: until Ctrl-C);
    returns the number of control steps played. `server`: an existing ViserServer (tests)."""
    import viser

    own = server is None
    if own:
        server = viser.ViserServer(host=host, port=port, verbose=False)
        print(f"viewer: http://{host}:{server.get_port()} (Ctrl-C stops)", flush=True)
    scene = RunScene(server.scene, server.atomic, "play")
    for note in scene.show(rollout.scene, np.zeros(3)):
        print(f"note: {note}", flush=True)
    status = server.gui.add_markdown("")
    played, shown_episode, last = 0, rollout.episode, None

    def verdict() -> None:
        """The ended episode's last frame again, with its success or failure mark."""
        nonlocal next_time
        if last is None:
            return
        scene.set_markers(rollout.markers(rollout.verdict(last)))
        if realtime:
            time.sleep(VERDICT_HOLD_S)
            next_time = time.monotonic()

    try:
        next_time = time.monotonic()
        for _ in rollout.steps(episodes, steps):
            if rollout.episode != shown_episode:
                verdict()
                shown_episode = rollout.episode
            episode = snapshot_episode(rollout)
            last = episode.task[0]
            root = scene.set_frame(episode, 0)
            scene.set_markers(rollout.markers(last))
            follow_camera(server, root)
            if rollout.frame % 15 == 0:
                status.content = (f"**{md_text(rollout.run.path.name)}** · episode {rollout.episode} · "
                                  f"{rollout.frame * rollout.dt:.1f} s · {md_text(episode.skill[0])}")
            if realtime:
                next_time += rollout.dt
                time.sleep(max(0.0, next_time - time.monotonic()))
            played += 1
        if rollout.episode != shown_episode:
            verdict()
    finally:
        if own:
            server.stop()
    return played

