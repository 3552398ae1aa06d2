"""The Replay tab: a run's scene and a recorded episode in 3D, optionally a second run beside
it on the same clock; play, pause, step, loop, speed, a frame scrubber, a camera that follows
the character, the path it actually walked drawn beside the planned one, and each frame's task
markers (`detach.eval.task_markers`: Follow path done and ahead, targets, subtask and time,
the verdict on the closing frame).

Switching to a run without episodes clears the character, its label, its trail and the
frame controls: nothing of the previous run's episode stays on screen.
"""

from __future__ import annotations

import math
import threading
from typing import Any

import viser

from detach.runfolder.log_tail import EpisodeKey
from server.episode import Episode, load_episode
from server.markup import md_text
from server.replay import Replay
from server.scene_view import SceneView, check_episode
from server.session import Panel, Session, chosen, is_quiet, quietly

NEWEST = "newest"
NONE = "(none)"
NO_RUNS = "(no runs)"


def _describe(ep: Episode | None) -> str:
    if ep is None:
        return "no episode recorded in this run's log"
    trial = " (training)" if ep.trial < 0 else f", trial {ep.trial}" if ep.trial else ""
    return (f"episode {ep.number}{trial}: {ep.num_frames} frames, "
            f"{ep.times[-1] - ep.times[0]:.1f} s")


def episode_options(keys: list[EpisodeKey]) -> dict[str, EpisodeKey]:
    """Dropdown text -> (episode, trial): '300' for an episode recorded once, '300 · trial 4'
    for the trials of one evaluation (each trial is an episode of its own), '300 · training'
    for the training episode recorded after checkpoint 300."""
    trials: dict[int, int] = {}
    for episode, trial in keys:
        if trial >= 0:
            trials[episode] = trials.get(episode, 0) + 1
    return {(f"{e} · training" if t < 0 else f"{e} · trial {t}" if trials[e] > 1 or t
             else str(e)): (e, t) for e, t in keys}


def replay_panel(s: Session) -> Panel:
    gui = s.gui
    quiet = threading.local()
    view = SceneView(s.client)
    run_dd = gui.add_dropdown("Run", (NO_RUNS,))
    episode_dd = gui.add_dropdown("Episode", (NONE,),
                                  hint="'newest' follows a live run's newest episode")
    compare_dd = gui.add_dropdown("Beside it", (NONE,), hint="a second run in the same scene, "
                                  "its newest episode on the same clock")
    info = gui.add_markdown("")
    play = gui.add_button("Pause", icon=viser.Icon.PLAYER_PAUSE)
    step = gui.add_button_group("Step", ("◀ frame", "frame ▶"))
    loop = gui.add_checkbox("Loop", True, hint="off: stop at the last frame")
    speed = gui.add_slider("Speed", min=0.1, max=4.0, step=0.1, initial_value=1.0)
    scrub = gui.add_slider("Frame", min=0, max=1, step=1, initial_value=0, disabled=True)
    follow = gui.add_checkbox("Camera follows", False, hint="keep the character in the middle "
                              "of the view")
    trail = gui.add_checkbox("Walked path", True, hint="the path the character walked (orange) "
                             "beside the planned one (blue)")
    status = gui.add_markdown("")
    shown: dict[str, Any] = {"a": None, "b": None, "log": {}, "scene": {}, "episode": None,
                             "problem": None, "ids": (), "keys": {}}

    def draw(slot: str, ep: Episode, i: int) -> None:
        scene = view.a if slot == "a" else view.b
        skill = ep.skill[i]
        prefix = "B · " if slot == "b" else ""
        markers = scene.frame_markers(ep, i, prefix)  # their caption names the subtask and time
        text = "" if markers else (prefix + f"subtask {ep.subtask[i]}: {skill}") if skill else ""
        root = scene.set_frame(ep, i, text)
        scene.set_markers(markers)
        if slot == "a" and follow.value:
            view.follow(root)

    def on_frame(ep: Episode, i: int) -> None:
        quietly(quiet, scrub, max=max(ep.num_frames - 1, 1), value=i, disabled=False)
        skill = ep.skill[i]
        status.content = (f"**t = {ep.times[i] - ep.times[0]:.2f} s** of "
                          f"{ep.times[-1] - ep.times[0]:.2f} s, frame {i + 1}/{ep.num_frames}"
                          + (f"  \ncurrent subtask **{ep.subtask[i]}: {md_text(skill)}**" if skill else ""))

    replay = Replay(draw, on_frame)
    s.dashboard.ticker.add(replay)

    def chosen_episode(run: str, choice: str | None) -> Episode | None:
        reader = s.index.reader(run)
        shown["problem"] = None
        if reader is None:
            return None
        if choice == NONE:
            return None  # the log has no episode
        try:
            ep = load_episode(reader.log, shown["keys"].get(choice))  # None: the newest
            if ep is not None:
                check_episode(ep)
            return ep
        except Exception as exc:  # noqa: BLE001 - malformed frames: say so, keep serving
            shown["problem"] = f"episode frames unreadable ({exc!r:.160})"
            return None

    def clear_frame_controls() -> None:
        quietly(quiet, scrub, value=0, max=1, disabled=True)
        status.content = "*no episode to replay*"

    def open_episode(slot: str, keep_time: bool = False) -> None:
        run = shown[slot]
        choice = chosen(episode_dd, episode_dd_options(), NEWEST) if slot == "a" else NEWEST
        ep = chosen_episode(run, choice) if run is not None else None
        scene = view.a if slot == "a" else view.b
        live = bool(run in s.infos and s.infos[run].live)
        if slot == "a":
            replay.player.hold_at_end = live and choice == NEWEST
            shown["episode"] = None if ep is None else (ep.number, ep.trial)
        if ep is None:
            scene.hide_character()
            replay.set_episode(slot, None)
            if slot == "a":
                clear_frame_controls()
        else:
            scene.set_trail(ep if trail.value else None)
            replay.set_episode(slot, ep, keep_time)
        if slot == "a":
            describe(ep)

    def list_episodes(log: Any) -> tuple[str, ...]:
        """The Episode dropdown's options for a log (and the keys they stand for)."""
        shown["keys"] = episode_options(log.episode_keys())
        return (NEWEST, *shown["keys"]) if shown["keys"] else (NONE,)

    def episode_dd_options() -> tuple[str, ...]:
        return tuple(episode_dd.options)

    def describe(ep: Episode | None) -> None:
        run = shown["a"]
        r = s.infos.get(run) if run else None
        lines = [f"**{md_text(run)}**" + (f" ({r.state})" if r else ""), _describe(ep)]
        notes = [*view.a.notes, shown["problem"]]
        if shown["b"]:
            lines.append(f"beside it (B): **{md_text(shown['b'])}**")
        text = "\n\n".join(lines) + ("\n\n" + "\n".join(f"- {md_text(n)}" for n in notes if n)
                                     if any(notes) else "")
        if info.content != text:
            info.content = text

    def open_run(slot: str, run: str | None) -> None:
        """Draw run `run` in `slot` (None removes slot B) and its newest/chosen episode."""
        with replay.lock:
            shown[slot] = run
            reader = s.index.reader(run) if run else None
            if reader is None:
                replay.set_episode(slot, None)
                view.remove(slot)
                if slot == "a":
                    clear_frame_controls()
                    describe(None)
                return
            log = reader.log
            shown["log"][slot] = s.infos[run].log_version if run in s.infos else ()
            shown["scene"][slot] = log.scene
            view.show(slot, log.scene)
            if slot == "a":
                quietly(quiet, episode_dd, options=(options := list_episodes(log)),
                        value=options[0])
            open_episode(slot)

    @run_dd.on_update
    def _(_event: object) -> None:
        if is_quiet(quiet):
            return
        with s.lock:
            run = chosen(run_dd, list(s.infos))
            if run is not None and run != shown["a"]:
                open_run("a", run)

    @compare_dd.on_update
    def _(_event: object) -> None:
        if is_quiet(quiet):
            return
        with s.lock:
            run = chosen(compare_dd, list(s.infos))
            if run != shown["b"]:
                open_run("b", run)
                describe(replay.episode)

    @episode_dd.on_update
    def _(_event: object) -> None:
        if not is_quiet(quiet) and shown["a"] is not None:
            with s.lock, replay.lock:
                if chosen(episode_dd, episode_dd_options()) is not None:
                    open_episode("a")

    @play.on_click
    def _(_event: object) -> None:
        with replay.lock:
            player = replay.player
            player.playing = not player.playing
            play.label = "Pause" if player.playing else "Play"
            play.icon = viser.Icon.PLAYER_PAUSE if player.playing else viser.Icon.PLAYER_PLAY

    @step.on_click
    def _(event: viser.GuiEvent) -> None:
        with replay.lock:
            replay.player.step(-1 if event.target.value.startswith("◀") else 1)
            play.label, play.icon = "Play", viser.Icon.PLAYER_PLAY
            replay.redraw()

    @loop.on_update
    def _(_event: object) -> None:
        replay.player.loop = bool(loop.value)

    @speed.on_update
    def _(_event: object) -> None:
        if math.isfinite(speed.value):  # a client can send any number, NaN included
            replay.player.speed = float(min(max(speed.value, 0.1), 4.0))

    @scrub.on_update
    def _(_event: object) -> None:
        if is_quiet(quiet) or not math.isfinite(scrub.value):
            return  # our own update from the replay thread, or not a frame
        with replay.lock:
            replay.player.seek(int(scrub.value))
            replay.redraw()

    @trail.on_update
    def _(_event: object) -> None:
        with replay.lock:
            for slot, scene in (("a", view.a), ("b", view.b)):
                ep = replay.episodes.get(slot)
                scene.set_trail(ep if trail.value and ep is not None else None)

    def update_options() -> None:
        ids = tuple(s.infos)
        if ids == shown["ids"]:
            return
        shown["ids"] = ids
        quietly(quiet, run_dd, options=ids or (NO_RUNS,))
        quietly(quiet, compare_dd, options=(NONE, *ids))
        if shown["b"] is not None and shown["b"] not in s.infos:
            quietly(quiet, compare_dd, value=NONE)
            open_run("b", None)

    def follow_log(slot: str) -> None:
        """A shown run's log grew: a new scene redraws it; new frames stream the newest
        episode (the same episode keeps playing from where it was)."""
        run = shown[slot]
        info = s.infos.get(run) if run else None
        if info is None or info.log_version == shown["log"].get(slot):
            return
        shown["log"][slot] = info.log_version
        reader = s.index.reader(run)
        if reader is None:
            return
        log = reader.log
        if log.scene != shown["scene"].get(slot):
            open_run(slot, run)  # the scene arrived (or an evaluation logged another one)
            return
        if slot == "a":
            options = list_episodes(log)
            if tuple(episode_dd.options) != options:
                value = episode_dd.value if episode_dd.value in options else options[0]
                quietly(quiet, episode_dd, options=options, value=value)
        choice = chosen(episode_dd, episode_dd_options(), NEWEST) if slot == "a" else NEWEST
        if choice == NEWEST:
            with replay.lock:
                current = replay.episodes.get(slot)
                open_episode(slot, keep_time=current is not None
                             and log.newest_episode() == (current.number, current.trial))

    def refresh(changed: set[str]) -> None:
        update_options()
        if shown["a"] not in s.infos:
            candidates = [r for r in s.selected if r in s.infos] or \
                [i.run_id for i in s.infos.values() if i.has_log] or list(s.infos)
            if candidates:
                quietly(quiet, run_dd, value=candidates[-1])
                open_run("a", candidates[-1])
            elif shown["a"] is not None:
                open_run("a", None)
            return
        for slot in ("a", "b"):
            if shown[slot] in changed:
                follow_log(slot)

    def close() -> None:
        s.dashboard.ticker.discard(replay)

    s.replay = replay  # tests and benchmarks reach the replay of a session through it
    return Panel(refresh=refresh, open_runs=lambda: {r for r in (shown["a"], shown["b"]) if r},
                 close=close)
