"""The stage contracts: task parameters and results as `vint_core::contract` defines them.

`contract.schema.json`, next to this module, is generated from the Rust types (a Rust test fails
when it is stale), so the bounds and defaults the engines apply are the ones the spec validator and
the planner use: a spec that validates gives parameters every engine accepts. Engines call
`validated(stage, params)` first and then read plain values; they keep only the checks a schema
cannot express (a rotation matrix, a profile that must not cross itself, a file that must exist).
"""

from __future__ import annotations

import copy
import json
from collections.abc import Mapping
from functools import cache
from pathlib import Path
from typing import Any

from jsonschema import Draft202012Validator
from jsonschema.exceptions import ValidationError, best_match

from vint_engines.errors import BadInput, shown

SCHEMA_FILE = Path(__file__).with_name("contract.schema.json")

Json = dict[str, Any]


@cache
def schema() -> Json:
    """The committed schema document (read once; it never changes while the process runs)."""
    document: Json = json.loads(SCHEMA_FILE.read_text(encoding="utf-8"))
    return document


@cache
def _validator(stage: str, part: str) -> Draft202012Validator:
    stages = schema()["stages"]
    if stage not in stages:
        raise BadInput(f"unknown stage {stage!r} (contracts: {sorted(stages)})")
    return _validator_of(stages[stage][part]["$ref"])


@cache
def _validator_of(ref: str) -> Draft202012Validator:
    return Draft202012Validator({"$ref": ref, "$defs": schema()["$defs"]})


def validated(stage: str, params: Mapping[str, Any], where: str = "params") -> Json:
    """`params` checked against the stage's parameter schema, with every absent field that has a
    default filled in (a deep copy: the input is left as it is). BadInput names the field, the
    value and the rule it breaks."""
    _check(_validator(stage, "params"), params, where)
    filled = copy.deepcopy(dict(params))
    _fill_defaults(_validator(stage, "params").schema, filled)
    return filled


def validated_part(name: str, obj: object, where: str) -> Json:
    """`obj` checked against the type `name` of the schema's `$defs` (a part of some stage's
    parameters, e.g. `GraspPhysics`), defaults filled in. `{}` gives the defaults."""
    if not isinstance(obj, Mapping):
        raise BadInput(f"{where}: expected an object, got {shown(obj)}")
    validator = _validator_of(f"#/$defs/{name}")
    _check(validator, obj, where)
    filled = copy.deepcopy(dict(obj))
    _fill_defaults(validator.schema, filled)
    return filled


def check_result(stage: str, result: Mapping[str, Any]) -> None:
    """A result an engine is about to send follows its stage's contract (else: a bug, not bad
    input, so the error is a RuntimeError)."""
    error = best_match(_validator(stage, "result").iter_errors(result))
    if error is not None:
        raise RuntimeError(f"{stage} result breaks its contract at {_path('result', error)}: {error.message}")


def definition(name: str) -> Json:
    """A type's schema by its name in `$defs` (e.g. `ObjectEntry`)."""
    found: Json = schema()["$defs"][name]
    return found


def bounds(name: str, field: str, variant: str | None = None) -> tuple[float, float]:
    """The [minimum, maximum] of a number field of a type, e.g. `bounds("ObjectEntry", "mass_kg")`;
    for an array field, of its items; for a tagged union (`Shape`), of its `variant`'s field."""
    node = definition(name)
    if variant is not None:
        node = next(v for v in node["oneOf"] if v["properties"]["type"].get("const") == variant)
    prop = node["properties"][field]
    prop = prop.get("items", prop)
    return float(prop["minimum"]), float(prop["maximum"])


def count_bounds(name: str, field: str, variant: str | None = None) -> tuple[int, int]:
    """The [minItems, maxItems] of an array field of a type."""
    node = definition(name)
    if variant is not None:
        node = next(v for v in node["oneOf"] if v["properties"]["type"].get("const") == variant)
    prop = node["properties"][field]
    return int(prop["minItems"]), int(prop["maxItems"])


def _check(validator: Draft202012Validator, instance: Mapping[str, Any], where: str) -> None:
    error = best_match(validator.iter_errors(instance))
    if error is not None:
        raise BadInput(f"{_path(where, error)}: {_rule(error)}")


def _path(where: str, error: ValidationError) -> str:
    path = where
    for part in error.absolute_path:
        path += f"[{part}]" if isinstance(part, int) else f".{part}"
    return path


def _rule(error: ValidationError) -> str:
    """The rule, worded like the spec validator's: the value, then what it breaks."""
    value = shown(error.instance)
    keyword = error.validator
    if keyword == "minimum" or keyword == "maximum":
        low = _find(error.schema, "minimum")
        high = _find(error.schema, "maximum")
        return f"{value} is outside [{low}, {high}]"
    if keyword == "additionalProperties":
        return f"{error.message} (allowed: {sorted(error.schema.get('properties', {}))})"
    return f"{error.message}"


def _find(schema: Mapping[str, Any], key: str) -> object:
    return schema.get(key, "…")


def _resolve(node: Mapping[str, Any]) -> Mapping[str, Any]:
    """A schema node with its `$ref` (into `$defs`) followed."""
    while "$ref" in node:
        node = {
            **definition(node["$ref"].removeprefix("#/$defs/")),
            **{k: v for k, v in node.items() if k != "$ref"},
        }
    return node


def _fill_defaults(node: Mapping[str, Any], instance: object) -> None:
    """Adds the schema's defaults for absent properties, recursing into objects and arrays, and
    makes integer fields Python ints (JSON Schema counts 4.0 as an integer)."""
    node = _resolve(node)
    if isinstance(instance, dict):
        for key, prop in node.get("properties", {}).items():
            if key not in instance and "default" in prop:
                instance[key] = copy.deepcopy(prop["default"])
            if key not in instance:
                continue
            value = instance[key]
            if _is_integer_type(_resolve(prop)) and isinstance(value, float):
                instance[key] = int(value)
            else:
                _fill_defaults(prop, value)
        for variant in node.get("oneOf", []):
            resolved = _resolve(variant)
            const = resolved.get("properties", {}).get("type", {}).get("const")
            if const is not None and instance.get("type") == const:
                _fill_defaults(resolved, instance)
    elif isinstance(instance, list) and isinstance(node.get("items"), Mapping):
        items = _resolve(node["items"])
        for i, item in enumerate(instance):
            if _is_integer_type(items) and isinstance(item, float):
                instance[i] = int(item)
            else:
                _fill_defaults(items, item)


def _is_integer_type(node: Mapping[str, Any]) -> bool:
    kind = node.get("type")
    return kind == "integer" or (isinstance(kind, list) and "integer" in kind)
