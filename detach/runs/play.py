"""`detach-run play` and `--video`: a trained policy driving one env, step by step.

`PolicyRollout` builds the run's env (one world, evaluation settings, the run's task or
another) and its policy from a checkpoint; each `step()` advances one control step, and
`task_state()` says what the task markers (`detach.eval.task_markers`: path, targets,
subtask and time, the verdict at the end) are drawn from. `record_video` renders episodes
offscreen to an mp4 with those markers (`detach.runs.video`), holding each episode's last
frame with its verdict for a second; the live viewer (`server.play_view`) draws the same
frames and markers in viser.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Iterator

from detach.eval.task_markers import Marker, TaskState, task_markers
from detach.runfolder.folder import RunFolder
from detach.runs.video import FollowRenderer, VideoWriter, choose_gl


class PolicyRollout:
    """A run's deterministic policy in one env of its task (or `task_path`)."""

    def __init__(self, run: RunFolder, checkpoint: Path | None = None, task_path: Path | None = None,
                 device: str = "cpu") -> None:
        import torch

        from detach.envs.lh_env import make_env
        from detach.eval.scene import scene_message
        from detach.runs.policy import load_policy
        from detach.runs.session import eval_config
        from detach.train.checkpoints import CheckpointError, run_policy_checkpoint
        from detach.train.setup import apply_torch_threads, prepare_assets, seed_everything

        self.run = run
        self.cfg = eval_config(run.config(), task_path)
        self.checkpoint = checkpoint or run_policy_checkpoint(run.path, device)
        if self.checkpoint is None:
            raise CheckpointError("no readable checkpoint to play", str(run.checkpoints))
        prepare_assets(self.cfg.task)
        apply_torch_threads(self.cfg)
        seed_everything(self.cfg.seed + 1)
        self.env = make_env(self.cfg, num_envs=1, device=device, eval_mode=True)
        self.actor, _state = load_policy(self.cfg, self.env, self.checkpoint, device)
        self.scene = scene_message(self.env, self.cfg)
        self.dt = float(self.env.dt)
        self.obs = self.env.get_observations()
        self.episode, self.frame = 0, 0
        self.last_outcome: tuple[bool, tuple[float, ...]] | None = None
        """(success, each subtask's score) of the episode that ended last."""
        self._torch = torch

    def step(self) -> bool:
        """One control step of the policy; True when an episode ended (the env resets itself)."""
        from detach.eval.episodes import trial_outcome

        with self._torch.inference_mode():
            self.obs, _rew, dones, extras = self.env.step(self.actor(self.obs))
        done = bool(dones[0])
        if done:
            progress = extras.get("episode_progress")
            if progress is not None:
                outcome = trial_outcome(progress, 0, self.dt)
                self.last_outcome = (outcome.completed, tuple(outcome.scores))
            self.episode, self.frame = self.episode + 1, 0
        else:
            self.frame += 1
        return done

    def task_state(self) -> TaskState:
        """What the task markers of the current frame are drawn from."""
        snap = self.snapshot()
        return TaskState(self.frame * self.dt, snap.subtask, snap.skill, snap.body_pos[0], snap.target, snap.path,
                         snap.path_index)

    def markers(self, state: TaskState | None = None) -> list[Marker]:
        """The task markers of `state` (default: the current frame)."""
        return task_markers(self.scene.targets, state if state is not None else self.task_state())

    def verdict(self, state: TaskState) -> TaskState:
        """`state` (the ended episode's last frame) with the episode's outcome."""
        if self.last_outcome is None:
            return state
        ok, scores = self.last_outcome
        return dataclasses.replace(state, outcome="success" if ok else "failure", scores=scores)

    def snapshot(self):
        """Bodies, objects and current subtask of the env (`detach.envs.views.EnvSnapshot`)."""
        return self.env.snapshot(0)

    def data(self):
        """The world's MjData (for rendering)."""
        return self.env.backend.get_data(0)

    def steps(self, episodes: int | None = None, steps: int | None = None) -> Iterator[int]:
        """Step until `episodes` episodes ended or `steps` steps (None: no limit); yields
        the step count before each step."""
        n = 0
        while (episodes is None or self.episode < episodes) and (steps is None or n < steps):
            yield n
            self.step()
            n += 1


VERDICT_HOLD_S = 1.0
"""How long the video holds an episode's last frame with its success or failure mark."""


def record_video(rollout: PolicyRollout, path: Path, episodes: int | None = 1, steps: int | None = None,
                 size: tuple[int, int] = (640, 480), markers: bool = True) -> int:
    """Render the rollout's episodes (camera tracking the character's root) to an mp4 at the
    control rate, with the task markers unless `markers` is False; each episode's end is its
    last frame held `VERDICT_HOLD_S` with the verdict. Returns the number of frames written."""
    width, height = size
    root = int(rollout.env.scene.body_ids[0])
    renderer = FollowRenderer(rollout.env.model, width, height, root)
    hold = max(1, round(VERDICT_HOLD_S / rollout.dt))
    try:
        with VideoWriter(path, 1.0 / rollout.dt, width, height) as video:
            ended, n = False, 0
            while (episodes is None or rollout.episode < episodes) and (steps is None or n < steps):
                state = rollout.task_state() if markers else None
                video.add(renderer.render(rollout.data(), rollout.markers(state) if state else ()))
                ended = rollout.step()
                n += 1
                if ended:
                    last = renderer.render_again(rollout.markers(rollout.verdict(state)) if state else ())
                    for _ in range(hold):
                        video.add(last)
            if not ended:
                state = rollout.task_state() if markers else None
                video.add(renderer.render(rollout.data(), rollout.markers(state) if state else ()))
            return video.frames
    finally:
        renderer.close()


def play_video(run: RunFolder, checkpoint: Path | None, task_path: Path | None, video: Path,
               device: str = "cpu", episodes: int | None = None, steps: int | None = None,
               size: tuple[int, int] = (640, 480)) -> int:
    """`--video`: choose an OpenGL platform first (before mujoco is imported), then record."""
    choose_gl()
    rollout = PolicyRollout(run, checkpoint, task_path, device)
    frames = record_video(rollout, video, episodes=1 if episodes is None and steps is None else episodes,
                          steps=steps, size=size)
    print(f"video written to {video} ({frames} frames, {frames * rollout.dt:.1f} s)", flush=True)
    return frames
