"""detach.envs: the simulated character, batched MuJoCo environments, task logic.

Entry point: `detach.envs.lh_env.make_env(run_cfg, num_envs=None, device="cpu",
eval_mode=False)` -> an rsl-rl `VecEnv` publishing `env.obs_spec`. One module per concept:
humanoid / puppet (characters), backend (physics seam), trajectories, plan, state,
observations, rewards, success, resets, lh_env (the env), oracle (scripted puppet
controller + evaluator), preview (CLI).
"""
