"""What the operator is told when a mission ends because the link to the controller
failed: which process of the stack stalled, and for how long (docs/realtime.md).

A mission that ends on ``fault:watchdog``, ``fault:link_lost`` or ``fault:no_ack`` most
often means a process was starved of the CPU. Every program of the stack logs its stalls
to a shared stall log (:mod:`firmware_proto.runtime.stall`); :func:`stall_report` reads
the ones during the mission.
"""

from __future__ import annotations

from pathlib import Path

from firmware_proto.runtime.stall import describe_stalls, read_stalls
from planner.ground.mission import MissionReport

__all__ = ["LINK_FAULTS", "ended_on_link_fault", "stall_report"]

LINK_FAULTS = ("watchdog", "link_lost", "no_ack")
"""The ``fault:``/``aborted:`` reasons that mean the link to the controller failed."""


def ended_on_link_fault(report: MissionReport) -> bool:
    """The mission stopped short because the link to the controller failed."""
    if report.reached or report.cancelled:
        return False
    texts = [report.reason] + [
        f"{run.execution.outcome} {run.execution.reason}" for run in report.runs
    ]
    return any(f":{name}" in text for text in texts for name in LINK_FAULTS)


def stall_report(
    report: MissionReport,
    *,
    since_wall_s: float,
    stall_log: Path | None,
    threshold_s: float,
    logs: Path | None = None,
) -> list[str]:
    """Lines for the operator when ``report`` ended on a link fault (else none): the
    stalls logged since ``since_wall_s`` (``time.time()``), longest first, or that no
    process stalled longer than ``threshold_s``; and where the processes' logs are."""
    if not ended_on_link_fault(report):
        return []
    lines = ["the link to the controller failed; stalls of the stack's processes:"]
    stalls = read_stalls(stall_log, since_wall_s)
    lines += [f"  {line}" for line in describe_stalls(stalls, threshold_s)]
    if stall_log is not None:
        lines.append(f"  stall log: {stall_log}")
    if logs is not None:
        lines.append(f"  the processes' logs: {logs}")
    return lines
