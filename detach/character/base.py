"""The `Character` interface and the registry of characters.

A character is the shared 15-body, 32-hinge body (`detach.character.body`) plus a root: how the
pelvis is attached to the world, what actuates it, and how policy actions become MuJoCo
controls. Everything that differs between characters lives behind this interface, so no other
package branches on a character's name:

- building: `add_root` (root joints, before the body) and `finish_body` (after it) into an
  MjSpec; `link_objects` adds whatever the character needs per movable scene object;
- actions: `num_actions`, `action_std` (initial policy std), `controls(actions, qpos)`;
- episodes: `write_root` (reset states), `bind` / `reset` / `pre_step` (per-env runtime state,
  e.g. the puppet's grasp), `held_object`, and `hold` where `can_hold` (start an episode
  holding an object);
- rewards: `joint_power_weight` scales the power penalty;
- scripting: a `scriptable` character accepts `scripted_actions` (the oracle's commands).

Register a new character with `register_character`; `make_character(name)` builds one.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import ClassVar, Protocol

import mujoco
import torch

from detach.character.actions import pd_targets
from detach.character.body import dof_ranges


class CharacterState(Protocol):
    """What `pre_step` reads of the simulator state (world frame, [N, ...] tensors)."""

    body_pos: torch.Tensor
    obj_pos: torch.Tensor
    obj_quat: torch.Tensor

    @property
    def root_pos(self) -> torch.Tensor: ...

    @property
    def root_quat(self) -> torch.Tensor: ...


class EqualityBackend(Protocol):
    """The part of the physics backend a character may drive (equality constraints)."""

    def set_equality(self, mask: torch.Tensor, eq_id: int, active: torch.Tensor,
                     data: torch.Tensor | None = None) -> None: ...


@dataclass(frozen=True)
class MovableObject:
    """A dynamic scene object as a character sees it at run time."""

    slot: int
    """Index among the scene's dynamic objects (the order of `SceneInfo.dynamic`)."""
    index: int
    """Index among all scene objects (the columns of `CharacterState.obj_pos`)."""
    link_eq: int
    """Equality id the character added for it with `link_objects`, else -1."""
    half_size: tuple[float, float, float]
    """Half bounding-box sizes, metres, object frame."""


@dataclass(frozen=True)
class ScriptedCommand:
    """A scripted controller's wish per env: root velocity (world XY, m/s), heading (rad),
    pelvis height (m), hinge targets [N, 32] (rad) and grasp (> 0 holds)."""

    velocity: torch.Tensor
    yaw: torch.Tensor
    yaw_target: torch.Tensor
    height: torch.Tensor
    hinges: torch.Tensor
    grasp: torch.Tensor


class Character(ABC):
    """See the module docstring; one instance per environment (it may hold per-env state)."""

    name: ClassVar[str]
    root_joint: ClassVar[str]
    """MuJoCo name of the root joint whose qpos/qvel addresses `write_root` receives."""
    num_actions: ClassVar[int]
    action_std: ClassVar[float]
    """Initial action std of a Gaussian policy (`model.init_noise_std: null` picks it)."""
    joint_power_weight: ClassVar[float] = 1.0
    scriptable: ClassVar[bool] = False
    can_hold: ClassVar[bool] = False
    """`hold` can start an episode with an object held (`env.mid_task_init_prob`)."""
    named_actions: ClassVar[dict[str, int]] = {}
    """Action dimensions a config may name (`train.init_action_mean`), e.g. the puppet's grasp."""

    def __init__(self) -> None:
        rng = torch.as_tensor(dof_ranges(), dtype=torch.float32)
        self.dof_lo, self.dof_hi = rng[:, 0], rng[:, 1]
        self.num_envs = 0

    # ------------------------------------------------------------------ building
    @abstractmethod
    def add_root(self, pelvis: mujoco.MjsBody) -> None:
        """Root joint(s) of the pelvis, added before the body's own joints."""

    def finish_body(self, spec: mujoco.MjSpec, bodies: dict[str, mujoco.MjsBody]) -> None:
        """Anything after the body and its 32 hinge actuators (extra actuators, gravity)."""

    def link_objects(self, spec: mujoco.MjSpec, object_bodies: dict[int, str]) -> dict[int, str]:
        """Per movable object (scene index -> body name): constraints the character may switch
        on at run time; returns scene index -> equality name of each one it added."""
        return {}

    # ------------------------------------------------------------------ run time
    def bind(self, num_envs: int, device: torch.device, backend: EqualityBackend,
             movable: tuple[MovableObject, ...], hand_ids: torch.Tensor, root_qpos_adr: int) -> None:
        """Allocate per-env state; hand_ids are the hands' indices among the 15 bodies,
        root_qpos_adr the qpos address of `root_joint`."""
        self.num_envs, self.device, self.root_qpos_adr = num_envs, device, root_qpos_adr
        self.dof_lo, self.dof_hi = self.dof_lo.to(device), self.dof_hi.to(device)
        self.backend, self.movable, self.hand_ids = backend, movable, hand_ids

    def reset(self, ids: torch.Tensor) -> None:
        """Envs ids start a new episode (the backend has reset their constraints)."""

    def pre_step(self, actions: torch.Tensor, state: CharacterState, may_hold: torch.Tensor) -> None:
        """Before physics, with the clamped actions and the state read after the last step;
        may_hold [N] bool: the envs whose current skill allows holding an object
        (`Skill.holds_objects`); a character with a grasp refuses and releases elsewhere."""

    def held_object(self) -> torch.Tensor:
        """[N] slot of the movable object each env holds by a constraint, -1 for none."""
        return torch.full((self.num_envs,), -1, dtype=torch.long, device=self.device)

    def hold(self, ids: torch.Tensor, slots: torch.Tensor, root_pos: torch.Tensor, root_quat: torch.Tensor,
             obj_pos: torch.Tensor, obj_quat: torch.Tensor) -> None:
        """Envs ids [n] (just reset) start holding movable objects slots [n] (-1: that row holds
        nothing), the pelvis at root_pos/root_quat and the objects at obj_pos/obj_quat (world
        frame, wxyz)."""
        raise NotImplementedError(f"character '{self.name}' cannot start an episode holding an object; use one "
                                  f"of {', '.join(n for n, c in CHARACTERS.items() if c.can_hold)}")

    def controls(self, actions: torch.Tensor, qpos: torch.Tensor) -> torch.Tensor:
        """MuJoCo ctrl [N, nu] from clamped actions [N, num_actions] and the current qpos."""
        return pd_targets(actions, self.dof_lo, self.dof_hi)

    @abstractmethod
    def write_root(self, qpos: torch.Tensor, qvel: torch.Tensor, q_adr: int, v_adr: int,
                   xy: torch.Tensor, height: torch.Tensor, yaw: torch.Tensor, tilt: torch.Tensor,
                   lin: torch.Tensor, ang: torch.Tensor) -> None:
        """Write a reset root state into rows of qpos/qvel: pelvis XY [n, 2] and height [n]
        (m), heading yaw [n] (rad), tilt [n, 4] (wxyz, heading removed), linear and angular
        velocity [n, 3] in the heading frame."""

    def scripted_actions(self, cmd: ScriptedCommand) -> torch.Tensor:
        """Actions [N, num_actions] realising a scripted command (scriptable characters)."""
        raise NotImplementedError(f"character '{self.name}' cannot be scripted; use one of "
                                  f"{', '.join(scriptable_characters())}")


CHARACTERS: dict[str, type[Character]] = {}


def register_character(cls: type[Character]) -> type[Character]:
    """Add a character class to the registry (usable as a decorator)."""
    if cls.name in CHARACTERS and CHARACTERS[cls.name] is not cls:
        raise ValueError(f"character '{cls.name}' is already registered")
    CHARACTERS[cls.name] = cls
    return cls


def character_names() -> tuple[str, ...]:
    return tuple(CHARACTERS)


def scriptable_characters() -> tuple[str, ...]:
    """Names of the characters a scripted controller (the oracle) can drive."""
    return tuple(n for n, c in CHARACTERS.items() if c.scriptable)


def character_class(name: str) -> type[Character]:
    try:
        return CHARACTERS[name]
    except KeyError:
        raise ValueError(f"unknown character '{name}'; available: {', '.join(CHARACTERS)}") from None


def make_character(name: str) -> Character:
    """A fresh character of the registered class `name` (ValueError naming the valid ones)."""
    return character_class(name)()

