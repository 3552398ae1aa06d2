"""Running evaluation episodes of a policy in an env, and what they leave in the run log.

Unbiased trial counting: stopping at "the first `trials` finished episodes" over parallel envs
would favour short (often failed) episodes, so every env gets a fixed quota of episodes and
only those count. Every counted trial is recorded frame by frame (`EpisodeFrame`: the bodies,
the current subtask, its target and Follow path) through a recorder (the run's log.mcap),
together with the scene, and closed by a frame with its verdict (`closing_frame`).
"""

from __future__ import annotations

from typing import Callable, Protocol

import torch
from tensordict import TensorDict
from tqdm import tqdm

from detach.config.schema import RunConfig
from detach.eval.report import TrialOutcome, summarize
from detach.eval.scene import scene_message
from detach.runfolder.eval_result import EvalResult
from detach.runfolder.messages import EpisodeFrame, SceneMessage

Policy = Callable[[TensorDict], torch.Tensor]


class EpisodeRecorder(Protocol):
    """Where a recorded evaluation goes (`detach.runs.mcap_log.RunLogWriter`)."""

    def log_scene(self, scene: SceneMessage) -> None: ...

    def log_frame(self, frame: EpisodeFrame) -> None: ...

    def flush(self) -> None: ...


def _frame(env, i: int, episode: int, trial: int, frame: int, last_path: list) -> EpisodeFrame:
    """Env i's frame; its path only where it differs from `last_path[0]` (the path the
    recording's previous frame had in force), which it updates."""
    snap = env.snapshot(i)
    path = None
    if frame == 0:
        last_path[0] = None
    if not _same_path(snap.path, last_path[0]):
        path = [] if snap.path is None else snap.path.tolist()
        last_path[0] = snap.path
    return EpisodeFrame(episode, frame, frame * env.dt, list(snap.bodies), snap.body_pos.tolist(),
                        snap.body_quat.tolist(), snap.objects, snap.subtask, snap.skill, trial,
                        target=None if snap.target is None else snap.target.tolist(), path=path,
                        path_index=snap.path_index)


def _same_path(a, b) -> bool:
    if a is None or b is None:
        return a is None and b is None
    return a.shape == b.shape and bool((a == b).all())


def closing_frame(last: EpisodeFrame, success: bool, scores: list[float], dt: float) -> EpisodeFrame:
    """The frame that closes a recorded episode with its verdict: the last pose again, one
    step later (the env has already reset when the verdict is known)."""
    return EpisodeFrame(last.episode, last.frame + 1, last.time + dt, last.bodies, last.pos, last.quat,
                        last.objects, last.subtask, last.skill, last.trial, target=last.target,
                        path_index=last.path_index, outcome="success" if success else "failure",
                        scores=[float(v) for v in scores])


TRAINING_TRIAL = -1
"""`EpisodeFrame.trial` of a training episode (evaluation trials are 0, 1, ...)."""


class TrainingEpisodes:
    """Records env 0's next whole episode after each checkpoint of a training run, as
    (the checkpoint's iteration, `TRAINING_TRIAL`): the replay shows how the policy moved
    while it learned, a few episodes per run, each from its frame 0."""

    def __init__(self, recorder: EpisodeRecorder) -> None:
        self.recorder = recorder
        self.episode: int | None = None
        """The episode being waited for or recorded (None: idle until the next checkpoint)."""
        self.frame: int | None = None
        """The next frame's number (None: waiting for env 0's current episode to end)."""
        self._last: EpisodeFrame | None = None
        self._path: list = [None]

    def start(self, iteration: int) -> None:
        """After checkpoint `iteration`: record env 0's next episode (one at a time)."""
        if self.episode is None:
            self.episode, self.frame = iteration, None

    def after_step(self, env, dones: torch.Tensor, extras: dict | None = None) -> None:
        """Call after every env.step (with its extras, for the verdict on the closing
        frame): a done of env 0 starts or ends the recording."""
        if self.episode is None:
            return
        done = bool(dones.reshape(-1)[0])
        if done and self.frame is not None:  # the recorded episode ended
            progress = (extras or {}).get("episode_progress")
            if progress is not None and self._last is not None:
                outcome = trial_outcome(progress, 0, env.dt)
                self.recorder.log_frame(closing_frame(self._last, outcome.completed, outcome.scores, env.dt))
            self.recorder.flush()
            self.episode = self.frame = self._last = None
            return
        if self.frame is None:
            if not done:
                return
            self.frame = 0  # env 0 was reset: its new episode starts now
        self._last = _frame(env, 0, self.episode, TRAINING_TRIAL, self.frame, self._path)
        self.recorder.log_frame(self._last)
        self.frame += 1


def run_evaluation(env, policy: Policy, trials: int, cfg: RunConfig, recorder: EpisodeRecorder | None = None,
                   progress: bool = True, episode_id: int = 0) -> EvalResult:
    """Roll out `trials` episodes (quota per env) and summarise them as an eval.json result.

    With a `recorder`, every counted trial is recorded as episode `episode_id` (the
    checkpoint's iteration, so evaluations of successive checkpoints stay apart), trial 0, 1,
    ... in the order the trials started (each env's first episodes are its trials)."""
    n = env.num_envs
    quota = [trials // n + (1 if i < trials % n else 0) for i in range(n)]
    counted = [0] * n
    outcomes: list[TrialOutcome] = []
    trial_of = list(range(n))  # the trial each env is playing (recorded while < its quota)
    frame_of = [0] * n
    last: list[EpisodeFrame | None] = [None] * n
    paths: list[list] = [[None] for _ in range(n)]
    next_trial = n
    if recorder is not None:
        recorder.log_scene(scene_message(env, cfg))
    obs = env.get_observations()
    bar = tqdm(total=trials, desc=f"eval {cfg.task_name}", disable=not progress, unit="ep")
    with torch.inference_mode():
        while len(outcomes) < trials:
            for i in range(n) if recorder is not None else ():
                if counted[i] < quota[i]:
                    last[i] = _frame(env, i, episode_id, trial_of[i], frame_of[i], paths[i])
                    recorder.log_frame(last[i])
                    frame_of[i] += 1
            obs, _rew, dones, extras = env.step(policy(obs))
            progress_data = extras.get("episode_progress")
            for i in dones.nonzero().flatten().tolist():
                if counted[i] < quota[i] and progress_data is not None:
                    counted[i] += 1
                    outcomes.append(trial_outcome(progress_data, i, env.dt))
                    bar.update(1)
                    if recorder is not None and last[i] is not None:
                        recorder.log_frame(closing_frame(last[i], outcomes[-1].completed, outcomes[-1].scores,
                                                         env.dt))
                if counted[i] < quota[i]:  # its next episode is a trial too
                    trial_of[i], frame_of[i], next_trial = next_trial, 0, next_trial + 1
    bar.close()
    if recorder is not None:
        recorder.flush()
    return summarize([s.skill for s in env.plan], outcomes, cfg.eval.confidence,
                     task=cfg.task_name, model=cfg.model_name)


def trial_outcome(prog: dict[str, torch.Tensor], i: int, dt: float) -> TrialOutcome:
    """Env i's finished episode from `extras["episode_progress"]`: scores, times, success."""
    scores = prog["score"][i].float().tolist()
    times = prog["exec_time"][i].float().tolist()
    last_end = int(prog["end"][i, -1])
    return TrialOutcome(scores=scores, times=times, completed=bool(prog["lh_success"][i]),
                        reached=[bool(s >= 0) for s in prog["start"][i].tolist()],
                        total_time=float(prog["length"][i]) * dt,
                        completion_time=last_end * dt if last_end >= 0 else float("nan"))
