"""The values a numeric config field accepts, declared on the field (`ranged`) and checked
once, when a config is built.

A field's type alone admits values a run cannot use (0 environments, a negative iteration
count, a probability above 1); its range says which, beside its default, so that such a value
fails in one line, at the file and line it came from, before any run folder exists, and
`detach-run keys` shows the range with the key.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

from detach.config.yaml_source import ConfigError, ConfigOrigin, KeyPath

RANGE = "range"
"""The metadata key of a field's `Range`."""


@dataclass(frozen=True)
class Range:
    """The values a numeric field accepts: from `low` to `high` (None: unbounded), the ends
    excluded where `open_low` / `open_high`."""

    low: float | None = None
    high: float | None = None
    open_low: bool = False
    open_high: bool = False

    def admits(self, value: float) -> bool:
        if value != value or value in (float("inf"), float("-inf")):  # NaN, or an end no setting can use
            return False
        if self.low is not None and (value <= self.low if self.open_low else value < self.low):
            return False
        return self.high is None or (value < self.high if self.open_high else value <= self.high)

    def describe(self) -> str:
        low, high = _number_text(self.low), _number_text(self.high)
        if self.high is None:
            return f"{'>' if self.open_low else '>='} {low}"
        return f"in {'(' if self.open_low else '['}{low}, {high}{')' if self.open_high else ']'}"


def _number_text(value: float | None) -> str:
    if value is None:
        return ""
    return str(int(value)) if float(value).is_integer() else f"{value:g}"


POSITIVE = Range(0, open_low=True)
ENV_COUNT = Range(1, 2**20)
"""Environments in one process: the paper's 4096 x 256 is far past what one GPU holds; a larger
number is a typo that would exhaust memory before any error could name it."""
AT_LEAST_0, AT_LEAST_1 = Range(0), Range(1)
FRACTION = Range(0, 1)


def ranged(default: Any, allowed: Range) -> Any:
    """A dataclass field with `default` whose values must lie in `allowed`."""
    return field(default=default, metadata={RANGE: allowed})


def range_of(f: dataclasses.Field) -> Range | None:
    """The range declared on a field (None: any value of its type)."""
    return f.metadata.get(RANGE)


def check_ranges(cfg: Any, origin: ConfigOrigin) -> None:
    """Every ranged field of the dataclass `cfg` and of the sections in it within its range
    (ConfigError at the value's file and line; in declaration order, the first one out)."""
    for path, value, allowed in _ranged_values(cfg, ()):
        if isinstance(value, (int, float)) and not isinstance(value, bool) and not allowed.admits(value):
            finite = "finite " if value in (float("inf"), float("-inf")) else ""
            message = f"expected a {finite}value {allowed.describe()}, found {value}"
            if path in origin.prov:
                raise origin.error(path, message)
            raise ConfigError(message, "<command line>", None, path)  # e.g. --seed: in no file


def _ranged_values(obj: Any, path: KeyPath) -> Any:
    """(key path, value, range) of every ranged field under the dataclass instance `obj`."""
    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        allowed = range_of(f)
        if allowed is not None:
            yield (*path, f.name), value, allowed
        elif dataclasses.is_dataclass(value):
            yield from _ranged_values(value, (*path, f.name))
        elif isinstance(value, tuple):
            for i, item in enumerate(value):
                if dataclasses.is_dataclass(item):
                    yield from _ranged_values(item, (*path, f.name, i))
