"""The `Skill` interface: everything about one skill of a plan, in one class.

A skill module (follow, carry, climb, sit, or a plug-in) subclasses `Skill` and registers it
(`detach.skills.register_skill`). It owns:

- plan entries: which target sources it accepts (`sources`) and `compile_entry`, the check of
  one plan entry against the task (errors are `PlanError`s naming the key);
- targets: `target` (the world target of its subtasks each step) and `display_target` (a
  static one for drawing the scene), `distance` (anchor-to-target distance that the
  transition rule holds under `success_threshold`);
- per-subtask statistics it accumulates (`stats`, updated in `update_stats`) and its success
  score (`score`: 1 success, 0 failure, partial credit allowed);
- reward terms (`reward_terms`, name -> `RewardTerm` with a default weight; YAML weights
  override them as `rewards.terms.<skill>/<term>`);
- extra episode terminations (`termination_names`, `terminations`);
- its piece of the scripted oracle (`oracle`);
- optionally, start states from the middle of its task (`mid_task_start`, `env.mid_task_init_prob`);
- the motion-clip labels of its style prior (`motion_labels`);
- display: `display_name` and `color` (eval tables, the dashboard).

All tensors are batched over envs ([N, ...]) on the env's device, world frame, metres.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Callable, ClassVar

import numpy as np
import torch

if TYPE_CHECKING:  # pragma: no cover - types only
    from detach.config.schema import TaskCfg
    from detach.skills.context import OracleCommand, SkillContext, SkillServices
    from scene_builder.scene import SceneInfo

RAND = -1
"""Source index of `traj_rand`: a procedural trajectory per episode."""


class PlanError(ValueError):
    """A plan entry a skill cannot run; `key` is the offending task key path."""

    def __init__(self, key: tuple, message: str) -> None:
        super().__init__(message)
        self.key = key


@dataclass(frozen=True)
class Subtask:
    """One compiled plan entry (static: the same for every env)."""

    index: int
    skill: str
    """Canonical skill name."""
    source: str
    """'traj', 'tarpos' or 'scene'."""
    ref: int
    """K of `source_K` (RAND for traj_rand)."""
    obj: int = -1
    """Object of the subtask (the box for carry, the object for climb/sit), else -1."""
    fixed_target: tuple[float, float, float] | None = None
    """World target when it does not move: tarpos_K, or the last waypoint (z = 0) of traj_K."""
    choices: tuple[int, ...] = ()
    """Objects one of which each episode draws at random (a list in `target_object`); empty
    when the object is fixed (`obj`)."""


@dataclass(frozen=True)
class RewardTerm:
    """A reward term: fn(ctx) -> [N] values (in [0, 1] by convention) and its default weight."""

    fn: Callable[["SkillContext"], torch.Tensor]
    weight: float


@dataclass(frozen=True)
class MidTaskStart:
    """An episode start from the middle of a skill's task, per env [n, ...]: where the
    character stands and how it holds itself, where the subtask's object is, and whether the
    character starts holding it (world frame, metres and radians)."""

    root_xy: torch.Tensor
    yaw: torch.Tensor
    height: torch.Tensor
    """Pelvis height."""
    hinges: torch.Tensor
    """[n, 32] hinge angles."""
    obj_pos: torch.Tensor
    obj_quat: torch.Tensor
    """[n, 4] wxyz."""
    held: torch.Tensor
    """[n] bool: the character starts holding the object."""


class Skill:
    """Base class of skills; see the module docstring. Defaults suit a skill whose target is
    a fixed point and whose success is "the transition fired"."""

    name: ClassVar[str]
    aliases: ClassVar[tuple[str, ...]] = ()
    """Other names accepted in task YAMLs (e.g. TokenHSI's `traj` for follow)."""
    display_name: ClassVar[str]
    color: ClassVar[tuple[int, int, int]] = (220, 40, 40)
    motion_labels: ClassVar[tuple[str, ...]] = ()
    sources: ClassVar[tuple[str, ...]] = ("tarpos",)
    needs_object: ClassVar[bool] = False
    """`target_object` must name a scene object (checked by `compile_entry`)."""
    follows_path: ClassVar[bool] = False
    """Its subtasks track the trajectory reference (observations show the path ahead)."""
    holds_objects: ClassVar[bool] = False
    """The character may grasp objects during its subtasks. Under any other skill a grasp
    request is refused and a held object let go: a Climb policy that could lift the box it
    is to climb carried it away instead (the climb point moves with the box)."""
    mid_task_reads_target: ClassVar[bool] = True
    """`mid_task_start` reads the subtask's fixed target (Carry's destination). False for a
    skill whose starts need only the object's place (Climb): its mid-task starts also apply
    to subtasks whose target comes from the object (no fixed target)."""
    stats: ClassVar[dict[str, torch.dtype]] = {}
    """Per-subtask statistics [N, S] it accumulates, by name and dtype (zeroed at reset)."""
    termination_names: ClassVar[tuple[str, ...]] = ()
    task_observation: ClassVar[tuple[str, ...]] = ("target", "object", "height_map")
    """The parts of an env frame (`ObsSpec.env_fields`) this skill's task observation is made
    of: what a model with one task tokenizer per skill (TokenHSI) feeds its tokenizer."""
    reward_terms: ClassVar[dict[str, RewardTerm]] = {}

    # ------------------------------------------------------------------ plan
    def compile_entry(self, index: int, source: str, ref: int, obj: int, task: "TaskCfg") -> Subtask:
        """Check plan entry `index` (source already known to exist) and resolve its target."""
        if source not in self.sources:
            accepted = ", ".join(f"{s}_K" for s in self.sources)
            raise PlanError(("sample_target_from", index), f"'{self.name}' takes its target from "
                            f"{accepted}, found {source}_{ref}")
        if self.needs_object and not 0 <= obj < len(task.scene):
            raise PlanError(("target_object", index), f"object index {obj} for '{self.name}' does not "
                            f"exist (scene has {len(task.scene)} objects)")
        fixed = tuple(float(v) for v in task.target_positions[ref]) if source == "tarpos" else None
        target_obj = ref if source == "scene" else (obj if self.needs_object else -1)
        return Subtask(index, self.name, source, ref, obj=target_obj, fixed_target=fixed)  # type: ignore[arg-type]

    def bind(self, plan: tuple[Subtask, ...], services: "SkillServices") -> None:
        """Per-environment set-up for the subtasks of `plan` that are this skill's."""
        self.plan, self.services, self.device = plan, services, services.device

    def display_target(self, sub: Subtask, scene: "SceneInfo") -> np.ndarray | None:
        """A world point to draw for the subtask (the target at the episode start)."""
        return None if sub.fixed_target is None else np.asarray(sub.fixed_target, dtype=np.float64)

    # ------------------------------------------------------------------ every step
    def start(self, mask: torch.Tensor, subtask: torch.Tensor, root_xy: torch.Tensor) -> None:
        """The envs in mask [N] just started one of this skill's subtasks (plan indices
        subtask [N], pelvis at root_xy [N, 2]; rows outside mask are to be left alone). A
        mask, not indices: selecting the envs would read the device on the host
        (`detach.host_sync`); `may_any(mask)` guards work worth skipping on a CPU."""

    def target(self, ctx: "SkillContext") -> torch.Tensor:
        """World target [N, 3] for envs on this skill (values elsewhere are ignored)."""
        return ctx.fixed_target

    def goal(self, ctx: "SkillContext") -> torch.Tensor:
        """The world point [N, 3] the character makes for now, shown to the policy as the
        current target (ctx.target filled; default: the target). A skill whose task passes
        through another place first (Carry: the box) shows that place until it is reached.
        Called for every env at each step's context (values of envs on other skills are
        ignored), possibly more than once per step: state kept here must be idempotent per
        step and reset in `start`."""
        return ctx.target

    def distance(self, ctx: "SkillContext") -> torch.Tensor:
        """Anchor-to-target distance [N], metres (default: pelvis to target, 3-D)."""
        return (ctx.state.root_pos - ctx.target).norm(dim=-1)

    def update_stats(self, ctx: "SkillContext", active: torch.Tensor, stats: dict[str, torch.Tensor]) -> None:
        """Accumulate this step into `stats` [N, S] at each env's current subtask (active [N]:
        the env is on this skill)."""

    def score(self, done: torch.Tensor, stats: dict[str, torch.Tensor]) -> torch.Tensor:
        """Success score [N, S] for subtasks of this skill from done [N, S] and the stats."""
        return done.float()

    def terminations(self, ctx: "SkillContext") -> dict[str, torch.Tensor]:
        """Extra episode-ending conditions [N] bool (evaluated where the env is on this skill)."""
        return {}

    def mid_task_start(self, objects: torch.Tensor, obj_rest: torch.Tensor, obj_half: torch.Tensor,
                       target: torch.Tensor, gen: torch.Generator) -> MidTaskStart | None:
        """A start state from the middle of this skill's task for n episodes whose first
        subtask is this skill's: objects [n] the subtask's object (scene index), obj_rest [n, 3]
        its resting bbox centre, obj_half [n, 3] its half sizes, target [n, 3] the subtask's
        fixed target (NaN where it has none and `mid_task_reads_target` is False). None (the
        default): the skill has no such states, and its episodes start as configured (`env.init`)."""
        return None

    def oracle(self, ctx: "SkillContext", cmd: "OracleCommand", active: torch.Tensor) -> None:
        """Write the scripted controller's command for envs on this skill (active [N])."""
        raise NotImplementedError(f"skill '{self.name}' has no oracle piece")
