"""JSON documents checked against a JSON Schema, every violation at its JSON pointer:
what the plan schema (:mod:`firmware_proto.plan`) and the map schema
(:mod:`emulator.worldmap`) report through.

Beyond the schema, numbers must be finite: JSON has no NaN or infinity, but Python's
parser accepts them. An extra property is reported at its own pointer, not its parent's.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Any

from jsonschema import Draft202012Validator

__all__ = ["json_pointer", "schema_violations"]


def json_pointer(path: Iterable[Any]) -> str:
    """The RFC 6901 pointer of a path of keys and indices (``""`` for the root)."""
    return "".join("/" + str(p).replace("~", "~0").replace("/", "~1") for p in path)


def schema_violations(validator: Draft202012Validator, obj: Any) -> list[tuple[str, str]]:
    """Every violation of ``obj`` as ``(json_pointer, message)``, sorted by pointer."""
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


def _non_finite(obj: Any, ptr: str) -> list[str]:
    if isinstance(obj, float) and not math.isfinite(obj):
        return [ptr]
    if isinstance(obj, dict):
        return [p for k, v in obj.items() for p in _non_finite(v, ptr + json_pointer([k]))]
    if isinstance(obj, list):
        return [p for i, v in enumerate(obj) for p in _non_finite(v, f"{ptr}/{i}")]
    return []
