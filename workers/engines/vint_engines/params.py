"""Typed reads of task parameters (plain JSON) with errors that name the offending field.

Every failure raises `BadInput`, which the serve loop reports as a non-retryable task failure.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

from vint_engines.errors import BadInput, shown


def section(obj: Mapping[str, Any], key: str, where: str) -> Mapping[str, Any]:
    """The JSON object at `obj[key]`; `where` names `obj` in error messages (e.g. "params")."""
    value = obj.get(key)
    if not isinstance(value, Mapping):
        raise BadInput(f"{where}.{key}: expected an object, got {shown(value)}")
    return value


def items(obj: Mapping[str, Any], key: str, where: str) -> list[Mapping[str, Any]]:
    """The list of JSON objects at `obj[key]` (at least one)."""
    value = obj.get(key)
    if not isinstance(value, list) or not value:
        raise BadInput(f"{where}.{key}: expected a non-empty list, got {shown(value)}")
    for i, item in enumerate(value):
        if not isinstance(item, Mapping):
            raise BadInput(f"{where}.{key}[{i}]: expected an object, got {shown(item)}")
    return value


def number(
    obj: Mapping[str, Any],
    key: str,
    where: str,
    default: float | None = None,
    *,
    low: float | None = None,
    high: float | None = None,
) -> float:
    """A finite number in [low, high]; `default` when the key is absent (if given)."""
    value = obj.get(key, default)
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise BadInput(f"{where}.{key}: expected a finite number, got {shown(value)}")
    if (low is not None and value < low) or (high is not None and value > high):
        raise BadInput(f"{where}.{key}: {value} is outside [{low}, {high}]")
    return float(value)


def integer(
    obj: Mapping[str, Any],
    key: str,
    where: str,
    default: int | None = None,
    *,
    low: int | None = None,
    high: int | None = None,
) -> int:
    """An integer in [low, high]; `default` when the key is absent (if given)."""
    value = obj.get(key, default)
    if isinstance(value, bool) or not isinstance(value, int):
        raise BadInput(f"{where}.{key}: expected an integer, got {shown(value)}")
    if (low is not None and value < low) or (high is not None and value > high):
        raise BadInput(f"{where}.{key}: {value} is outside [{low}, {high}]")
    return value


def seed(obj: Mapping[str, Any], key: str, where: str) -> int:
    """A seed as the Rust side derives them: an unsigned 64-bit integer."""
    return integer(obj, key, where, low=0, high=2**64 - 1)


def views(params: Mapping[str, Any]) -> list[tuple[int, int]]:
    """`params.views` as (view_index, seed) pairs; indices are unique and fit the `vNN` file names."""
    pairs = []
    for i, view in enumerate(items(params, "views", "params")):
        where = f"params.views[{i}]"
        pairs.append((integer(view, "view_index", where, low=0, high=99), seed(view, "seed", where)))
    if len({index for index, _ in pairs}) != len(pairs):
        raise BadInput("params.views: view_index values must be unique")
    return pairs


def boolean(obj: Mapping[str, Any], key: str, where: str, default: bool | None = None) -> bool:
    """A JSON boolean; `default` when the key is absent (if given)."""
    value = obj.get(key, default)
    if not isinstance(value, bool):
        raise BadInput(f"{where}.{key}: expected true or false, got {shown(value)}")
    return value


def string(obj: Mapping[str, Any], key: str, where: str, default: str | None = None) -> str:
    value = obj.get(key, default)
    if not isinstance(value, str) or not value:
        raise BadInput(f"{where}.{key}: expected a non-empty string, got {shown(value)}")
    return value


def number_range(
    obj: Mapping[str, Any], key: str, where: str, default: Sequence[float], *, low: float | None = None
) -> tuple[float, float]:
    """A `[min, max]` pair of finite numbers with min <= max."""
    value = obj.get(key, list(default))
    if not isinstance(value, list) or len(value) != 2:
        raise BadInput(f"{where}.{key}: expected [min, max], got {shown(value)}")
    pair = {"min": value[0], "max": value[1]}
    lo = number(pair, "min", f"{where}.{key}", low=low)
    hi = number(pair, "max", f"{where}.{key}", low=low)
    if lo > hi:
        raise BadInput(f"{where}.{key}: min {lo} exceeds max {hi}")
    return lo, hi
