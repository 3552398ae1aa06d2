"""`detach-run play` and `--video`: a trained policy driving one env, step by step.

`PolicyRollout` builds the run's env (one world, evaluation settings, the run's task or
another) and its policy from a checkpoint; each `step()` advances one control step and
returns the frame to draw. `record_video` renders episodes offscreen to an mp4
(`detach.runs.video`); the live viewer (`server.play_view`) draws the same frames in viser.
"""

from __future__ import annotations

from pathlib import Path
from typing import Iterator

from detach.runs.folder import RunFolder
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
        from detach.train.checkpoints import CheckpointError
        from detach.train.setup import apply_torch_threads, prepare_assets, seed_everything

        self.run = run
        self.cfg = eval_config(run.config(), task_path)
        self.checkpoint = checkpoint or run.policy_checkpoint(device)
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
        self._torch = torch

    def step(self) -> bool:
        """One control step of the policy; True when an episode ended (the env resets itself)."""
        with self._torch.inference_mode():
            self.obs, _rew, dones, _extras = self.env.step(self.actor(self.obs))
        done = bool(dones[0])
        if done:
            self.episode, self.frame = self.episode + 1, 0
        else:
            self.frame += 1
        return done

    def snapshot(self):
        """Bodies, objects and current subtask of the env (`detach.envs.lh_env.EnvSnapshot`)."""
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


def record_video(rollout: PolicyRollout, path: Path, episodes: int = 1, steps: int | None = None,
                 size: tuple[int, int] = (640, 480)) -> int:
    """Render the rollout's episodes (camera tracking the character's root) to an mp4 at the
    control rate; returns the number of frames written."""
    width, height = size
    root = int(rollout.env.scene.body_ids[0])
    renderer = FollowRenderer(rollout.env.model, width, height, root)
    try:
        with VideoWriter(path, 1.0 / rollout.dt, width, height) as video:
            for _ in rollout.steps(episodes, steps):
                video.add(renderer.render(rollout.data()))
            video.add(renderer.render(rollout.data()))
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
