"""Resolve a configuration

A run's configuration is a task YAML merged with a model YAML, presets and `key=value`
overrides, into one frozen `RunConfig` of typed sections. Tasks and models are found by name
(the working directory's configs/, then the ones shipped with detach) or by path.

    python examples/01_resolve_config.py
"""

from detach.config import dump, find_task_file, resolve
from detach.config.keys import format_keys, select


def main() -> None:
    cfg = resolve(find_task_file("lh1"), "detach", ["env.character=puppet", "sim.num_envs=8"], seed=3)
    print(f"task {cfg.task_name}, model {cfg.model_name} ({cfg.model.kind}), seed {cfg.seed}")
    print(f"plan: {list(cfg.task.plan)}")
    print(f"{cfg.sim.num_envs} envs, control at {1 / (cfg.sim.physics_dt * cfg.sim.substeps):.0f} Hz")
    print("\n".join(dump(cfg).splitlines()[:8]) + "\n...")  # what config.yaml of a run holds
    print(format_keys(select("sim"))[:400])  # `detach-run keys sim`: what can be overridden


if __name__ == "__main__":
    main()
