"""Command plans: the thesis's Listing 1 schema, validation and the wire form.

A plan is ``{"goal": {x, y, yaw_deg}, "commands": [{command, speed, distance}, ...]}``
(docs/architecture.md, Contracts 1), checked against ``data/command_plan.schema.json``
(the one copy every part uses); violations come with their JSON pointers.
:meth:`PlanStep.to_wire` gives the ``[command, speed, distance]`` integers of
``/wheel_instructions`` (Contracts 2).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import TYPE_CHECKING, Any

from firmware_proto.errors import PlanError
from firmware_proto.model.pose import Pose
from firmware_proto.wire.messages import Command

if TYPE_CHECKING:
    from jsonschema import Draft202012Validator

__all__ = [
    "COMMAND_NAMES",
    "MAX_PLAN_STEPS",
    "Goal",
    "Plan",
    "PlanStep",
    "plan_is_valid",
    "plan_schema",
    "validate_plan",
]

MAX_PLAN_STEPS = 12
COMMAND_NAMES: dict[int, str] = {int(c): c.name for c in Command}
"""Command code -> schema name (``1 -> "FWD"``)."""


@cache
def plan_schema() -> dict[str, Any]:
    """The plan JSON schema (Listing 1) as a dict. Do not mutate it."""
    text = (Path(__file__).resolve().parent / "data" / "command_plan.schema.json").read_text()
    schema: dict[str, Any] = json.loads(text)
    return schema


@cache
def _validator() -> Draft202012Validator:
    from jsonschema import Draft202012Validator  # noqa: PLC0415 - on first use: most never do

    return Draft202012Validator(plan_schema())


def validate_plan(obj: Any, *, limit: int | None = None) -> list[tuple[str, str]]:
    """Every schema violation of ``obj`` as ``(json_pointer, message)``, sorted by pointer
    (with ``limit``, the first that many found); non-finite numbers are violations too."""
    from firmware_proto.model.schemacheck import schema_violations  # noqa: PLC0415 - jsonschema

    return schema_violations(_validator(), obj, fast=True, limit=limit)


def plan_is_valid(obj: Any) -> bool:
    """Whether ``obj`` is a valid plan (:func:`validate_plan` would find nothing), decided by
    the compiled check alone, which stops at the first violation."""
    from firmware_proto.model.schemacheck import is_valid  # noqa: PLC0415 - jsonschema

    return is_valid(_validator(), obj)


Goal = Pose
"""A plan's goal: a :class:`~firmware_proto.model.pose.Pose` (map frame, m; yaw deg CCW of +x)."""


@dataclass(frozen=True)
class PlanStep:
    """One step: command name, speed units 0..60, distance units 0..30000."""

    command: str
    speed: int
    distance: int

    @property
    def code(self) -> int:
        """Command code (STOP 0, FWD 1, REV 2, LEFT 3, RIGHT 4)."""
        return int(Command[self.command])

    def to_wire(self) -> tuple[int, int, int]:
        """``(command, speed, distance)`` as sent on ``/wheel_instructions``."""
        return (self.code, self.speed, self.distance)

    @classmethod
    def from_wire(cls, command: int, speed: int, distance: int) -> PlanStep:
        """Inverse of :meth:`to_wire` (no range check; validate the plan for that)."""
        return cls(COMMAND_NAMES[command], speed, distance)


@dataclass(frozen=True)
class Plan:
    """A validated command plan."""

    goal: Goal
    commands: tuple[PlanStep, ...]

    @classmethod
    def from_dict(cls, obj: Any, *, checked: bool = False) -> Plan:
        """Validate and build a plan; with ``checked``, the caller has found ``obj``
        valid already (:func:`plan_is_valid`) and it is only built.

        Raises:
            PlanError: with ``violations``, one ``(json_pointer, message)`` each.
        """
        violations = [] if checked else validate_plan(obj)
        if violations:
            raise PlanError(violations)
        goal = obj["goal"]
        return cls(
            Goal(float(goal["x"]), float(goal["y"]), float(goal["yaw_deg"])),
            tuple(
                PlanStep(c["command"], int(c["speed"]), int(c["distance"])) for c in obj["commands"]
            ),
        )

    @classmethod
    def from_json(cls, text: str | bytes) -> Plan:
        """Parse and validate plan JSON.

        Raises:
            PlanError: not JSON (pointer ``""``), or schema violations.
        """
        try:
            obj = json.loads(text)
        except (ValueError, UnicodeDecodeError, RecursionError) as exc:
            raise PlanError([("", f"not valid JSON: {exc}")]) from exc
        return cls.from_dict(obj)

    def to_dict(self) -> dict[str, Any]:
        """The plan as schema-valid plain data."""
        return {
            "goal": {"x": self.goal.x, "y": self.goal.y, "yaw_deg": self.goal.yaw_deg},
            "commands": [
                {"command": s.command, "speed": s.speed, "distance": s.distance}
                for s in self.commands
            ],
        }

    def to_json(self) -> str:
        """Compact JSON text of :meth:`to_dict`."""
        return json.dumps(self.to_dict(), separators=(",", ":"))

    def to_wire(self) -> list[tuple[int, int, int]]:
        """Every step as ``(command, speed, distance)``."""
        return [s.to_wire() for s in self.commands]
