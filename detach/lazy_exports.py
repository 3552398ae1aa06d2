"""A package's public names loaded on first use (PEP 562), so that importing the package, or any
of its submodules, does not pay for what those names need (torch, MuJoCo).

    __getattr__, __dir__ = lazy_exports(__name__, {"NAME": "module.path", ...}, globals())
"""

from __future__ import annotations

import importlib
from typing import Any, Callable, Mapping


def lazy_exports(package: str, homes: Mapping[str, str], namespace: dict[str, Any],
                 renamed: Mapping[str, str] | None = None
                 ) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """The package's `__getattr__` and `__dir__`: public name -> the module (absolute) that
    defines it, under `renamed[name]` where the two differ; a name that is no attribute of its
    module is that module's submodule (e.g. `detach.envs.observations`). A name once loaded is
    kept in `namespace` (the package's globals)."""
    renamed = renamed or {}

    def __getattr__(name: str) -> Any:
        home = homes.get(name)
        if home is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        owner, attribute = importlib.import_module(home), renamed.get(name, name)
        value = (getattr(owner, attribute) if hasattr(owner, attribute)
                 else importlib.import_module(f"{home}.{attribute}"))
        namespace[name] = value
        return value

    def __dir__() -> list[str]:
        return sorted({*namespace, *homes})

    return __getattr__, __dir__
