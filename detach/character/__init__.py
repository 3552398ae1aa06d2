"""detach.character: the simulated characters behind one `Character` interface.

`body` is the shared 15-body, 32-hinge definition; `humanoid` (free root, the paper's
character) and `puppet` (actuated root, for fast CPU studies) are the registered characters.
`make_character(name)` builds one; `build_character_spec(name)` a stand-alone MjSpec of it on a
floor. No other package branches on a character's name.
"""

from __future__ import annotations

import mujoco

from detach.character import humanoid as _humanoid  # noqa: F401  (registers)
from detach.character import puppet as _puppet  # noqa: F401  (registers)
from detach.character.base import (
    CHARACTERS, Character, MovableObject, ScriptedCommand, character_class, character_names, make_character,
    register_character, scriptable_characters,
)
from detach.character.body import add_body, add_floor, configure_options

__all__ = ["CHARACTERS", "Character", "MovableObject", "ScriptedCommand", "build_character_model",
           "build_character_spec", "character_class", "character_names", "make_character",
           "register_character", "scriptable_characters"]


def add_character(character: Character, parent: mujoco.MjsBody, spec: mujoco.MjSpec,
                  friction: float = 1.0) -> dict[str, mujoco.MjsBody]:
    """The character's root, body, hinge actuators and extras under `parent`."""
    bodies = add_body(parent, spec, character.add_root, friction)
    character.finish_body(spec, bodies)
    return bodies


def build_character_spec(name: str = "humanoid", physics_dt: float = 1.0 / 120.0, iterations: int = 4,
                         friction: float = 1.0, with_floor: bool = True) -> mujoco.MjSpec:
    """A stand-alone spec: the named character on a floor plane."""
    character = make_character(name)
    spec = mujoco.MjSpec()
    spec.modelname = name
    configure_options(spec, physics_dt, iterations)
    if with_floor:
        add_floor(spec, friction)
    add_character(character, spec.worldbody, spec, friction)
    return spec


def build_character_model(name: str = "humanoid", **kw) -> mujoco.MjModel:
    """Compile `build_character_spec`; a convenience for tests and tools."""
    return build_character_spec(name, **kw).compile()
