"""The plan check's fast path (firmware_proto/model/schemacheck.py) against jsonschema: the
compiled check passes exactly the documents jsonschema finds no violation in.

The property test kills, among others, these changes to the compiled schema alone: a
limit of speed or distance one off, `speed` a number, `maxItems` 13 or `minItems` 0, a
command enum with `fwd`, `goal` not required, extra goal properties allowed. (A fast
check stricter than jsonschema would change nothing: what it refuses, jsonschema
decides.)"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_proto.model import plan, schemacheck
from firmware_proto.model.plan import _validator, plan_is_valid, plan_schema, validate_plan
from firmware_proto.model.schemacheck import schema_violations

# Values of every JSON kind, near and at the schema's limits, and of the wrong kinds.
_limits = st.sampled_from(
    [0, 60, 61, -1, 30000, 30001, 0.0, 60.0, 61.0, 59.5, -0.5, 30000.5, 2**63, True, False]
)
_scalars = st.one_of(
    _limits,
    _limits,
    _limits,
    st.none(),
    st.integers(-2, 30002),
    st.floats(allow_nan=False, allow_infinity=False),
    st.sampled_from(["STOP", "FWD", "REV", "LEFT", "RIGHT", "fwd", "", "JUMP"]),
)
_values = st.recursive(
    _scalars,
    lambda inner: (
        st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=4), inner, max_size=3)
    ),
    max_leaves=6,
)


_valid_steps = st.fixed_dictionaries(
    {
        "command": st.sampled_from(["STOP", "FWD", "REV", "LEFT", "RIGHT"]),
        "speed": st.integers(0, 60) | st.sampled_from([0.0, 60.0]),
        "distance": st.integers(0, 30000),
    }
)
_valid_plans = st.fixed_dictionaries(
    {
        "goal": st.fixed_dictionaries(
            {"x": st.floats(-10, 10), "y": st.integers(-10, 10), "yaw_deg": st.floats(-180, 180)}
        ),
        "commands": st.lists(_valid_steps, min_size=1, max_size=12),
    }
)


@st.composite
def _mutated(draw: st.DrawFn) -> Any:
    """A valid plan with one of its values (or a key) replaced, added or removed, a
    required property dropped, a step's number (or command) set at or just past a limit
    or to a fraction, or as many steps as allowed, one more, or none."""
    doc: dict[str, Any] = draw(_valid_plans)
    parents: list[Any] = [doc, doc["goal"], doc["commands"], *doc["commands"]]
    parent = draw(st.sampled_from(parents))
    keys = list(parent) if isinstance(parent, dict) else list(range(len(parent)))
    kinds = ["limit", "fraction", "command", "length", "drop", "replace", "add", "remove"]
    how = draw(st.sampled_from(kinds))
    if how == "limit":  # a number at or just past a limit, or of the wrong kind
        step = draw(st.sampled_from(doc["commands"]))
        key, top = draw(st.sampled_from([("speed", 60), ("distance", 30000)]))
        step[key] = draw(st.sampled_from([-1, 0, top, top + 1, float(top), top + 1.0, True]))
    elif how == "fraction":  # in range, but not an integer
        step = draw(st.sampled_from(doc["commands"]))
        step[draw(st.sampled_from(["speed", "distance"]))] = draw(st.floats(0.01, 59.99))
    elif how == "drop":  # a required property missing
        holder = draw(st.sampled_from([doc, doc["goal"], doc["commands"][0]]))
        del holder[draw(st.sampled_from(sorted(holder)))]
    elif how == "command":
        step = draw(st.sampled_from(doc["commands"]))
        step["command"] = draw(st.sampled_from(["fwd", "JUMP", "", "STOP", 1]))
    elif how == "length":  # no step, the most steps, one too many
        size = draw(st.sampled_from([0, 12, 13]))
        doc["commands"] = draw(st.lists(_valid_steps, min_size=size, max_size=size))
    elif how == "replace":
        parent[draw(st.sampled_from(keys))] = draw(_values)
    elif how == "add" and isinstance(parent, dict):
        parent[draw(st.text(max_size=4))] = draw(_values)
    elif how == "add":
        parent.extend(draw(st.lists(_valid_steps | _values, min_size=1, max_size=12)))
    else:
        del parent[draw(st.sampled_from(keys))]
    return doc


_plans = st.one_of(_valid_plans, _mutated(), _values)


def _agrees(doc: Any) -> None:
    slow = schema_violations(_validator(), doc)  # jsonschema alone
    assert validate_plan(doc) == slow  # the fast path first: the same answer
    assert (not list(_validator().iter_errors(doc))) == (
        not [v for v in slow if v[1] != "must be a finite number"]
    )
    assert plan_is_valid(doc) == (slow == [])  # the gate's check on its event loop
    first = validate_plan(doc, limit=2)  # the gate's wording: the first ones only
    assert len(first) <= 2 and set(first) <= set(slow) and bool(first) == bool(slow)


@settings(max_examples=1500, deadline=None, derandomize=True)
@given(_plans)
def test_the_fast_path_agrees_with_jsonschema(doc: Any) -> None:
    _agrees(doc)


@settings(max_examples=150, deadline=None, derandomize=True)
@given(_plans)
def test_the_fast_path_agrees_on_a_quick_sample(doc: Any) -> None:
    """The property above on fewer examples, for the fast lane (tests/lanes.py HEAVY)."""
    _agrees(doc)


def test_the_fast_path_passes_a_valid_plan_and_words_nothing_itself() -> None:
    ok = {
        "goal": {"x": 1, "y": 2.5, "yaw_deg": 0},
        "commands": [{"command": "FWD", "speed": 60, "distance": 30000}],
    }
    assert validate_plan(ok) == []
    bad = {**ok, "commands": [{"command": "FWD", "speed": 61.0, "distance": 1}]}
    assert validate_plan(bad) == [("/commands/0/speed", "61.0 is greater than the maximum of 60")]


def test_the_fast_path_leaves_the_shared_schema_as_it_was(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    pristine = json.loads(
        (Path(plan.__file__).parent / "data" / "command_plan.schema.json").read_text()
    )
    monkeypatch.setattr(schemacheck, "_compiled", {})  # compiled afresh here
    validate_plan({"goal": {}, "commands": []})
    # fastjsonschema rewrites the "$ref"s of the schema it is given
    assert plan_schema() == pristine
