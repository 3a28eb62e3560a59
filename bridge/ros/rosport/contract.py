"""The bridge's ROS contract in one place: its topic names and the ``/command_status``
vocabulary, shared by the bridge (which says them) and the ground station's executor,
link relay and demo (which listen). Pure: no ROS import, no I/O.

Topic names are relative: a node's namespace prefixes them (``rover1/command_status``).

``/command_status`` carries one string per event (docs/bridge.md, "``/command_status``"):
a step's fate (:data:`ACCEPTED`, then :data:`COMPLETED` or ``rejected:``, ``aborted:``,
``fault:<reason>``: :func:`rejected`, :func:`aborted`, :func:`fault`), or a link or latch
event (:data:`READY`, :data:`STOPPED`, :data:`CLEARED`, ``fault:<reason>``). Readers take
a string apart with :func:`parse_status` rather than matching prefixes.

The rover's onboard sequencer adds its own topics beside the bridge's
(:data:`PLAN_UPLINK`, :data:`PLAN_ACK`, :data:`ONBOARD_REPORT`, :data:`ONBOARD_POSE`;
docs/onboard.md, "Topics"), and one status: ``plan_refused:<reason>:<plan id>`` when it
refuses an uplink (not a step's fate: :func:`ends_step` is false for it).
"""

from __future__ import annotations

import enum
from typing import Final, NamedTuple

__all__ = [
    "ACCEPTED",
    "CLEARED",
    "CLEAR_EMERGENCY_STOP",
    "COMMAND_STATUS",
    "COMPLETED",
    "EMERGENCY_STOP",
    "ONBOARD_POSE",
    "ONBOARD_REPORT",
    "PLAN_ACK",
    "PLAN_REFUSED",
    "PLAN_UPLINK",
    "READY",
    "STOPPED",
    "WHEEL_INSTRUCTIONS",
    "CommandStatus",
    "Outcome",
    "aborted",
    "ends_step",
    "fault",
    "parse_status",
    "plan_refused",
    "rejected",
]

WHEEL_INSTRUCTIONS: Final = "wheel_instructions"
"""Steps in: ``std_msgs/Int16MultiArray`` ``[command, speed, distance]``."""
COMMAND_STATUS: Final = "command_status"
"""Status out: ``std_msgs/String``, the vocabulary of this module."""
EMERGENCY_STOP: Final = "emergency_stop"
"""Emergency stop in: ``std_msgs/Bool`` true."""
CLEAR_EMERGENCY_STOP: Final = "clear_emergency_stop"
"""Release the STOP latch: ``std_msgs/Empty``."""

PLAN_UPLINK: Final = "plan_uplink"
"""Plans and cancels up to the onboard sequencer: ``std_msgs/String``, an uplink envelope."""
PLAN_ACK: Final = "plan_ack"
"""The onboard sequencer's answer to each uplink message: ``std_msgs/String`` JSON."""
ONBOARD_REPORT: Final = "onboard_report"
"""The onboard sequencer's reports: ``std_msgs/String`` JSON snapshots."""
ONBOARD_POSE: Final = "onboard_pose"
"""The onboard estimate with its covariance: ``nav_msgs/Odometry``, map frame."""

ACCEPTED: Final = "accepted"
COMPLETED: Final = "completed"
READY: Final = "ready"
STOPPED: Final = "stopped"
CLEARED: Final = "cleared"
PLAN_REFUSED: Final = "plan_refused"
"""The kind of status the onboard sequencer says when it refuses an uplink."""


class Outcome(str, enum.Enum):
    """The kinds of status that carry a reason (``<kind>:<reason>``)."""

    REJECTED = "rejected"
    """The step never ran (refused by the bridge, the link or the controller)."""
    ABORTED = "aborted"
    """The step started, or was queued, and was ended early."""
    FAULT = "fault"
    """A fault or link event; while a step runs it ends the step."""


class CommandStatus(NamedTuple):
    """A ``/command_status`` string taken apart: its kind and its reason (``""``: none)."""

    kind: str
    reason: str = ""


def rejected(reason: str) -> str:
    """``rejected:<reason>``."""
    return f"{Outcome.REJECTED.value}:{reason}"


def aborted(reason: str) -> str:
    """``aborted:<reason>``."""
    return f"{Outcome.ABORTED.value}:{reason}"


def fault(reason: str) -> str:
    """``fault:<reason>``."""
    return f"{Outcome.FAULT.value}:{reason}"


def plan_refused(reason: str) -> str:
    """``plan_refused:<reason>`` (the onboard sequencer refused an uplink)."""
    return f"{PLAN_REFUSED}:{reason}"


def parse_status(text: str) -> CommandStatus:
    """Take a status apart at its first ``:`` (``"aborted:stop"`` -> ``("aborted",
    "stop")``; ``"completed"`` -> ``("completed", "")``). Reasons may hold more colons
    (``rejected:out_of_range:speed``)."""
    kind, _, reason = text.partition(":")
    return CommandStatus(kind, reason)


def ends_step(text: str) -> bool:
    """Whether this status ends the step in progress: :data:`COMPLETED`, or any
    rejected, aborted or fault status (a caller that lets some faults pass, as the
    executor does for a lost sensor, checks those first)."""
    return text == COMPLETED or parse_status(text).kind in _OUTCOMES


_OUTCOMES: Final = frozenset({Outcome.REJECTED.value, Outcome.ABORTED.value, Outcome.FAULT.value})
