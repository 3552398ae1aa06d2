"""`train.select_checkpoint_trials`: the run's policy is its best checkpoint on validation trials.

A stage of the progressive protocol that starts from a trained policy peaks and then drifts
(PPO at a small learning rate on a new task): which iteration is best differs between random
streams, so a fixed iteration count either stops early or hands on a worse policy. The run
scores every checkpoint it kept on the same validation trials (never the evaluation's), names
the best in selection.json, and every reader of the run's policy takes that one; the same
rule for every model.
"""

from __future__ import annotations

from detach.config.schema import RunConfig
from detach.runfolder.names import checkpoint_file, checkpoint_iteration
from detach.runfolder.atomic import atomic_write_json
from detach.runfolder.folder import RunFolder
from detach.runs.policy import load_policy
from detach.runs.validation import validation_env, validation_score, validation_seed
from detach.train.checkpoints import UnreadableCheckpoint


def select_checkpoint(run: RunFolder, cfg: RunConfig, device: str) -> str:
    """Score each checkpoint in `run` on `train.select_checkpoint_trials` validation trials,
    write selection.json naming the best (highest LH mean; on a tie the newest, the policy
    without a selection) and return the log line. Unreadable checkpoints are left out, with a
    note in the line."""
    trials = cfg.train.select_checkpoint_trials
    env = validation_env(cfg, trials, device)
    scores: dict[int, float] = {}
    skipped = []
    for path in reversed(run.checkpoint_files()):  # oldest first
        try:
            actor, _state = load_policy(cfg, env, path, device)
        except UnreadableCheckpoint:
            skipped.append(path.name)
            continue
        score = scores[checkpoint_iteration(path.name)] = validation_score(env, lambda obs: actor(obs), cfg, trials)
        print(f"  {path.name}: LH mean {score:.2f} over {trials} validation trials", flush=True)
    if not scores:
        return "train.select_checkpoint_trials: no readable checkpoint to choose from; the policy is the newest"
    best = max(scores, key=lambda it: (scores[it], it))
    chosen = run.checkpoints / checkpoint_file(best)
    atomic_write_json(run.selection_path, {
        "checkpoint": chosen.name, "iteration": best, "trials": trials, "seed": validation_seed(cfg),
        "metric": "lh_mean", "scores": {str(it): s for it, s in scores.items()}})
    listed = ", ".join(f"{it}: {s:.2f}" for it, s in scores.items())
    note = f" (unreadable, left out: {', '.join(skipped)})" if skipped else ""
    return (f"train.select_checkpoint_trials: LH mean over {trials} validation trials by iteration: {listed}{note}; "
            f"the run's policy is {chosen.name}")
