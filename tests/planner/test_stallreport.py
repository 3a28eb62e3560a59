"""A mission that ends because the link to the controller failed says which process of
the stack stalled (planner/stack/stallreport.py; docs/realtime.md)."""

from __future__ import annotations

import json
from pathlib import Path

from firmware_proto.model.pose import Pose
from firmware_proto.runtime.stall import StallRecord
from planner.ground.mission import MissionReport
from planner.stack.stallreport import ended_on_link_fault, stall_report


def _report(reached: bool, reason: str, cancelled: bool = False) -> MissionReport:
    pose = Pose(0.0, 0.0, 0.0)
    return MissionReport(pose, pose, (), (), reached, reason, None, None, None, 1.0, 0.0, cancelled)


def test_only_a_link_fault_asks_for_the_stalls() -> None:
    assert ended_on_link_fault(_report(False, "step 2/7: fault:watchdog"))
    assert ended_on_link_fault(_report(False, "step 1: aborted:link_lost"))
    assert ended_on_link_fault(_report(False, "step 3: fault:no_ack"))
    assert not ended_on_link_fault(_report(True, ""))
    assert not ended_on_link_fault(_report(False, "collision with 'table'"))
    assert not ended_on_link_fault(_report(False, "step 1: fault:watchdog", cancelled=True))


def test_the_report_names_the_stalled_process_and_the_logs(tmp_path: Path) -> None:
    log = tmp_path / "stalls.jsonl"
    old = StallRecord("gate", 7, "*", 900.0, 10.0)  # before the mission: not counted
    stall = StallRecord("bridge", 12, "link-timer", 312.0, 100.0, "stack")
    log.write_text("".join(json.dumps(r.__dict__) + "\n" for r in (old, stall)))
    lines = stall_report(
        _report(False, "step 2/7: fault:watchdog"),
        since_wall_s=50.0,
        stall_log=log,
        threshold_s=0.1,
        logs=tmp_path,
    )
    assert lines[0] == "the link to the controller failed; stalls of the stack's processes:"
    assert lines[1].startswith("  stall: bridge (pid 12): thread link-timer stalled 312 ms")
    assert not any("gate" in line for line in lines)
    assert lines[-2:] == [f"  stall log: {log}", f"  the processes' logs: {tmp_path}"]
    none = stall_report(
        _report(False, "step 1: fault:link_lost"),
        since_wall_s=200.0,
        stall_log=log,
        threshold_s=0.1,
    )
    assert none[1] == "  no process of the stack on this host stalled longer than 100 ms"
    assert stall_report(_report(True, ""), since_wall_s=0, stall_log=log, threshold_s=0.1) == []
