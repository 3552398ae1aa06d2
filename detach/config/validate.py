"""Turning checked YAML data into the frozen dataclasses of `detach.config.schema`.

The type hints of the dataclasses are the schema: this module walks them, so a new config
field needs no validation code. Every error names file, line, key path, what was expected and
what was found, and for an unknown key the closest valid one.
"""

from __future__ import annotations

import dataclasses
import difflib
import re
import types
import typing
from typing import Any, Literal

from detach.config.yaml_source import ConfigError, ConfigOrigin, KeyPath, Provenance

EXPONENT_FLOAT = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)[eE][+-]?\d+")
"""A number in exponent notation that YAML 1.1 leaves a string (no dot: `1e-5`, `3E4`)."""


def suggest(key: str, valid: typing.Iterable[str]) -> str:
    """' (did you mean 'x'?)' for a near miss, else ''."""
    close = difflib.get_close_matches(str(key), list(valid), n=1, cutoff=0.6)
    return f" (did you mean '{close[0]}'?)" if close else ""


def describe(value: Any) -> str:
    """Short rendering of a found value for error messages."""
    text = repr(value)
    if len(text) > 60:
        text = text[:57] + "..."
    return f"{type(value).__name__} {text}"


class Builder:
    """Validates data against a dataclass type, reporting positions through `prov`."""

    def __init__(self, prov: Provenance, default_file: str) -> None:
        self.prov = prov
        self.default_file = default_file

    def error(self, path: KeyPath, message: str) -> ConfigError:
        return ConfigOrigin(self.default_file, self.prov).error(path, message)

    def build(self, tp: Any, value: Any, path: KeyPath) -> Any:
        origin = typing.get_origin(tp)
        args = typing.get_args(tp)
        if dataclasses.is_dataclass(tp):
            return self._dataclass(tp, value, path)
        if origin in (typing.Union, types.UnionType):
            if value is None and type(None) in args:
                return None
            inner = [a for a in args if a is not type(None)]
            if len(inner) > 1:  # e.g. int | tuple[int, ...]: a list takes the sequence type
                seq = [a for a in inner if typing.get_origin(a) is tuple]
                plain = [a for a in inner if typing.get_origin(a) is not tuple]
                inner = (seq + plain) if isinstance(value, list) else (plain + seq)
            return self.build(inner[0], value, path)
        if origin is Literal:
            if value not in args:
                choices = ", ".join(repr(a) for a in args)
                raise self.error(path, f"expected one of {choices}, found {describe(value)}"
                                 + suggest(str(value), [str(a) for a in args]))
            return value
        if origin is tuple:
            return self._tuple(args, value, path)
        if origin is dict:
            return self._dict(args, value, path)
        return self._scalar(tp, value, path)

    def _scalar(self, tp: Any, value: Any, path: KeyPath) -> Any:
        if tp is float:
            if isinstance(value, str) and EXPONENT_FLOAT.fullmatch(value.strip()):
                return float(value)  # `1e-5`: YAML 1.1 (PyYAML) reads a string without a dot
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise self.error(path, f"expected a number, found {describe(value)}")
            return float(value)
        if tp is int:
            if isinstance(value, bool) or not isinstance(value, int):
                raise self.error(path, f"expected an integer, found {describe(value)}")
            return value
        if tp is bool:
            if not isinstance(value, bool):
                raise self.error(path, f"expected true or false, found {describe(value)}")
            return value
        if tp is str:
            if not isinstance(value, str):
                raise self.error(path, f"expected a string, found {describe(value)}")
            return value
        raise TypeError(f"unsupported schema type {tp!r} at {path}")

    def _tuple(self, args: tuple[Any, ...], value: Any, path: KeyPath) -> tuple[Any, ...]:
        variadic = len(args) == 2 and args[1] is Ellipsis
        if not isinstance(value, list):
            expected = "a list" if variadic else f"a list of {len(args)} values"
            raise self.error(path, f"expected {expected}, found {describe(value)}")
        if not variadic and len(value) != len(args):
            raise self.error(path, f"expected a list of {len(args)} values, found "
                                   f"{len(value)}: {value!r}")
        types_ = [args[0]] * len(value) if variadic else list(args)
        return tuple(self.build(t, v, path + (i,)) for i, (t, v) in enumerate(zip(types_, value)))

    def _dict(self, args: tuple[Any, ...], value: Any, path: KeyPath) -> dict[Any, Any]:
        if not isinstance(value, dict):
            raise self.error(path, f"expected a mapping, found {describe(value)}")
        key_tp, value_tp = args
        return {self._scalar(key_tp, k, path + (k,)): self.build(value_tp, v, path + (k,))
                for k, v in value.items()}

    def _dataclass(self, cls: Any, value: Any, path: KeyPath) -> Any:
        if not isinstance(value, dict):
            raise self.error(path, f"expected a mapping with keys of {cls.__name__}, "
                                   f"found {describe(value)}")
        if hasattr(cls, "kind_class"):  # a family of configs, one class per `kind`
            kind = value.get("kind", next(f.default for f in dataclasses.fields(cls) if f.name == "kind"))
            try:
                cls = cls.kind_class(kind)
            except ValueError as exc:
                raise self.error(path + ("kind",), str(exc)) from None
        hints = typing.get_type_hints(cls)
        fields = {f.name: f for f in dataclasses.fields(cls)}
        for key in value:
            if key not in fields:
                raise self.error(path + (key,), f"unknown key{suggest(key, fields)}; "
                                                f"valid keys: {', '.join(fields)}")
        kwargs = {}
        for name, f in fields.items():
            if name in value:
                kwargs[name] = self.build(hints[name], value[name], path + (name,))
            elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
                raise self.error(path, f"missing required key '{name}' ({cls.__name__})")
        return cls(**kwargs)


def to_plain(obj: Any) -> Any:
    """Dataclasses/tuples -> dicts/lists, the inverse of `Builder.build` (for dumping);
    fields marked `metadata={"dump": False}` are left out."""
    if dataclasses.is_dataclass(obj):
        return {f.name: to_plain(getattr(obj, f.name)) for f in dataclasses.fields(obj)
                if f.metadata.get("dump", True)}
    if isinstance(obj, (tuple, list)):
        return [to_plain(v) for v in obj]
    if isinstance(obj, dict):
        return {k: to_plain(v) for k, v in obj.items()}
    return obj
