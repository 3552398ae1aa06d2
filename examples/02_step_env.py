"""Step an environment

`make_env` builds the batched environment of a resolved config: MuJoCo worlds, the plan
tracker, observations as a TensorDict, rewards per skill. Here: random actions for a few steps.

    python examples/02_step_env.py [--steps 30]
"""

import argparse

import torch

from detach import find_task_file, make_env, resolve_run


def main(steps: int = 30) -> None:
    cfg = resolve_run(find_task_file("follow"), "mlp", ["env.character=puppet"])
    env = make_env(cfg, num_envs=2, eval_mode=True)
    obs = env.get_observations()
    print({key: tuple(value.shape) for key, value in obs.items()})
    gen = torch.Generator().manual_seed(0)
    total = torch.zeros(env.num_envs)
    for _ in range(steps):
        actions = torch.rand(env.num_envs, env.num_actions, generator=gen) * 2 - 1
        obs, reward, dones, _extras = env.step(actions)
        total += reward
    print(f"{steps} steps of {env.dt:.3f} s: return per env {total.tolist()}, root at "
          f"{env.snapshot(0).body_pos[0].round(2).tolist()}")


if __name__ == "__main__":
    parser = argparse.ArgumentParser()
    parser.add_argument("--steps", type=int, default=30)
    main(parser.parse_args().steps)
