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

Metrics carry rsl-rl's names (`metric_names`, docs/METRICS.md) and go to the run's log.mcap
and, with `train.logger: tensorboard | wandb`, through rsl-rl's own writers
(`rsl_rl.utils.logger.Logger`: TensorBoard's `SummaryWriter`, `WandbLogWriter`) into the run
folder. As rsl-rl's `check_nan`, every environment step is checked (`train.check_for_nan`):
a NaN in an observation group, the rewards, the dones or the policy's actions stops the run
with `NonFiniteError` naming the iteration, the step and the environments (status `failed`).
Loading never unpickles (`weights_only=True`; rsl-rl's own `load` would run a pickled
`__reduce__`), and a file of another model is refused in one line.
"""

from __future__ import annotations

import math
import os
import signal
import statistics
import time
from collections import deque
from pathlib import Path
from typing import Callable, Protocol

import torch
from rsl_rl.runners import OnPolicyRunner
from tqdm import tqdm

from detach.runfolder.folder import RunFolder
from detach.runfolder.names import checkpoint_file, replay_file
from detach.train.amp_ppo import REPLAY_KEY
from detach.train.checkpoints import (
    CheckpointError, capture_rng, check_model, describe_mismatch, disk_room_warning, first_line, folder_bytes,
    prune_checkpoints, read_checkpoint, read_sidecar, replay_path, restore_rng, saves_after, write_checkpoint,
)
from detach.train.schedule import stage_at

StageHook = Callable[..., None]
"""Called with the stage name when an iteration enters a new stage, and with
`resumed=True` for the stage a resumed run continues (enter-once work such as DETACH's encoder
snapshot must not run again: the checkpoint holds its result)."""
IterationHook = Callable[[int, dict[str, float]], None]
CurriculumHook = Callable[[int], dict[str, float]]
"""Called before each iteration's rollout with its index; returns metrics to log with it."""


def ended_episodes(ended: list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]]
                   ) -> tuple[list[float], list[float]]:
    """(returns, lengths) of the episodes that ended in a rollout, in the order they ended,
    from (done [N], return [N], length [N]) per step: one host read per rollout, not one per
    step."""
    done = torch.stack([e[0] for e in ended])
    returns, lengths = torch.stack([torch.stack(e[1:]) for e in ended], dim=1)[:, done].tolist()
    return returns, lengths


def rollout_means(logs: dict[str, list[torch.Tensor]]) -> dict[str, float]:
    """A rollout's mean of every env log key (rsl-rl's Logger names: a key without a '/' goes
    under `Episode/`), NaN values left out (a reward term with no env on its skill at a step:
    `RewardManager.compute`); keys with no value are left out. One host read per key."""
    out = {}
    for key, parts in logs.items():
        v = torch.cat(parts)
        v = v[~v.isnan()]
        if v.numel():
            out[key if "/" in key else f"Episode/{key}"] = float(v.double().mean())
    return out


class MetricsSink(Protocol):
    """Where the metrics of every iteration go (the run's log.mcap in a run folder)."""

    def log_metrics(self, iteration: int, metrics: dict[str, float], stage: str = "") -> None: ...


class StopRequested(Exception):
    """Raised inside the loop after SIGTERM/SIGINT once the checkpoint is written."""


class NonFiniteError(RuntimeError):
    """A NaN or infinity in what the environment returned or the policy produced (the run
    stops before it reaches a checkpoint; the last checkpoint is the last good state)."""


def metric_names(losses: dict[str, float]) -> dict[str, float]:
    """AmpPPO's update dict under rsl-rl's names: losses `Loss/<name>` (discriminator terms
    `Loss/amp/...`, DETACH's auxiliary terms `Loss/aux/...`), the mean reward per step of each
    objective `Train/step_reward_<objective>`."""
    return {(f"Train/step_{k}" if k.startswith("reward_") else f"Loss/{k}"): v for k, v in losses.items()}


SUCCESS_PREFIX = "Episode_Success/"
"""The environment's success fractions of the episodes that ended (`lh`, `<i>_<skill>`), shown
in the progress bar."""


def find_non_finite(it: int, step: int, **tensors: object) -> None:
    """Raise NonFiniteError naming the first group holding a NaN/inf (rsl-rl's `check_nan`,
    plus where: iteration, rollout step, environments). One device sync when all is finite."""
    groups = {what: ([(None, value)] if torch.is_tensor(value) else list(value.items()))  # a TensorDict
              for what, value in tensors.items()}
    named = [t for items in groups.values() for _key, t in items if torch.is_tensor(t) and t.is_floating_point()]
    if not named or bool(torch.stack([torch.isfinite(t).all() for t in named]).all()):
        return
    for what, items in groups.items():
        for key, tensor in items:
            if not torch.is_tensor(tensor) or not tensor.is_floating_point():
                continue
            bad = ~torch.isfinite(tensor)
            if bad.any():
                envs = bad.reshape(bad.shape[0], -1).any(dim=-1).nonzero().flatten().tolist() \
                    if bad.dim() else []
                name = f"observation group '{key}'" if key is not None else what
                shown = ", ".join(map(str, envs[:8])) + (" ..." if len(envs) > 8 else "")
                raise NonFiniteError(f"NaN/inf in the {name} at iteration {it}, step {step} of the rollout "
                                     f"(envs {shown}; {len(envs)} of {bad.shape[0] if bad.dim() else 1}); "
                                     f"the last checkpoint holds the last good weights")


class DetachRunner(OnPolicyRunner):
    episode_recorder = None
    """A `detach.eval.episodes.TrainingEpisodes`: env 0's next episode after each checkpoint."""

    def __init__(self, env, train_cfg: dict, device: str = "cpu",
                 schedule: list[tuple[str, int]] | None = None,
                 checkpoint_dir: Path | None = None, log: MetricsSink | None = None,
                 on_stage: StageHook | None = None, on_iteration: IterationHook | None = None,
                 progress: bool = True, log_dir: Path | None = None) -> None:
        """`train_cfg["logger"]`: "none", "tensorboard" or rsl-rl's dict form
        ({"class_name": "WandbLogWriter", "project_name": ...}); its writer writes into `log_dir`
        (the run folder; None: no writer)."""
        logger = train_cfg.get("logger", "none")
        super().__init__(env, {**train_cfg, "logger": "tensorboard" if logger == "none" else logger},
                         log_dir=None, device=device)
        self.logger.log_dir = str(log_dir) if log_dir is not None and logger != "none" else None
        self.logger._store_code_state = self._code_state_files  # provenance.json, not rsl-rl's git/*.diff
        self.schedule = schedule or [("ppo", 1)]
        self.checkpoint_dir = checkpoint_dir
        self.log = log
        self.on_stage = on_stage
        self.on_iteration = on_iteration
        self.before_iteration: CurriculumHook | None = None
        """A training curriculum (`train.balance_assist`), set by `detach.train.setup`."""
        self.progress = progress
        self.completed_iteration = -1
        self.resumed = False
        self._stop_signal: int | None = None
        self.model_name: str | None = None
        self.model_kind: str | None = None
        """The run's model (recorded in checkpoints; a checkpoint of another is refused)."""
        self.keep_last, self.keep_every = 0, 0
        """Checkpoint retention (`train.keep_checkpoints`); 0, 0 keeps every checkpoint."""
        self._warned_room: int | None = None
        """Saves that still fitted when the last low-disk line was printed (None: none yet)."""

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
        before = folder_bytes(path.parent)
        self.save(str(path), infos={"stage": stage_at(self.schedule, self.completed_iteration)})
        written = sum(p.stat().st_size for p in (path, replay_path(path)) if p is not None and p.exists())
        prune_checkpoints(path.parent, self.keep_last, self.keep_every)
        self._warn_on_low_disk(path.parent, written, folder_bytes(path.parent) - before)
        return path

    def _warn_on_low_disk(self, folder: Path, written: int, growth: int) -> None:
        """Say when the disk is close to full: once, and again each time the saves that still
        fit have halved (the line goes to stdout, which a sweep cell's log keeps)."""
        warning = disk_room_warning(folder, written, growth)
        if warning is None:
            return
        fits, line = warning
        if self._warned_room is None or fits < (self._warned_room + 1) // 2:
            print(line, flush=True)
            self._warned_room = fits

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
        self.alg.critic_warmup_left = max(0, getattr(self.alg, "critic_warmup_iterations", 0) - start)
        if self.is_distributed:  # torchrun: rank 0's weights, loaded or resumed after __init__'s broadcast
            self.alg.broadcast_parameters()
        if init_at_random_ep_len:  # new or resumed, the env was just built: all episodes at step 0
            self.env.episode_length_buf.copy_(torch.randint_like(
                self.env.episode_length_buf, high=int(self.env.max_episode_length)))
        previous = {sig: signal.signal(sig, self._request_stop)
                    for sig in (signal.SIGTERM, signal.SIGINT)}
        if self.logger.log_dir is not None and self.logger.writer is None:
            if isinstance(self.cfg["logger"], dict):  # W&B: its files in the run folder too
                os.environ.setdefault("WANDB_DIR", self.logger.log_dir)
            self.logger.init_logging_writer()
        try:
            self._loop(start, num_learning_iterations)
        finally:
            for sig, handler in previous.items():
                signal.signal(sig, handler)
            self.close_writer()
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
            curriculum = self.before_iteration(it) if self.before_iteration is not None else {}
            t0 = time.time()
            episode_logs: dict[str, list[torch.Tensor]] = {}
            ended: list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]] = []
            with torch.inference_mode():
                check = self.cfg.get("check_for_nan", True)
                for step in range(self.cfg["num_steps_per_env"]):
                    actions = self.alg.act(obs)
                    if check:
                        find_non_finite(it, step, actions=actions)
                    obs, rewards, dones, extras = self.env.step(actions.to(self.env.device))
                    if check:
                        find_non_finite(it, step, observations=obs, rewards=rewards, dones=dones.float())
                    if self.episode_recorder is not None:
                        self.episode_recorder.after_step(self.env, dones, extras)
                    obs, rewards, dones = obs.to(self.device), rewards.to(self.device), dones.to(self.device)
                    self.alg.process_env_step(obs, rewards, dones, extras)
                    reward_sum += rewards.reshape(-1)
                    length += 1
                    done = dones.reshape(-1).bool()
                    ended.append((done, reward_sum.clone(), length.clone()))
                    reward_sum.masked_fill_(done, 0.0)
                    length.masked_fill_(done, 0.0)
                    for key, value in extras.get("log", {}).items():
                        episode_logs.setdefault(key, []).append(torch.as_tensor(value, dtype=torch.float32).flatten())
                returns, lengths = ended_episodes(ended)
                rewards_buf.extend(returns)
                lengths_buf.extend(lengths)
                collect_time = time.time() - t0
                self.alg.compute_returns(obs)
            t1 = time.time()
            losses = self.alg.update()
            learn_time = time.time() - t1
            self.completed_iteration = it
            steps = self.cfg["num_steps_per_env"] * self.env.num_envs
            metrics = metric_names(losses)
            if self.cfg.get("check_for_nan", True):
                bad = [k for k, v in metrics.items() if not math.isfinite(v)]
                if bad:
                    raise NonFiniteError(f"{bad[0]} is {metrics[bad[0]]} after the update of iteration {it}"
                                         f"{f' (and {len(bad) - 1} more)' if len(bad) > 1 else ''}; "
                                         f"the last checkpoint holds the last good weights")
            metrics.update(rollout_means(episode_logs))
            metrics.update(curriculum)
            metrics["Perf/total_fps"] = steps / max(collect_time + learn_time, 1e-9)
            metrics["Perf/collection_time"] = collect_time
            metrics["Perf/learning_time"] = learn_time
            metrics["Loss/learning_rate"] = float(self.alg.learning_rate)
            metrics["Policy/mean_std"] = float(self.alg.get_policy().output_std.detach().mean())
            if rewards_buf:
                metrics["Train/mean_reward"] = statistics.fmean(rewards_buf)
                metrics["Train/mean_episode_length"] = statistics.fmean(lengths_buf)
            if self.log is not None:
                self.log.log_metrics(it, metrics, stage=stage or "")
            self.write_metrics(it, metrics)
            bar.set_postfix(self._postfix(stage, metrics), refresh=False)
            if self.on_iteration is not None:
                self.on_iteration(it, metrics)
            last = it == end - 1
            if saves_after(it, end, self.cfg["save_interval"]) or self._stop_signal:
                saved = self.save_checkpoint()
                if saved is not None:
                    self.logger.save_model(str(saved), it)  # W&B uploads it, as rsl-rl's learn does
                if self.episode_recorder is not None and not last:
                    self.episode_recorder.start(it)
            if self._stop_signal is not None:
                bar.close()
                signum, self._stop_signal = self._stop_signal, None
                raise StopRequested(signal.Signals(signum).name)
        bar.close()

    # ------------------------------------------------------------------ logging sinks
    def _code_state_files(self) -> list[str]:
        """What rsl-rl's Logger uploads as the code state (W&B): the run's provenance.json."""
        path = RunFolder(Path(self.logger.log_dir or ".")).provenance_path
        return [str(path)] if self.logger.log_dir and path.exists() else []

    def write_metrics(self, it: int, metrics: dict[str, float]) -> None:
        """The iteration's metrics through rsl-rl's writer (TensorBoard, W&B), if any."""
        writer = self.logger.writer
        if writer is None:
            return
        for key, value in metrics.items():
            writer.add_scalar(key, value, it)

    def close_writer(self) -> None:
        """Flush and close the writer (W&B: finish the run)."""
        writer, self.logger.writer = self.logger.writer, None
        if writer is None:
            return
        if hasattr(writer, "stop"):
            writer.stop()
        if hasattr(writer, "close"):
            writer.close()

    @staticmethod
    def _postfix(stage: str | None, metrics: dict[str, float]) -> dict[str, str]:
        """stage, fps, mean episode reward and the success fractions (`Episode_Success/`)."""
        post = {"stage": stage or "", "fps": f"{metrics['Perf/total_fps']:.0f}"}
        if "Train/mean_reward" in metrics:
            post["reward"] = f"{metrics['Train/mean_reward']:.2f}"
        for key, value in metrics.items():
            if key.startswith(SUCCESS_PREFIX):
                post[f"success_{key.removeprefix(SUCCESS_PREFIX)}"] = f"{value:.2f}"
        return post

