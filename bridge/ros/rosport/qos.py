"""Quality of service of the product's topics, stated once.

A :class:`Qos` is the part of a ROS 2 QoS profile the product chooses (history is always
keep-last); backends translate it, and ``inprocess`` matches as DDS does
(:func:`compatible`). The profiles by topic, and why telemetry is published reliable but
subscribed best effort: docs/rosport.md, "The product's QoS, per topic". A STOP and a
status are never best effort.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

__all__ = [
    "COMMAND",
    "DEFAULT",
    "DIAGNOSTICS",
    "SENSOR",
    "STATUS",
    "STOP",
    "TELEMETRY",
    "Qos",
    "compatible",
]


@dataclass(frozen=True)
class Qos:
    """Reliability, keep-last depth and durability of one endpoint.

    Attributes:
        reliable: reliable (retransmitted) rather than best effort.
        depth: keep-last history depth, >= 1.
        transient_local: late joiners get the last ``depth`` messages.
    """

    reliable: bool = True
    depth: int = 10
    transient_local: bool = False

    def __post_init__(self) -> None:
        if self.depth < 1:
            raise ValueError(f"QoS depth must be >= 1, got {self.depth}")

    def __str__(self) -> str:
        kind = "reliable" if self.reliable else "best_effort"
        durable = ", transient_local" if self.transient_local else ""
        return f"{kind}, keep_last {self.depth}{durable}"


DEFAULT: Final = Qos()
"""ROS 2's default profile: reliable, volatile, keep-last 10."""
COMMAND: Final = Qos(reliable=True, depth=10)
STOP: Final = Qos(reliable=True, depth=10)
STATUS: Final = Qos(reliable=True, depth=100)
"""100: a lost link drops at most 74 steps at once (64 in the bridge's lane, 8 in the
controller, 1 in flight, and the one ``fault:``), each with its own status."""
TELEMETRY: Final = Qos(reliable=True, depth=5)
SENSOR: Final = Qos(reliable=False, depth=5)
DIAGNOSTICS: Final = Qos(reliable=True, depth=10)


def compatible(publisher: Qos, subscription: Qos) -> bool:
    """Whether a subscription with ``subscription`` QoS receives from a publisher with
    ``publisher`` QoS (DDS's request/offer rule for reliability and durability)."""
    if subscription.reliable and not publisher.reliable:
        return False
    return not (subscription.transient_local and not publisher.transient_local)
