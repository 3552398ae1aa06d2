"""Reading YAML files while remembering where every key came from.

Error messages must name the file and line of the offending key, so loading returns, beside
the plain data, a provenance map {key path: (file, line)}. Duplicate keys (which PyYAML
silently overwrites) are errors here.

Configs are small, and the loader refuses what is not: a file over `MAX_YAML_BYTES` (read no
further than that, so /dev/zero or a 200 MB file costs nothing), more than `MAX_YAML_NODES`
values once aliases are expanded (a 2 KB "billion laughs" alias bomb expands to billions),
or nesting deeper than `MAX_YAML_DEPTH`. Each is one ConfigError line.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

KeyPath = tuple[str | int, ...]
Provenance = dict[KeyPath, tuple[str, int]]

MAX_YAML_BYTES = 4 * 1024 * 1024
"""The largest config file read (the biggest shipped one is a few KB)."""
MAX_YAML_NODES = 200_000
"""The most values (mappings, lists, scalars) one document may expand to, aliases counted
at every use."""
MAX_YAML_DEPTH = 64
"""The deepest nesting of mappings and lists."""


class ConfigError(Exception):
    """A user error in a configuration: one line naming file, line, key, expected and found."""

    def __init__(self, message: str, file: str | None = None, line: int | None = None,
                 path: KeyPath = ()) -> None:
        where = ""
        if file:
            where = f"{file}:{line}: " if line else f"{file}: "
        key = format_path(path)
        super().__init__(f"{where}{key + ': ' if key else ''}{message}")
        self.file, self.line, self.path = file, line, path


def format_path(path: KeyPath) -> str:
    """('scene', 2, 'pos3d') -> 'scene[2].pos3d'."""
    out = ""
    for part in path:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out


def load_yaml(file: Path) -> tuple[Any, Provenance]:
    """Parse one YAML file into plain data plus the line of every key and list item."""
    name = str(file)
    if not file.exists():
        raise ConfigError("file not found", name)
    if file.is_dir():
        raise ConfigError("expected a YAML file, found a directory", name)
    try:
        with open(file, "rb") as f:
            raw = f.read(MAX_YAML_BYTES + 1)
        if len(raw) > MAX_YAML_BYTES:
            raise ConfigError(f"file is larger than {MAX_YAML_BYTES // (1024 * 1024)} MB; expected a "
                              f"config file of a few KB", name)
        text = raw.decode("utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"cannot read file ({exc.__class__.__name__}: {exc})", name) from None
    node = _compose(text, name)
    if node is None:
        raise ConfigError("file is empty (expected a mapping of config keys)", name)
    prov: Provenance = {}
    data = _convert(node, (), name, prov, _Budget(name))
    return data, prov


def _compose(text: str, name: str) -> yaml.Node | None:
    """PyYAML's node graph (aliases still shared, so this step cannot blow up in size)."""
    try:
        return yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise ConfigError(f"not valid YAML: {problem}", name,
                          mark.line + 1 if mark else None) from None
    except RecursionError:
        raise ConfigError(f"nested more than {MAX_YAML_DEPTH} levels deep", name) from None


class _Budget:
    """Counts the values a document expands to; refuses an alias bomb before memory grows."""

    def __init__(self, file: str) -> None:
        self.file, self.nodes = file, 0

    def spend(self, node: yaml.Node, path: KeyPath) -> None:
        self.nodes += 1
        if self.nodes > MAX_YAML_NODES:
            raise ConfigError(f"expands to more than {MAX_YAML_NODES} values (aliases counted at each "
                              f"use); expected a config file, refused as a possible alias bomb",
                              self.file, node.start_mark.line + 1)
        if len(path) > MAX_YAML_DEPTH:
            raise ConfigError(f"nested more than {MAX_YAML_DEPTH} levels deep", self.file,
                              node.start_mark.line + 1, path[:3])


def _convert(node: yaml.Node, path: KeyPath, file: str, prov: Provenance, budget: _Budget) -> Any:
    budget.spend(node, path)
    prov[path] = (file, node.start_mark.line + 1)
    if isinstance(node, yaml.MappingNode):
        out: dict[Any, Any] = {}
        for key_node, value_node in node.value:
            key = _scalar(key_node, path, file)
            if key == "<<":
                raise ConfigError("YAML merge keys (<<) are not supported; use `extends`",
                                  file, key_node.start_mark.line + 1, path)
            if key in out:
                raise ConfigError(f"duplicate key '{key}'", file,
                                  key_node.start_mark.line + 1, path)
            out[key] = _convert(value_node, path + (key,), file, prov, budget)
        return out
    if isinstance(node, yaml.SequenceNode):
        return [_convert(item, path + (i,), file, prov, budget) for i, item in enumerate(node.value)]
    return _scalar(node, path, file)


def _scalar(node: yaml.Node, path: KeyPath, file: str) -> Any:
    if not isinstance(node, yaml.ScalarNode):
        raise ConfigError("mapping keys must be plain scalars", file,
                          node.start_mark.line + 1, path)
    try:
        return yaml.SafeLoader(" ").construct_object(node, deep=True)
    except yaml.YAMLError as exc:
        raise ConfigError(f"bad value: {exc}", file, node.start_mark.line + 1, path) from None


def parse_scalar(text: str) -> Any:
    """Parse a command-line value as YAML (numbers, booleans, lists, null); text that is not
    YAML stays a string. The same budget as a file: an alias bomb is a ConfigError."""
    if not text.strip():
        return ""
    if len(text) > MAX_YAML_BYTES:
        raise ConfigError(f"override value is longer than {MAX_YAML_BYTES} characters", "<command line>")
    try:
        node = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.YAMLError:
        return text
    except RecursionError:
        raise ConfigError(f"override value nested more than {MAX_YAML_DEPTH} levels deep",
                          "<command line>") from None
    if node is None:
        return None
    try:
        return _convert(node, (), "<command line>", {}, _Budget("<command line>"))
    except ConfigError as exc:
        if "expands to more than" in str(exc) or "nested more than" in str(exc):
            raise
        return yaml.safe_load(text)  # e.g. a mapping with non-scalar keys: plain YAML semantics


class ConfigOrigin:
    """Where a resolved configuration's values came from, so that layers which check values
    later (plug-in names, plans) still report file and line."""

    def __init__(self, default_file: str = "<config>", prov: Provenance | None = None) -> None:
        self.default_file, self.prov = default_file, dict(prov or {})

    def error(self, path: KeyPath, message: str) -> ConfigError:
        """A ConfigError at the nearest key of `path` that has a recorded position."""
        probe = path
        while probe not in self.prov and probe:
            probe = probe[:-1]
        file, line = self.prov.get(probe, (self.default_file, None))
        return ConfigError(message, file, line, path)

    def __repr__(self) -> str:
        return f"ConfigOrigin({self.default_file!r})"
