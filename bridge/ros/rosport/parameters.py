"""Node parameters through the ROS port: declared with a description and a range,
settable at run time where the node can apply them, refused with a reason otherwise.

A node gives :meth:`RosPort.declare_parameters <bridge.ros.rosport.port.RosPort.declare_parameters>`
its :class:`ParameterSpec` list and one ``on_set`` callback. On ``rclpy`` they are real
ROS 2 parameters with a ``ParameterDescriptor``, and rclpy refuses a wrong type or range
itself; ``inprocess`` applies the same checks (:func:`check_value`) in the same order
(docs/rosport.md, "Parameters").

``on_set(changes)`` gets the new values by name, after the type, range and read-only
checks passed; it returns ``None`` to accept them (and must then have applied them) or
a reason to refuse them all.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

__all__ = ["OnSet", "ParameterSpec", "ParameterValue", "check_value"]

ParameterValue = bool | int | float | str
OnSet = Callable[[Mapping[str, Any]], "str | None"]


@dataclass(frozen=True)
class ParameterSpec:
    """One parameter as a node declares it.

    Attributes:
        default: its value unless set at start; its type is the parameter's type
            (``bool``, ``int``, ``float`` or ``str``).
        description: what it is, with its unit.
        read_only: it cannot change once the node runs (it is set at start only).
        range: inclusive bounds for a number.
    """

    name: str
    default: ParameterValue
    description: str = ""
    read_only: bool = False
    range: tuple[float, float] | None = None

    @property
    def kind(self) -> type:
        """The parameter's Python type."""
        return type(self.default)


def check_value(spec: ParameterSpec, value: object) -> str | None:
    """Why ``value`` cannot be ``spec``'s value, or ``None`` when it can: its type (an
    integer is not a double, as in ROS 2) and range (NaN and infinities are in none)."""
    kind = spec.kind
    if kind is float and isinstance(value, int) and not isinstance(value, bool):
        return f"{spec.name} is a double, got the integer {value}"
    if type(value) is not kind:
        return f"{spec.name} must be of type {kind.__name__}, got {type(value).__name__}"
    if isinstance(value, float) and not math.isfinite(value):
        return f"{spec.name} must be finite, got {value}"
    if spec.range is not None and isinstance(value, (int, float)):
        low, high = spec.range
        if not low <= value <= high:
            return f"{spec.name} must be in {low:g}..{high:g}, got {value}"
    return None
