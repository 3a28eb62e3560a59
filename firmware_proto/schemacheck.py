"""JSON documents checked against a JSON Schema, every violation at its JSON pointer:
what the plan schema (:mod:`firmware_proto.plan`) and the map schema
(:mod:`firmware_proto.worldmap`) report through.

Beyond the schema, numbers must be finite: JSON has no NaN or infinity, but Python's
parser accepts them. An extra property is reported at its own pointer, not its parent's.
A document nested deeper than :data:`MAX_DEPTH` is one violation at the root and is not
walked further: every walk here is iterative, and no schema of ours nests that deep.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Any

from jsonschema import Draft202012Validator

__all__ = ["MAX_DEPTH", "json_depth", "json_pointer", "schema_violations"]

MAX_DEPTH = 32
"""Deepest nesting of arrays and objects a checked document may have (a plan has 3)."""


def json_pointer(path: Iterable[Any]) -> str:
    """The RFC 6901 pointer of a path of keys and indices (``""`` for the root)."""
    return "".join("/" + str(p).replace("~", "~0").replace("/", "~1") for p in path)


def schema_violations(validator: Draft202012Validator, obj: Any) -> list[tuple[str, str]]:
    """Every violation of ``obj`` as ``(json_pointer, message)``, sorted by pointer.

    A document nested deeper than :data:`MAX_DEPTH` gives one violation at ``""``.
    """
    depth = json_depth(obj, MAX_DEPTH + 1)
    if depth > MAX_DEPTH:
        return [("", f"nested deeper than {MAX_DEPTH} levels")]
    found: list[tuple[str, str]] = []
    for error in validator.iter_errors(obj):
        base = json_pointer(error.absolute_path)
        if error.validator == "additionalProperties" and isinstance(error.instance, dict):
            allowed = set(error.schema.get("properties", {}))
            for key in sorted(k for k in error.instance if k not in allowed):
                found.append((base + json_pointer([key]), f"unexpected property {key!r}"))
            continue
        found.append((base, error.message))
    found += [(ptr, "must be a finite number") for ptr in _non_finite(obj, "")]
    return sorted(set(found))


def json_depth(obj: Any, limit: int | None = None) -> int:
    """How deeply ``obj`` nests arrays and objects (a scalar is 0, ``[]`` is 1), counted
    without recursion; the walk stops once ``limit`` is reached and returns it."""
    deepest = 0
    todo: list[tuple[Any, int]] = [(obj, 0)]
    while todo:
        node, depth = todo.pop()
        if isinstance(node, (dict, list)):
            depth += 1
            deepest = max(deepest, depth)
            if limit is not None and deepest >= limit:
                return deepest
            todo.extend((v, depth) for v in (node.values() if isinstance(node, dict) else node))
    return deepest


def _non_finite(obj: Any, ptr: str) -> list[str]:
    """Pointers of the non-finite floats in ``obj`` (iterative: any depth), in document
    order."""
    found: list[str] = []
    todo: list[tuple[Any, str]] = [(obj, ptr)]
    while todo:
        node, here = todo.pop()
        if isinstance(node, float) and not math.isfinite(node):
            found.append(here)
        elif isinstance(node, dict):
            todo.extend((v, here + json_pointer([k])) for k, v in reversed(node.items()))
        elif isinstance(node, list):
            todo.extend((v, f"{here}/{i}") for i, v in reversed(list(enumerate(node))))
    return found
