"""The skill registry: name -> skill class, in a fixed order.

A run's skills (`env.skills`, `run_skills`) are an ordered list of registered names, recorded
in its config.yaml; a skill's position there is its index in the run's tensors (the `task`
one-hot observation, the AMP condition, the plan's skill ids), so what else a process has
registered never changes a run's observation sizes. The registry order (follow, carry, climb,
sit, then plug-ins in the order they are registered) completes a run's list.
`skill_class` accepts a skill's aliases (`traj`).
"""

from __future__ import annotations

import difflib
from collections.abc import Iterable, Sequence
from typing import TypeVar

from detach.skills.base import Skill

_SKILLS: dict[str, type[Skill]] = {}
_ALIASES: dict[str, str] = {}
S = TypeVar("S", bound=type[Skill])


def register_skill(cls: S) -> S:
    """Add a skill class (usable as a decorator); its name and aliases must be new."""
    for name in (cls.name, *cls.aliases):
        owner = _ALIASES.get(name)
        if owner is not None and _SKILLS[owner] is not cls:
            raise ValueError(f"skill name '{name}' is already taken by '{owner}'")
    _SKILLS[cls.name] = cls
    for name in (cls.name, *cls.aliases):
        _ALIASES[name] = cls.name
    return cls


def unregister_skill(name: str) -> None:
    """Remove a plug-in skill (tests); built-in skills keep their indices only if they stay."""
    cls = _SKILLS.pop(canonical_name(name))
    for alias in (cls.name, *cls.aliases):
        _ALIASES.pop(alias, None)


def skill_names() -> tuple[str, ...]:
    """Canonical names in registry (index) order."""
    return tuple(_SKILLS)


def canonical_name(name: str) -> str:
    """The skill's canonical name for a name or alias (ValueError naming the valid ones)."""
    try:
        return _ALIASES[name]
    except KeyError:
        aliases = [f"{a} = {c}" for a, c in _ALIASES.items() if a != c]
        close = difflib.get_close_matches(str(name), list(_ALIASES), n=1, cutoff=0.6)
        hint = f" (did you mean '{close[0]}'?)" if close else ""
        raise ValueError(f"unknown skill '{name}'{hint}; available: {', '.join(_SKILLS)}"
                         + (f" (aliases: {', '.join(aliases)})" if aliases else "")) from None


def skill_class(name: str) -> type[Skill]:
    return _SKILLS[canonical_name(name)]


def skill_index(name: str) -> int:
    """Index of a skill (or alias) in registry order (a run's tensors use `run_skills`)."""
    return list(_SKILLS).index(canonical_name(name))


DEFAULT_RUN_SKILLS: tuple[str, ...] = ("follow", "carry", "climb", "sit")
"""The skills of a run whose config has no `env.skills` (every run recorded before the key):
the built-in skills in their order. Fixed, so that such runs keep their observation sizes."""


def run_skills(listed: Sequence[str], plan: Iterable[str]) -> tuple[str, ...]:
    """A run's skills in one-hot order: `listed` (env.skills) in canonical names, or when it is
    empty `DEFAULT_RUN_SKILLS` and then the plan's other skills in registry order. ValueError
    when a listed name is unknown or twice, or the plan uses a skill the list lacks."""
    used = {canonical_name(s) for s in plan}
    if not listed:
        return (*DEFAULT_RUN_SKILLS, *(s for s in _SKILLS if s in used and s not in DEFAULT_RUN_SKILLS))
    names = tuple(canonical_name(s) for s in listed)
    if len(set(names)) != len(names):
        raise ValueError(f"a skill is listed twice: {list(listed)}")
    missing = [s for s in _SKILLS if s in used and s not in names]
    if missing:
        raise ValueError(f"the plan uses {', '.join(missing)}, which the list ({', '.join(names)}) lacks")
    return names


def display_name(name: str) -> str:
    """'Follow' for follow or traj; an unknown name is returned as it is (old files)."""
    try:
        return skill_class(name).display_name
    except ValueError:
        return name
