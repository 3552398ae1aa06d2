"""A thin subclass of rsl-rl-lib's OnPolicyRunner: stages, progress bar, run-folder output.

It keeps rsl-rl's algorithm construction and replaces `learn`, `save` and `load`, to add
what a run of this platform needs: the training stage of each iteration (DETACH's protocol),
a tqdm bar with iteration / FPS / reward / success rates, one `/metrics` MCAP message per
iteration, checkpoints `model_<iter>.pt` into the run folder, and a clean stop on SIGTERM or
Ctrl-C (checkpoint first). A checkpoint's `iter` is the last *completed* iteration; resuming
continues at `iter + 1`.

What a checkpoint restores (`detach.train.checkpoints`): actor and critic with their
observation normalisers, PPO's optimiser and adaptive learning rate, the discriminators,
their normalisers and optimiser, the AMP replay buffer (a sidecar file, newest checkpoint
only) and the random-number states (Python, NumPy, torch, the environment's generator).
What it does not: the simulation state of the environments (a resumed run starts fresh
episodes) and the progress bar's running reward averages.
Loading never unpickles (`weights_only=True`; rsl-rl's own `load` would run a pickled
`__reduce__`), and a file of another model is refused in one line.
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

from detach.run_contract import checkpoint_file, replay_file
from detach.train.amp_ppo import REPLAY_KEY
from detach.train.checkpoints import (
    CheckpointError, capture_rng, check_model, describe_mismatch, first_line, prune_checkpoints, read_checkpoint, read_sidecar,
    replay_path, restore_rng, write_checkpoint,
)
from detach.train.schedule import stage_at

StageHook = Callable[..., None]
"""Called with the stage name when an iteration enters a new stage, and with
`resumed=True` for the stage a resumed run continues (enter-once work such as DETACH's encoder
snapshot must not run again: the checkpoint holds its result)."""
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
        self.resumed = False
        self._stop_signal: int | None = None
        self.model_name: str | None = None
        self.model_kind: str | None = None
        """The run's model (recorded in checkpoints; a checkpoint of another is refused)."""
        self.keep_last, self.keep_every = 0, 0
        """Checkpoint retention (`train.keep_checkpoints`); 0, 0 keeps every checkpoint."""

    # ------------------------------------------------------------------ checkpoints
    def checkpoint_path(self, iteration: int) -> Path | None:
        if self.checkpoint_dir is None:
            return None
        return self.checkpoint_dir / checkpoint_file(iteration)

    def save(self, path: str, infos: dict | None = None) -> None:
        """rsl-rl's save, written atomically; the AMP replay buffer goes to its sidecar and
        the random-number states into the checkpoint."""
        checkpoint = Path(path)
        state = self.alg.save()
        replay = state.pop(REPLAY_KEY, None)
        state["iter"] = self.current_learning_iteration
        state["infos"] = {**(infos or {}), "model": self.model_name, "model_kind": self.model_kind}
        state["rng_state"] = capture_rng(getattr(self.env, "gen", None))
        sidecar = replay_path(checkpoint) if replay is not None else None
        if sidecar is not None:
            write_checkpoint(sidecar, replay)
        try:
            write_checkpoint(checkpoint, state)
        except BaseException:
            if sidecar is not None:
                sidecar.unlink(missing_ok=True)
            raise

    def save_checkpoint(self) -> Path | None:
        path = self.checkpoint_path(self.completed_iteration)
        if path is None or self.completed_iteration < 0:
            return None
        self.current_learning_iteration = self.completed_iteration
        self.save(str(path), infos={"stage": stage_at(self.schedule, self.completed_iteration)})
        prune_checkpoints(path.parent, self.keep_last, self.keep_every)
        return path

    def load(self, path: str, load_cfg: dict | None = None, strict: bool = True,
             map_location: str | None = None) -> dict:
        """rsl-rl's load without unpickling, plus the replay sidecar and the random state.

        CheckpointError (one line) for a refused, truncated or foreign file."""
        checkpoint = Path(path)
        device = map_location or self.device
        state = read_checkpoint(checkpoint, device)
        if self.model_name is not None:
            check_model(state, checkpoint, self.model_name, str(self.model_kind))
        if getattr(self.alg, "amp_enabled", False):
            sidecar = replay_path(checkpoint)
            if sidecar is not None and sidecar.exists():
                state[REPLAY_KEY] = read_sidecar(sidecar, device)
            else:
                print(f"note: no {replay_file(int(state['iter']))} beside {checkpoint.name}: the AMP replay "
                      f"buffer starts empty", flush=True)
        try:
            load_iteration = self.alg.load(state, load_cfg, strict)
        except (RuntimeError, KeyError, ValueError, TypeError) as exc:
            raise CheckpointError(f"the checkpoint does not fit this run's model ({self._mismatch(state, exc)}); "
                                  f"was it written by another model or config?", str(checkpoint)) from None
        if load_iteration:
            self.current_learning_iteration = int(state["iter"])
        restore_rng(state.get("rng_state") or {}, getattr(self.env, "gen", None))
        return state.get("infos") or {}

    def _mismatch(self, state: dict, exc: BaseException) -> str:
        """What of the checkpoint does not fit the actor and the critic, briefly."""
        parts = []
        for part, module, key in (("actor", self.alg.actor, "actor_state_dict"),
                                  ("critic", self.alg.critic, "critic_state_dict")):
            why = describe_mismatch(module.state_dict(), state.get(key))
            if why != "incompatible values":
                parts.append(f"{part}: {why}")
        return "; ".join(parts) or first_line(exc)

    def load_checkpoint(self, path: Path) -> int:
        """Restore models, optimisers, replay buffer, random state and iteration; returns the
        next iteration to run. CheckpointError when the checkpoint's stage is not the one this
        run's schedule gives its iteration (the schedule changed since it was written)."""
        infos = self.load(str(path), map_location=self.device)
        self.completed_iteration = self.current_learning_iteration
        self.resumed = True
        saved_stage = infos.get("stage") if isinstance(infos, dict) else None
        expected = stage_at(self.schedule, self.completed_iteration)
        if saved_stage is not None and saved_stage != expected:
            raise CheckpointError(f"iteration {self.completed_iteration} was trained in stage '{saved_stage}', "
                                  f"but this run's schedule puts it in '{expected}' (train.stages or "
                                  f"train.max_iterations changed the past)", str(path))
        return self.completed_iteration + 1

    # ------------------------------------------------------------------ loop
    def _request_stop(self, signum: int, _frame: object) -> None:
        self._stop_signal = signum

    def learn(self, num_learning_iterations: int, init_at_random_ep_len: bool = False) -> None:
        """Run iterations completed_iteration+1 .. num_learning_iterations-1 (absolute)."""
        start = self.completed_iteration + 1
        if self.is_distributed:  # torchrun: rank 0's weights, loaded or resumed after __init__'s broadcast
            self.alg.broadcast_parameters()
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
        if self._stop_signal is not None:  # arrived after the last iteration's check
            raise StopRequested(signal.Signals(self._stop_signal).name)

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
                continuing = it == start and start > 0 and self.resumed \
                    and stage_at(self.schedule, start - 1) == new_stage
                stage = new_stage
                if self.on_stage is not None:
                    if continuing:
                        self.on_stage(stage, resumed=True)
                    else:
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
                signum, self._stop_signal = self._stop_signal, None
                raise StopRequested(signal.Signals(signum).name)
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

