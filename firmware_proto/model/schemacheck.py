"""JSON documents checked against a JSON Schema, every violation at its JSON pointer:
what the plan and map schemas report through.

Beyond the schema, numbers must be finite (Python's parser accepts NaN and infinity). An
extra property is reported at its own pointer. A document nested deeper than
:data:`MAX_DEPTH` is one violation at the root and is not walked further; every walk
here is iterative.

Fast path (``fast=True``, the plan check only, which runs on every gate request): the
schema compiled by fastjsonschema decides validity; only a refused document is walked by
jsonschema, which alone words the violations. Their agreement is tested
(``tests/firmware_proto/test_schemacheck.py``); a schema whose agreement is not tested
keeps jsonschema alone.
"""

from __future__ import annotations

import copy
import itertools
import math
from collections.abc import Callable, Iterable
from typing import Any

import fastjsonschema
from jsonschema import Draft202012Validator

__all__ = ["MAX_DEPTH", "is_valid", "json_depth", "json_pointer", "schema_violations"]

MAX_DEPTH = 32
"""Deepest nesting of arrays and objects a checked document may have (a plan has 3)."""


def json_pointer(path: Iterable[Any]) -> str:
    """The RFC 6901 pointer of a path of keys and indices (``""`` for the root)."""
    return "".join("/" + str(p).replace("~", "~0").replace("/", "~1") for p in path)


_compiled: dict[int, tuple[Draft202012Validator, Callable[[Any], Any] | None]] = {}


def _fast_check(validator: Draft202012Validator) -> Callable[[Any], Any] | None:
    """``validator``'s schema compiled by fastjsonschema (once per validator, which is kept,
    so its id is never reused); ``None`` where it cannot compile. A race compiles it twice,
    harmlessly."""
    entry = _compiled.get(id(validator))
    if entry is None:
        try:
            # A copy: fastjsonschema rewrites the "$ref"s of the shared schema in place.
            fast: Callable[[Any], Any] | None = fastjsonschema.compile(
                copy.deepcopy(validator.schema)
            )
        except fastjsonschema.JsonSchemaDefinitionException:
            fast = None
        entry = _compiled[id(validator)] = (validator, fast)
    return entry[1]


def is_valid(validator: Draft202012Validator, obj: Any) -> bool:
    """Whether ``obj`` has no violation at all, decided as fast as it can be: the
    compiled check where the schema has one (module docstring), and no wording. What
    :func:`schema_violations` with ``fast`` finds empty, this finds true."""
    check = _fast_check(validator)
    if check is not None:
        # First: it stops at the first violation, so a large bad document costs no walk.
        try:
            check(obj)
        except (fastjsonschema.JsonSchemaValueException, RecursionError):
            return False
    depth, has_non_finite = _scan(obj, MAX_DEPTH + 1)
    if depth > MAX_DEPTH or has_non_finite:
        return False
    return check is not None or not any(True for _ in validator.iter_errors(obj))


def schema_violations(
    validator: Draft202012Validator,
    obj: Any,
    *,
    fast: bool = False,
    limit: int | None = None,
) -> list[tuple[str, str]]:
    """Every violation of ``obj`` as ``(json_pointer, message)``, sorted by pointer; with
    ``limit``, the walk stops once that many are found (the first in document order).

    A document nested deeper than :data:`MAX_DEPTH` gives one violation at ``""``. With
    ``fast``, the compiled check decides first (module docstring).
    """
    depth, has_non_finite = _scan(obj, MAX_DEPTH + 1)
    if depth > MAX_DEPTH:
        return [("", f"nested deeper than {MAX_DEPTH} levels")]
    room = math.inf if limit is None else limit
    found: list[tuple[str, str]] = []
    if has_non_finite:
        found += [(ptr, "must be a finite number") for ptr in _non_finite(obj)]
        del found[int(min(room, len(found))) :]
    check = _fast_check(validator) if fast else None
    if check is not None:
        try:
            check(obj)
        except fastjsonschema.JsonSchemaValueException:
            pass
        else:
            return sorted(set(found))
    for error in validator.iter_errors(obj):
        if len(found) >= room:
            break
        base = json_pointer(error.absolute_path)
        if error.validator == "additionalProperties" and isinstance(error.instance, dict):
            allowed = set(error.schema.get("properties", {}))
            extra = (k for k in error.instance if k not in allowed)
            for key in sorted(itertools.islice(extra, int(min(room - len(found), 1e9)))):
                found.append((base + json_pointer([key]), f"unexpected property {key!r}"))
            continue
        found.append((base, error.message))
    return sorted(set(found))


def json_depth(obj: Any, limit: int | None = None) -> int:
    """How deeply ``obj`` nests arrays and objects (a scalar is 0, ``[]`` is 1), counted
    without recursion; the walk stops once ``limit`` is reached and returns it."""
    return _scan(obj, math.inf if limit is None else limit)[0]


def _scan(obj: Any, limit: float) -> tuple[int, bool]:
    """One iterative walk of ``obj``: how deeply it nests (as :func:`json_depth`; the walk
    stops once ``limit`` is reached) and whether it holds a non-finite float."""
    deepest = 0
    non_finite = False
    todo: list[tuple[Any, int]] = [(obj, 0)]
    while todo:
        node, depth = todo.pop()
        if isinstance(node, float):
            non_finite = non_finite or not math.isfinite(node)
        elif isinstance(node, (dict, list)):
            depth += 1
            if depth > deepest:
                deepest = depth
                if deepest >= limit:
                    return deepest, non_finite
            todo.extend((v, depth) for v in (node.values() if isinstance(node, dict) else node))
    return deepest, non_finite


def _non_finite(obj: Any) -> list[str]:
    """Pointers of the non-finite floats in ``obj`` (iterative: any depth)."""
    found: list[str] = []
    todo: list[tuple[Any, str]] = [(obj, "")]
    while todo:
        node, here = todo.pop()
        if isinstance(node, float) and not math.isfinite(node):
            found.append(here)
        elif isinstance(node, dict):
            todo.extend((v, here + json_pointer([k])) for k, v in node.items())
        elif isinstance(node, list):
            todo.extend((v, f"{here}/{i}") for i, v in enumerate(node))
    return found
