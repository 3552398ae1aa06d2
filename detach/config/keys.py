"""`detach-run keys [section]`: every config key with its type, default and doc.

Generated from the dataclasses of `detach.config.schema` and the config classes of the model
kinds (the built-ins', `detach.models.configs`, and installed add-ons'), so the list cannot drift
from what the loader accepts. A field's doc is the string literal under it in the class body (the
convention of this code base); a range is the field's own (`detach.config.ranges.ranged`).
"""

from __future__ import annotations

import ast
import dataclasses
import inspect
import textwrap
import types
import typing
from dataclasses import dataclass
from functools import lru_cache
from typing import Any, Iterator

from detach.config.ranges import range_of
from detach.config.schema import (
    EnvCfg, EvalCfg, ModelCfg, RewardsCfg, SimCfg, TaskCfg, TrainCfg, registered_model_kinds,
)

SECTIONS: dict[str, type] = {"task": TaskCfg, "sim": SimCfg, "env": EnvCfg, "rewards": RewardsCfg,
                             "eval": EvalCfg, "model": ModelCfg, "train": TrainCfg}
"""YAML sections in file order. The task's own keys (scene, plan, ...) sit at the top level of
a task YAML, so they are listed without a prefix."""


@dataclass(frozen=True)
class Key:
    path: str
    """As written in an override: `sim.num_envs`, `scene[K].pos3d`, `model.d_model`."""
    type: str
    default: str
    doc: str
    section: str
    kind: str | None = None
    """For model keys: the model kind that has it (None: every kind)."""


@lru_cache(maxsize=None)
def field_docs(cls: type) -> dict[str, str]:
    """Field name -> the string literal written under it, for `cls` and its bases."""
    docs: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        if not dataclasses.is_dataclass(klass):
            continue
        try:
            tree = ast.parse(textwrap.dedent(inspect.getsource(klass)))
        except (OSError, TypeError, SyntaxError):
            continue
        body = tree.body[0].body if tree.body and isinstance(tree.body[0], ast.ClassDef) else []
        for node, after in zip(body, body[1:] + [None]):
            if isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name) and \
                    isinstance(after, ast.Expr) and isinstance(after.value, ast.Constant) and \
                    isinstance(after.value.value, str):
                docs[node.target.id] = " ".join(after.value.value.split())
    return docs


def type_name(tp: Any) -> str:
    """A type hint as a reader writes it: int, float | None, list of 3 float, one of a|b."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin is typing.Literal:
        return "one of " + "|".join(str(a) for a in args)
    if origin in (typing.Union, types.UnionType):
        return " | ".join("null" if a is type(None) else type_name(a) for a in args)
    if origin is tuple:
        if len(args) == 2 and args[1] is Ellipsis:
            inner = type_name(args[0])
            return f"list of ({inner})" if " | " in inner else f"list of {inner}"
        if args and all(a == args[0] for a in args):
            return f"list of {len(args)} {type_name(args[0])}"
        return "[" + ", ".join(type_name(a) for a in args) + "]"
    if origin is dict:
        return f"map {type_name(args[0])} -> {type_name(args[1])}"
    if dataclasses.is_dataclass(tp):
        return "section"
    return getattr(tp, "__name__", str(tp))


def _default_text(f: dataclasses.Field) -> str:
    if f.default is not dataclasses.MISSING:
        value = f.default
    elif f.default_factory is not dataclasses.MISSING:  # type: ignore[misc]
        value = f.default_factory()  # type: ignore[misc]
    else:
        return "(required)"
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, tuple):
        return "[" + ", ".join(_scalar(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k}: {_scalar(v)}" for k, v in value.items()) + "}"
    return _scalar(value)


def _scalar(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:g}" if abs(value) >= 1e-4 or value == 0 else f"{value:.6g}"
    if isinstance(value, tuple):
        return "[" + ", ".join(_scalar(v) for v in value) + "]"
    return str(value)


def _element(tp: Any) -> type | None:
    """The dataclass of a list-of-sections field (`scene`), else None."""
    args = typing.get_args(tp)
    if typing.get_origin(tp) is tuple and len(args) == 2 and args[1] is Ellipsis and dataclasses.is_dataclass(args[0]):
        return args[0]
    return None


def _keys_of(cls: type, prefix: str, section: str, kind: str | None = None,
             skip: frozenset[str] = frozenset()) -> Iterator[Key]:
    hints = typing.get_type_hints(cls)
    docs = field_docs(cls)
    for f in dataclasses.fields(cls):
        if f.name in skip or not f.init or f.metadata.get("dump") is False:
            continue
        tp = hints[f.name]
        path = f"{prefix}{f.name}"
        nested = next((c for c in (tp, *typing.get_args(tp)) if dataclasses.is_dataclass(c)), None)
        element = _element(tp)
        if element is not None:
            yield Key(path, f"list of {element.__name__}", _default_text(f), docs.get(f.name, ""), section, kind)
            yield from _keys_of(element, f"{path}[K].", section, kind)
        elif nested is not None and _default_text(f) != "null":
            yield from _keys_of(nested, f"{path}.", section, kind)
        else:
            doc = docs.get(f.name, "")
            rng = range_of(f)
            if rng is not None:
                doc = f"{doc} (range: {rng.describe()})".strip()
            yield Key(path, type_name(tp), _default_text(f), doc, section, kind)


def model_kinds() -> dict[str, type[ModelCfg]]:
    """Model kinds -> config class (built-in, installed add-ons, registered), in name order."""
    return dict(sorted(registered_model_kinds().items()))


def all_keys(sections: tuple[str, ...] | None = None) -> list[Key]:
    """Every key of a run configuration (or of `sections`), section by section (model: the
    common fields, then each kind's own, from its config class; no network is imported)."""
    out: list[Key] = []
    for section, cls in SECTIONS.items():
        if sections is not None and section not in sections:
            continue
        prefix = "" if section == "task" else f"{section}."
        if section == "model":
            out.extend(_keys_of(cls, prefix, section))
            common = frozenset(f.name for f in dataclasses.fields(ModelCfg)) - {"kind"}
            for kind, kind_cls in model_kinds().items():
                out.extend(_keys_of(kind_cls, prefix, section, kind, skip=common))
        else:
            out.extend(_keys_of(cls, prefix, section))
    return out


def select(section: str | None) -> list[Key]:
    """The keys of one section (`sim`), a key prefix (`train.amp`, `scene`), one model kind
    (`model.detach`: the common model keys and that kind's), or every key (None); ValueError
    naming the sections when nothing matches."""
    if not section:
        return all_keys()
    head = section.split(".")[0].split("[")[0]
    keys = all_keys((head if head in SECTIONS else "task",))
    kind = section[len("model."):] if section.startswith("model.") else None
    chosen = [k for k in keys if k.section == section or k.path == section
              or k.path.startswith((section + ".", section + "["))
              or (kind is not None and k.section == "model" and k.kind in (None, kind) and kind in kind_names())]
    if not chosen:
        names = ", ".join([*SECTIONS, *(f"model.{name}" for name in kind_names())])
        raise ValueError(f"no config key under '{section}'; sections: {names}, or a key prefix such as train.amp")
    return chosen


def kind_names() -> list[str]:
    """Names of the model kinds."""
    return list(model_kinds())


def format_keys(keys: list[Key], width: int = 100) -> str:
    """`path: type = default` lines, each followed by its doc indented; a heading per section
    and per model kind."""
    lines: list[str] = []
    heading = None
    for k in keys:
        this = k.section if k.kind is None else f"model, kind {k.kind} ({_class_path(k.kind)})"
        if k.section == "task":
            this = "task (top level of a task YAML)"
        if this != heading:
            lines += ([""] if lines else []) + [f"# {this}"]
            heading = this
        lines.append(f"{k.path}: {k.type} = {k.default}")
        if k.doc:
            lines += textwrap.wrap(k.doc, width=width, initial_indent="    ", subsequent_indent="    ")
    return "\n".join(lines)


def _class_path(kind: str) -> str:
    cls = model_kinds().get(kind)
    return f"{cls.__module__}:{cls.__qualname__}" if cls else kind
