"""What does TokenHSI's Carry stage start from? The Follow cell's policy loaded as the laptop
preset's Carry stage loads it (`train.init_from`, merged statistics, the grasp at 0.1, with or
without the reach pose), scored with mean actions on validation trials of Carry (the run's seed
plus `VALIDATION_SEED_OFFSET`, what the stage's own start choice plays; never the evaluation's),
with and without `model.tokenizer_from={carry: follow}`. Also, on the first validation frames,
how far the carry token is from the follow token the same frame would give (the policy acts on
the carry token; Follow trained only the follow one), and the same policy told to follow.

    python results/laptop/diagnosis/tokenhsi_carry_start.py FOLLOW_RUN [TRIALS] [preset|copied|both]
"""
import sys
from pathlib import Path

import torch

from detach import (
    apply_action_means, build_runner, load_initial_weights, resolve_run, run_evaluation, seed_everything, skill_names,
    validation_env, validation_seed,
)

ROOT = Path(__file__).resolve().parents[3]
STAGE = ["env.character=puppet", "env.episode_length=600", "env.mid_task_init_prob=0.5", "sim.num_envs=4",
         "train.init_normalizers=merge", "train.torch_threads=1"]
GRASP = {"grasp": 0.1}
POSE = {"grasp": 0.1, "abdomen_y": 0.69, "right_shoulder_y": -0.43, "left_shoulder_y": -0.43,
        "right_elbow_y": 0.0, "left_elbow_y": 0.0}
FOLLOW = skill_names().index("follow")


def stage_start(follow_run: str, *extra: str):
    cfg = resolve_run(ROOT / "configs/tasks/carry.yaml", "tokenhsi",
                      [*STAGE, f"train.init_from={follow_run}", *extra])
    seed_everything(cfg.seed)
    _env, runner = build_runner(cfg, None, "cpu", progress=False)
    line = load_initial_weights(runner, cfg)
    return cfg, runner.alg.actor, line


def told_to_follow(obs):
    out = obs.clone()
    out["task"] = torch.zeros_like(obs["task"])
    out["task"][:, FOLLOW] = 1.0
    return out


def scored(env, policy, cfg, trials: int) -> str:
    """`validation_score`'s trials (the same seed and reset), with the interval and delivered share."""
    env.gen.manual_seed(validation_seed(cfg))
    with torch.inference_mode():
        env.reset()
        result = run_evaluation(env, policy, trials, cfg, progress=False)
    m, (lo, hi) = result.lh_mean.rate, result.lh_mean.ci
    return f"{m:.2f} [{lo:.2f}, {hi:.2f}], delivered {result.lh_chain.rate:.2f}"


def tokens(actor, obs) -> tuple[torch.Tensor, torch.Tensor]:
    """(carry token, follow token) of the newest env frame, each tokenizer on its own parts."""
    env = actor.normalized_groups(obs)["env"][:, -1]
    trunk = actor.trunk
    return tuple(trunk.task_tokenizers[s](env.index_select(-1, getattr(trunk, f"{s}_index")))
                 for s in ("carry", "follow"))


def main() -> None:
    follow_run, trials = sys.argv[1], int(sys.argv[2]) if len(sys.argv) > 2 else 50
    which = sys.argv[3] if len(sys.argv) > 3 else "both"
    variants = {"preset": ("preset (random carry tokenizer)", ()),
                "copied": ("tokenizer_from={carry: follow}", ("model.tokenizer_from={carry: follow}",))}
    for name, extra in [v for k, v in variants.items() if which in (k, "both")]:
        cfg, actor, line = stage_start(follow_run, *extra)
        print(f"== {name}: {line.split('(', 1)[1][:-1][-160:]}")
        env = validation_env(cfg, trials, "cpu")
        obs = env.get_observations()
        with torch.no_grad():
            carry, follow = tokens(actor, obs)
            cos = torch.nn.functional.cosine_similarity(carry, follow, dim=-1)
            gap = (actor(obs) - actor(told_to_follow(obs))).abs().max()
        print(f"   first validation frames: cos(carry token, follow token) median {cos.median():.2f}; "
              f"|carry token| {carry.norm(dim=-1).median():.2f}, |follow token| {follow.norm(dim=-1).median():.2f}; "
              f"max |action(carry) - action(told to follow)| {gap:.3f}")
        loaded = {k: v.clone() for k, v in actor.state_dict().items()}
        for means_name, means in (("grasp 0.1", GRASP), ("grasp 0.1 + reach pose", POSE)):
            actor.load_state_dict(loaded)
            apply_action_means(actor, cfg.env.character, means)
            for told, policy in (("carry", lambda o: actor(o)), ("told to follow", lambda o: actor(told_to_follow(o)))):
                if told != "carry" and extra:
                    continue  # the same actions at the start (checked above)
                score = scored(env, policy, cfg, trials)
                print(f"   {means_name}, one-hot {told}: Carry (LH mean) {score} on {trials} validation trials",
                      flush=True)


if __name__ == "__main__":
    main()
