"""A thin subclass of rsl-rl-lib's OnPolicyRunner: stages, progress bar, run-folder output.

It keeps rsl-rl's algorithm construction, save and load, and replaces only `learn`, to add
what a run of this platform needs: the training stage of each iteration (DETACH's protocol),
a tqdm bar with iteration / FPS / reward / success rates, one `/metrics` MCAP message per
iteration, checkpoints `model_<iter>.pt` into the run folder, and a clean stop on SIGTERM or
Ctrl-C (checkpoint first). A checkpoint's `iter` is the last *completed* iteration; resuming
continues at `iter + 1` with the optimiser state restored.
"""

from __future__ import annotations

import signal
import statistics
import time
from collections import deque
from pathlib import Path
from typing import Callable, Protocol

import torch
from rsl_rl.runners import OnPolicyRunner
from tqdm import tqdm

from detach.run_contract import checkpoint_file
from detach.train.schedule import stage_at

StageHook = Callable[[str], None]
IterationHook = Callable[[int, dict[str, float]], None]


class MetricsSink(Protocol):
    """Where the metrics of every iteration go (the run's log.mcap in a run folder)."""

    def log_metrics(self, iteration: int, metrics: dict[str, float], stage: str = "") -> None: ...


class StopRequested(Exception):
    """Raised inside the loop after SIGTERM/SIGINT once the checkpoint is written."""


class DetachRunner(OnPolicyRunner):
    def __init__(self, env, train_cfg: dict, device: str = "cpu",
                 schedule: list[tuple[str, int]] | None = None,
                 checkpoint_dir: Path | None = None, log: MetricsSink | None = None,
                 on_stage: StageHook | None = None, on_iteration: IterationHook | None = None,
                 progress: bool = True) -> None:
        train_cfg = {**train_cfg, "logger": {"class_name": "detach.train.null_writer:NullWriter"}}
        super().__init__(env, train_cfg, log_dir=None, device=device)
        self.schedule = schedule or [("ppo", 1)]
        self.checkpoint_dir = checkpoint_dir
        self.log = log
        self.on_stage = on_stage
        self.on_iteration = on_iteration
        self.progress = progress
        self.completed_iteration = -1
        self._stop_signal: int | None = None

    # ------------------------------------------------------------------ checkpoints
    def checkpoint_path(self, iteration: int) -> Path | None:
        if self.checkpoint_dir is None:
            return None
        return self.checkpoint_dir / checkpoint_file(iteration)

    def save_checkpoint(self) -> Path | None:
        path = self.checkpoint_path(self.completed_iteration)
        if path is None or self.completed_iteration < 0:
            return None
        self.current_learning_iteration = self.completed_iteration
        tmp = path.with_suffix(".pt.tmp")
        self.save(str(tmp), infos={"stage": stage_at(self.schedule, self.completed_iteration)})
        tmp.replace(path)
        return path

    def load_checkpoint(self, path: Path) -> int:
        """Restore models, optimisers and iteration; returns the next iteration to run."""
        self.load(str(path), map_location=self.device)
        self.completed_iteration = self.current_learning_iteration
        return self.completed_iteration + 1

    # ------------------------------------------------------------------ loop
    def _request_stop(self, signum: int, _frame: object) -> None:
        self._stop_signal = signum

    def learn(self, num_learning_iterations: int, init_at_random_ep_len: bool = False) -> None:
        """Run iterations completed_iteration+1 .. num_learning_iterations-1 (absolute)."""
        start = self.completed_iteration + 1
        if init_at_random_ep_len and start == 0:
            self.env.episode_length_buf = torch.randint_like(
                self.env.episode_length_buf, high=int(self.env.max_episode_length))
        previous = {sig: signal.signal(sig, self._request_stop)
                    for sig in (signal.SIGTERM, signal.SIGINT)}
        try:
            self._loop(start, num_learning_iterations)
        finally:
            for sig, handler in previous.items():
                signal.signal(sig, handler)

    def _loop(self, start: int, end: int) -> None:
        obs = self.env.get_observations().to(self.device)
        self.alg.train_mode()
        rewards_buf: deque[float] = deque(maxlen=200)
        lengths_buf: deque[float] = deque(maxlen=200)
        reward_sum = torch.zeros(self.env.num_envs, device=self.device)
        length = torch.zeros(self.env.num_envs, device=self.device)
        stage = None
        bar = tqdm(range(start, end), initial=start, total=end, desc="train",
                   disable=not self.progress, dynamic_ncols=True, unit="it")
        for it in bar:
            new_stage = stage_at(self.schedule, it)
            if new_stage != stage:
                stage = new_stage
                if self.on_stage is not None:
                    self.on_stage(stage)
            self.alg.stage = stage
            t0 = time.time()
            episode_logs: dict[str, list[float]] = {}
            with torch.inference_mode():
                for _ in range(self.cfg["num_steps_per_env"]):
                    actions = self.alg.act(obs)
                    obs, rewards, dones, extras = self.env.step(actions.to(self.env.device))
                    obs, rewards, dones = obs.to(self.device), rewards.to(self.device), dones.to(self.device)
                    self.alg.process_env_step(obs, rewards, dones, extras)
                    reward_sum += rewards.reshape(-1)
                    length += 1
                    done_ids = dones.reshape(-1).nonzero().flatten()
                    if done_ids.numel():
                        rewards_buf.extend(reward_sum[done_ids].tolist())
                        lengths_buf.extend(length[done_ids].tolist())
                        reward_sum[done_ids] = 0
                        length[done_ids] = 0
                    for key, value in extras.get("log", {}).items():
                        values = value.flatten().tolist() if torch.is_tensor(value) else [value]
                        episode_logs.setdefault(key, []).extend(float(v) for v in values)
                collect_time = time.time() - t0
                self.alg.compute_returns(obs)
            t1 = time.time()
            losses = self.alg.update()
            learn_time = time.time() - t1
            self.completed_iteration = it
            steps = self.cfg["num_steps_per_env"] * self.env.num_envs
            metrics = {f"loss/{k}": v for k, v in losses.items()}
            metrics.update({k if "/" in k else f"episode/{k}": statistics.fmean(v)
                            for k, v in episode_logs.items() if v})
            metrics["fps"] = steps / max(collect_time + learn_time, 1e-9)
            metrics["time/collect"] = collect_time
            metrics["time/learn"] = learn_time
            metrics["learning_rate"] = float(self.alg.learning_rate)
            metrics["policy/std"] = float(self.alg.get_policy().output_std.detach().mean())
            if rewards_buf:
                metrics["reward/mean"] = statistics.fmean(rewards_buf)
                metrics["episode/length"] = statistics.fmean(lengths_buf)
            if self.log is not None:
                self.log.log_metrics(it, metrics, stage=stage or "")
            bar.set_postfix(self._postfix(stage, metrics), refresh=False)
            if self.on_iteration is not None:
                self.on_iteration(it, metrics)
            last = it == end - 1
            if (it + 1) % self.cfg["save_interval"] == 0 or last or self._stop_signal:
                self.save_checkpoint()
            if self._stop_signal is not None:
                bar.close()
                raise StopRequested(signal.Signals(self._stop_signal).name)
        bar.close()

    @staticmethod
    def _postfix(stage: str | None, metrics: dict[str, float]) -> dict[str, str]:
        post = {"stage": stage or "", "fps": f"{metrics['fps']:.0f}"}
        if "reward/mean" in metrics:
            post["reward"] = f"{metrics['reward/mean']:.2f}"
        for key, value in metrics.items():
            if key.startswith("success/"):
                post[key.split("/", 1)[1]] = f"{value:.2f}"
        return post
