"""detach.envs: the batched environment that runs a plan.

Entry point: `detach.envs.lh_env.make_env(run_cfg, num_envs=None, device="cpu",
eval_mode=False)` -> an rsl-rl `VecEnv` publishing `env.obs_spec`. One module per job:
world (character, scene, backend), starts (a new episode's `StartPlan`; resets and
subtask_starts make its kinds), plan_tracker (progress, transitions, episode books), rewards,
terminations, observations / obs_spec, oracle (scripted puppet controller), views (summary,
snapshot), lh_env (the env, wiring them), preview (CLI).
"""
