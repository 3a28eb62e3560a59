"""``/diagnostics`` for the bridge: the link and the controller, as ROS 2 expects them.

:func:`diagnostic_array` turns a :class:`~bridge.link.controllerlink.LinkDiagnostics`
snapshot into a ``diagnostic_msgs/DiagnosticArray`` with three statuses, ``rover_bridge:
link``, ``rover_bridge: controller`` and ``rover_bridge: input`` (their values and levels:
docs/bridge.md, "Diagnostics"). The input status is always OK: a refusal is the answer to
bad input, not a fault of the bridge.

Pure: builds messages, publishes nothing.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from bridge.link.controllerlink import LinkDiagnostics
from bridge.ros.rosport.msgs import DiagnosticArray, DiagnosticStatus, Header, KeyValue, Time
from firmware_proto.wire.faults import STOPPING_FAULTS
from firmware_proto.wire.messages import FaultCode

__all__ = ["ERROR", "OK", "RECENT_STATUSES", "WARN", "diagnostic_array"]

OK, WARN, ERROR = DiagnosticStatus.OK, DiagnosticStatus.WARN, DiagnosticStatus.ERROR
"""The ROS levels (a ROS ``byte``: one-byte ``bytes`` in rclpy)."""
_STOPPING = {FaultCode(code).name for code in STOPPING_FAULTS}
RECENT_STATUSES = 8
"""How many of the last ``/command_status`` strings the input status carries."""


def _fmt(value: object) -> str:
    if value is None:
        return "n/a"
    if isinstance(value, float):
        return f"{value:.3f}"
    if isinstance(value, tuple):
        return ",".join(str(v) for v in value) or "none"
    return str(value)


def _values(diag: LinkDiagnostics, names: list[str]) -> list[KeyValue]:
    return [KeyValue(key=name, value=_fmt(getattr(diag, name))) for name in names]


def diagnostic_array(
    diag: LinkDiagnostics,
    stamp: Time,
    hardware_id: str = "rover-motor",
    rejected: Mapping[str, int] | None = None,
    statuses: Sequence[str] = (),
) -> DiagnosticArray:
    """The DiagnosticArray for one snapshot.

    Args:
        hardware_id: what the statuses name as their hardware.
        rejected: steps refused by reason, beside those the link counted
            (``diag.rejected``); counts of the same reason add up.
        statuses: the last ``/command_status`` strings published, oldest first (the
            last :data:`RECENT_STATUSES` of them are reported).
    """
    if diag.state in ("disconnected", "lost", "mismatch"):
        link_level, link_msg = (
            ERROR,
            f"link {diag.state}" + (f": {diag.last_error}" if diag.last_error else ""),
        )
    elif diag.state == "handshake":
        link_level, link_msg = WARN, "handshaking"
    elif diag.medium_state not in ("ok", "error_active", "n/a"):
        link_level, link_msg = WARN, f"ready; bus {diag.medium_state}"
    elif diag.no_ack_faults:
        link_level, link_msg = WARN, f"ready; {diag.no_ack_faults} no-ack fault(s) so far"
    else:
        link_level, link_msg = OK, "ready"
    link = DiagnosticStatus(
        level=link_level,
        name="rover_bridge: link",
        message=link_msg,
        hardware_id=hardware_id,
        values=_values(
            diag,
            [
                "state",
                "url",
                "connected",
                "rtt_ms",
                "rtt_median_ms",
                "heartbeat_age_s",
                "missed_beats",
                "lost_after_beats",
                "heartbeat_losses",
                "rx_frames",
                "tx_frames",
                "crc_errors",
                "resyncs",
                "rx_dropped",
                "rx_overflow",
                "lost_frames",
                "retries",
                "no_ack_faults",
                "stop_repeats",
                "reconnects",
                "last_stop_latency_ms",
                "last_error",
                "medium_state",
                "medium_errors",
                "heartbeat_rx_gap_max_ms",
                "heartbeat_rx_gap_p99_ms",
                "heartbeat_tx_gap_max_ms",
                "heartbeat_tx_gap_p99_ms",
                "samples_outside_session",
                "stalls",
                "stall_max_ms",
            ],
        ),
    )
    faults = set(diag.faults)
    latch = ",".join(diag.latch)
    if faults & _STOPPING:
        ctl_level, ctl_msg = ERROR, "fault: " + ",".join(sorted(faults))
        if latch:
            ctl_msg += f"; latched by {latch}"
    elif "fault" in diag.latch:
        what = f" ({diag.latch_fault})" if diag.latch_fault else ""
        ctl_level, ctl_msg = ERROR, f"latched by {latch}{what}: clear_emergency_stop to resume"
    elif diag.latch:
        ctl_level, ctl_msg = WARN, f"latched by {latch}"
    elif diag.stop_latched:
        ctl_level, ctl_msg = WARN, "emergency stop requested"
    elif faults:
        ctl_level, ctl_msg = WARN, "reporting fault: " + ",".join(sorted(faults))
    elif diag.state != "ready":
        ctl_level, ctl_msg = ERROR, "controller not reachable"
    else:
        ctl_level, ctl_msg = OK, diag.controller_state.lower()
    controller = DiagnosticStatus(
        level=ctl_level,
        name="rover_bridge: controller",
        message=ctl_msg,
        hardware_id=hardware_id,
        values=_values(
            diag,
            [
                "controller_state",
                "stop_latched",
                "latch",
                "latch_fault",
                "estop_requested",
                "faults",
                "watchdog_trips",
                "controller_queue",
                "firmware",
                "schema_hash",
                "host_schema_hash",
                "boot_nonce",
                "reboots",
                "last_stopping_distance_mm",
                "steps_sent",
                "steps_completed",
                "steps_rejected",
                "steps_aborted",
            ],
        ),
    )
    counts: dict[str, int] = dict(diag.rejected)
    for reason, count in (rejected or {}).items():
        counts[reason] = counts.get(reason, 0) + count
    total = sum(counts.values())
    inputs = DiagnosticStatus(
        level=OK,
        name="rover_bridge: input",
        message=f"{total} step(s) rejected" if total else "no step rejected",
        hardware_id=hardware_id,
        values=[KeyValue(key="rejected_total", value=str(total))]
        + [KeyValue(key=f"rejected_{r}", value=str(n)) for r, n in sorted(counts.items())]
        + [KeyValue(key="last_statuses", value=",".join(list(statuses)[-RECENT_STATUSES:]))],
    )
    return DiagnosticArray(
        header=Header(stamp=stamp, frame_id=""), status=(link, controller, inputs)
    )
