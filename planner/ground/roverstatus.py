"""The rover's state as the bridge reports it on ``/diagnostics``, read for an operator.

:func:`from_diagnostics` takes the bridge's ``diagnostic_msgs/DiagnosticArray`` apart
(its three statuses, ``rover_bridge: link``, ``rover_bridge: controller`` and
``rover_bridge: input``: docs/bridge.md, Diagnostics) into a :class:`RoverStatus`;
:meth:`RoverStatus.text` is what ``rover status`` prints, :meth:`RoverStatus.as_dict`
what ``rover status --json`` prints. Pure: no ROS calls, no I/O (the message is any
object with the generated class's fields).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

__all__ = ["LEVELS", "STOPPING_FAULT_NAMES", "RoverStatus", "from_diagnostics"]

LEVELS = {0: "OK", 1: "WARN", 2: "ERROR", 3: "STALE"}
"""``diagnostic_msgs/DiagnosticStatus`` levels by value."""
STOPPING_FAULT_NAMES = frozenset(
    {"WATCHDOG", "STALL_LEFT", "STALL_RIGHT", "ENCODER", "DRIVER", "INTERNAL"}
)
"""Controller faults that stop the rover and hold its latch (docs/protocol.md); IMU, POSE report."""

_PARTS = {"rover_bridge: link": "link", "rover_bridge: controller": "controller"}
_PARTS["rover_bridge: input"] = "input"


def _level(value: Any) -> int:
    """A ROS ``byte`` level (one-byte ``bytes`` in rclpy) or an int."""
    if isinstance(value, (bytes, bytearray)):
        return value[0] if value else 0
    return int(value)


def _items(text: str) -> tuple[str, ...]:
    """A comma-separated value (``"none"``, ``"n/a"`` and ``""``: nothing)."""
    if text in ("", "none", "n/a"):
        return ()
    return tuple(item for item in text.split(",") if item)


@dataclass(frozen=True)
class RoverStatus:
    """One ``/diagnostics`` message of the bridge, by part.

    Attributes:
        values: per part (``link``, ``controller``, ``input``), its key/value pairs as
            the bridge wrote them (text).
        levels: per part, its level (0 OK, 1 WARN, 2 ERROR).
        messages: per part, its one-line message.
        stamp_s: the message's header stamp, s since the epoch.
    """

    values: Mapping[str, Mapping[str, str]]
    levels: Mapping[str, int]
    messages: Mapping[str, str]
    stamp_s: float = 0.0

    def _get(self, part: str, key: str) -> str:
        return self.values.get(part, {}).get(key, "")

    @property
    def link_state(self) -> str:
        """``ready``, ``handshake``, ``disconnected``, ``lost`` or ``mismatch``."""
        return self._get("link", "state")

    @property
    def controller_state(self) -> str:
        """``BOOT``, ``IDLE``, ``EXECUTING``, ``STOP_LATCHED`` or ``FAULT``."""
        return self._get("controller", "controller_state")

    @property
    def latch(self) -> tuple[str, ...]:
        """What holds the latch: ``stop``, ``watchdog``, ``fault`` (empty: released)."""
        return _items(self._get("controller", "latch"))

    @property
    def latched(self) -> bool:
        """The controller's STOP latch is set (whatever holds it)."""
        return bool(self.latch) or self._get("controller", "stop_latched") == "True"

    @property
    def latch_fault(self) -> str:
        """The last stopping fault other than WATCHDOG the controller raised, or ``""``."""
        return self._get("controller", "latch_fault")

    @property
    def faults(self) -> tuple[str, ...]:
        """The fault conditions active now (not the latch)."""
        return _items(self._get("controller", "faults"))

    @property
    def stopping_faults(self) -> tuple[str, ...]:
        """The active conditions that stop the rover and keep the latch."""
        return tuple(f for f in self.faults if f in STOPPING_FAULT_NAMES)

    @property
    def statuses(self) -> tuple[str, ...]:
        """The bridge's last ``command_status`` strings, oldest first."""
        return _items(self._get("input", "last_statuses"))

    @property
    def ready(self) -> bool:
        """The rover takes steps: the link is ready, nothing latched, no stopping fault."""
        return self.link_state == "ready" and not self.latched and not self.stopping_faults

    def why_held(self) -> list[str]:
        """Why the rover would refuse a step now, one sentence each, with the way out;
        empty when :attr:`ready`."""
        out: list[str] = []
        state = self.link_state
        if state != "ready":
            error = self._get("link", "last_error")
            out.append(
                f"the bridge has no link to the controller (link {state}"
                + (f": {error}" if error and error != "n/a" else "")
                + "); steps are rejected:link_down until it is back"
            )
        for fault in self.stopping_faults:
            out.append(
                f"fault condition {fault} is active: it stops the rover, and the latch cannot "
                "be released while it lasts"
            )
        latch = self.latch
        if "fault" in latch:
            what = f" ({self.latch_fault})" if self.latch_fault else ""
            out.append(
                f"latched by a fault{what}: release it with 'rover clear-stop' once no fault "
                "condition is active"
            )
        if "stop" in latch:
            out.append("latched by an emergency stop: release it with 'rover clear-stop'")
        if "watchdog" in latch:
            out.append(
                "latched by the controller's watchdog (the host's heartbeats stopped for "
                "250 ms): the bridge releases it itself once the link is back, or 'rover "
                "clear-stop'"
            )
        if self.latched and not latch:
            out.append("latched (emergency stop requested): release it with 'rover clear-stop'")
        return out

    def text(self, where: str = "") -> str:
        """The readable report ``rover status`` prints (several lines, no newline at the end)."""
        link, ctl = self.values.get("link", {}), self.values.get("controller", {})
        inputs = self.values.get("input", {})
        verdict = "READY: steps are accepted" if self.ready else "HELD: steps are refused"
        lines = [f"rover status{f' ({where})' if where else ''}: {verdict}"]
        rtt = link.get("rtt_ms", "n/a")
        lines.append(
            f"  link        {LEVELS.get(self.levels.get('link', 0), '?'):5} "
            f"{self.messages.get('link', '')} (device {link.get('url', '?')}, rtt {rtt} ms, "
            f"heartbeat {link.get('heartbeat_age_s', 'n/a')} s ago, "
            f"{link.get('missed_beats', '0')} missed)"
        )
        lines.append(
            f"  controller  {LEVELS.get(self.levels.get('controller', 0), '?'):5} "
            f"{self.controller_state or '?'}: {self.messages.get('controller', '')}"
        )
        lines.append(
            "  latch       "
            + (", ".join(self.latch) if self.latch else ("set" if self.latched else "released"))
            + (f" (last stopping fault: {self.latch_fault})" if self.latch_fault else "")
        )
        lines.append("  faults      " + (", ".join(self.faults) or "none active"))
        statuses = self.statuses
        lines.append(
            "  statuses    "
            + (", ".join(statuses) + "  (oldest first)" if statuses else "none yet")
        )
        rejected = {
            k[len("rejected_") :]: v
            for k, v in inputs.items()
            if k.startswith("rejected_") and k != "rejected_total"
        }
        lines.append(
            f"  steps       sent {ctl.get('steps_sent', '?')}, completed "
            f"{ctl.get('steps_completed', '?')}, rejected {inputs.get('rejected_total', '?')}"
            + (" (" + ", ".join(f"{k} {v}" for k, v in sorted(rejected.items())) + ")")
            * bool(rejected)
            + f", aborted {ctl.get('steps_aborted', '?')}"
        )
        lines.append(
            f"  counters    watchdog trips {ctl.get('watchdog_trips', '?')}, reboots "
            f"{ctl.get('reboots', '?')}, reconnects {link.get('reconnects', '?')}, link losses "
            f"{link.get('heartbeat_losses', '?')}, crc errors {link.get('crc_errors', '?')}, "
            f"retries {link.get('retries', '?')}, last STOP latency "
            f"{link.get('last_stop_latency_ms', 'n/a')} ms"
        )
        for reason in self.why_held():
            lines.append(f"  why         {reason}")
        return "\n".join(lines)

    def as_dict(self) -> dict[str, Any]:
        """Everything, for ``--json``: the parts' values, levels and messages, and the
        derived fields."""
        return {
            "ready": self.ready,
            "link_state": self.link_state,
            "controller_state": self.controller_state,
            "latched": self.latched,
            "latch": list(self.latch),
            "latch_fault": self.latch_fault,
            "faults": list(self.faults),
            "statuses": list(self.statuses),
            "why_held": self.why_held(),
            "levels": {k: LEVELS.get(v, str(v)) for k, v in self.levels.items()},
            "messages": dict(self.messages),
            "values": {k: dict(v) for k, v in self.values.items()},
            "stamp_s": self.stamp_s,
        }


def from_diagnostics(msg: Any) -> RoverStatus:
    """The bridge's statuses of one ``DiagnosticArray`` (``ValueError``: it holds none,
    being another node's)."""
    values: dict[str, dict[str, str]] = {}
    levels: dict[str, int] = {}
    messages: dict[str, str] = {}
    for status in msg.status:
        part = _PARTS.get(status.name)
        if part is None:
            continue
        values[part] = {kv.key: kv.value for kv in status.values}
        levels[part] = _level(status.level)
        messages[part] = status.message
    if not values:
        raise ValueError("not the bridge's diagnostics (no rover_bridge status)")
    stamp = msg.header.stamp
    return RoverStatus(values, levels, messages, stamp.sec + stamp.nanosec / 1e9)
