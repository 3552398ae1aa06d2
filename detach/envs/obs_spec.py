"""Shapes of the observation TensorDict that envs publish and models consume.

Every group is a 2-D tensor [N, D] (rsl-rl-lib's format). History groups travel flattened
([N, T*d], time-major: step 0 is the oldest, step T-1 the newest) and models reshape them with
the (T, d) given here. The sizes depend only on the character and the env config (the run's
skills, `env.skills`, give the `task` width), never on the scene or on what else a process
registered, so a policy trained on LH1 runs on LH2 and LH3.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

from detach.skills import skill_names

OBS_GROUPS: tuple[str, ...] = ("self", "env", "task", "critic", "amp")
OBJECT_WIDTH = 3 + 6 + 24
"""Object features of an env frame: position, rotation (6-D) and bounding-box corners."""


@dataclass(frozen=True)
class ObsSpec:
    self_steps: int
    """T of the proprioception history (`self` group)."""
    self_dim: int
    """d of one proprioception frame (joint pos/vel, body pos/rot/vel in the heading frame)."""
    env_steps: int
    """T of the environment history (`env` group)."""
    env_dim: int
    """d of one environment frame (target, object features, flattened local height map)."""
    height_map_cells: int
    """The last `height_map_cells` entries of an env frame are the local height map (grid x grid)."""
    num_skills: int
    """Width of the `task` one-hot (the run's skills, `env.skills`)."""
    critic_dim: int
    """Width of the privileged `critic` group."""
    amp_steps: int
    amp_dim: int
    """The `amp` group is [N, amp_steps * amp_dim]."""
    num_actions: int
    skills: tuple[str, ...] = ()
    """The skill of each `task` one-hot entry, in order (empty in specs written before it)."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "skills", tuple(self.skills))  # a list when read back from YAML
        if self.skills and len(self.skills) != self.num_skills:
            raise ValueError(f"ObsSpec: {len(self.skills)} skills {list(self.skills)} for a task one-hot "
                             f"of {self.num_skills}")

    def one_hot_skills(self) -> tuple[str, ...]:
        """The skill of each `task` one-hot entry; for a spec without `skills`, the registry's
        first `num_skills` (follow, carry, climb, sit for every run recorded before it)."""
        return self.skills or skill_names()[:self.num_skills]

    def group_dims(self) -> dict[str, int]:
        """Flat width of each TensorDict group."""
        return {
            "self": self.self_steps * self.self_dim,
            "env": self.env_steps * self.env_dim,
            "task": self.num_skills,
            "critic": self.critic_dim,
            "amp": self.amp_steps * self.amp_dim,
        }

    def to_dict(self) -> dict[str, int | tuple[str, ...]]:
        return asdict(self)

    def env_fields(self) -> dict[str, slice]:
        """Named parts of one env frame (`detach.envs.observations`): the current target (3),
        the path ahead (2 per sample), the subtask's object (position 3, rotation 6, corners 24)
        and the local height map (last `height_map_cells`)."""
        path = self.env_dim - OBJECT_WIDTH - 3 - self.height_map_cells
        obj = 3 + path
        return {"target": slice(0, 3), "path": slice(3, obj), "object": slice(obj, obj + OBJECT_WIDTH),
                "height_map": slice(self.env_dim - self.height_map_cells, self.env_dim)}

    def describe(self) -> str:
        """A table of the groups and their shapes (for start-up logs)."""
        shapes = {"self": f"{self.self_steps} x {self.self_dim}", "env": f"{self.env_steps} x {self.env_dim}",
                  "task": f"{self.num_skills}", "critic": f"{self.critic_dim}",
                  "amp": f"{self.amp_steps} x {self.amp_dim}"}
        return "\n".join(["Observation groups", "  group   shape", *(f"  {g:<7} {v}" for g, v in shapes.items())])


EXAMPLE_SPEC = ObsSpec(
    self_steps=5,
    self_dim=287,
    env_steps=5,
    env_dim=3 + 3 + 24 + 6 + 625,
    height_map_cells=625,
    num_skills=4,
    critic_dim=287 + 661 + 4,
    amp_steps=10,
    amp_dim=105,
    num_actions=32,
)
"""Representative humanoid sizes for tests of models on random tensors."""
