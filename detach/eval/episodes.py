"""Running evaluation episodes of a policy in an env, and what they leave in the run log.

Unbiased trial counting: stopping at "the first `trials` finished episodes" over parallel envs
would favour short (often failed) episodes, so every env gets a fixed quota of episodes and
only those count. Env 0's first episode is recorded frame by frame (`EpisodeFrame`) through a
recorder (the run's log.mcap), together with the scene.
"""

from __future__ import annotations

from typing import Callable, Protocol

import torch
from tensordict import TensorDict
from tqdm import tqdm

from detach.config_schema import RunConfig
from detach.eval.report import TrialOutcome, summarize
from detach.eval.scene import scene_message
from detach.run_contract import EpisodeFrame, EvalResult, SceneMessage

Policy = Callable[[TensorDict], torch.Tensor]


class EpisodeRecorder(Protocol):
    """Where a recorded evaluation goes (`detach.runs.mcap_log.RunLogWriter`)."""

    def log_scene(self, scene: SceneMessage) -> None: ...

    def log_frame(self, frame: EpisodeFrame) -> None: ...

    def flush(self) -> None: ...


def _frame(env, episode: int, frame: int) -> EpisodeFrame:
    snap = env.snapshot(0)
    return EpisodeFrame(episode, frame, frame * env.dt, list(snap.bodies), snap.body_pos.tolist(),
                        snap.body_quat.tolist(), snap.objects, snap.subtask, snap.skill)


def run_evaluation(env, policy: Policy, trials: int, cfg: RunConfig, recorder: EpisodeRecorder | None = None,
                   progress: bool = True, episode_id: int = 0) -> EvalResult:
    """Roll out `trials` episodes (quota per env) and summarise them as an eval.json result.

    With a `recorder`, env 0's first episode is recorded as episode `episode_id` (the
    checkpoint's iteration, so evaluations of successive checkpoints stay apart)."""
    n = env.num_envs
    quota = [trials // n + (1 if i < trials % n else 0) for i in range(n)]
    counted = [0] * n
    outcomes: list[TrialOutcome] = []
    recording = recorder is not None
    frame = 0
    if recorder is not None:
        recorder.log_scene(scene_message(env, cfg))
    obs = env.get_observations()
    bar = tqdm(total=trials, desc=f"eval {cfg.task_name}", disable=not progress, unit="ep")
    with torch.inference_mode():
        while len(outcomes) < trials:
            if recording:
                recorder.log_frame(_frame(env, episode_id, frame))
                frame += 1
            obs, _rew, dones, extras = env.step(policy(obs))
            progress_data = extras.get("episode_progress")
            for i in dones.nonzero().flatten().tolist():
                if i == 0 and recording:
                    recording = False
                    recorder.flush()
                if counted[i] >= quota[i] or progress_data is None:
                    continue
                counted[i] += 1
                outcomes.append(_outcome(progress_data, i, env.dt))
                bar.update(1)
    bar.close()
    return summarize([s.skill for s in env.plan], outcomes, cfg.eval.confidence,
                     task=cfg.task_name, model=cfg.model_name)


def _outcome(prog: dict[str, torch.Tensor], i: int, dt: float) -> TrialOutcome:
    scores = prog["score"][i].float().tolist()
    times = prog["exec_time"][i].float().tolist()
    return TrialOutcome(scores=scores, times=times, completed=bool(prog["lh_success"][i]),
                        total_time=float(prog["length"][i]) * dt)
