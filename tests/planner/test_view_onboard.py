"""The live view of a plan run on board (planner/view/hub.py, docs/view.md): the uplink
and the rover's answers in the log, its reports as ``onboard`` events, and where and
why its guard stopped it as a STOP marker. Virtual time, no thread, no HTTP."""

from __future__ import annotations

import json

from bridge.ros.rosport.msgs import String
from firmware_proto.model.downlink import GuardStop, OnboardReport, RestReport
from firmware_proto.model.pose import Pose
from firmware_proto.model.uplink import UplinkAck
from planner.view import ViewHub
from tests.planner.test_view_hub import WORLD, Clock, _all_events


def _report(seq: int, **fields: object) -> String:
    base = OnboardReport(seq, "step", 10.0 + seq, 42, "c" * 64, "running", 1, 3, "accepted")
    return String(data=base.with_(**fields).to_json())


def test_a_guard_stop_on_board_is_drawn_where_and_why() -> None:
    clock = Clock()
    hub = ViewHub(WORLD, rtt_s=3.0, clock=clock)
    client = hub.subscribe()
    body = json.dumps({"type": "plan", "plan_id": 42, "steps": [[1, 30, 9000]]})
    uplink = json.dumps({"body": body, "tag": None})
    for _ in range(3):  # resent until answered: logged once
        hub.tap("sent", "/ground/plan_uplink", String(data=uplink))
    hub.tap("received", "/ground/plan_ack", String(data=UplinkAck(42, "accepted").to_json()))
    hub.tap("received", "/ground/onboard_report", _report(1))
    guard = GuardStop(1, 12.0, 12.001, Pose(2.0, 3.3, 20.0), Pose(2.0, 3.0, 0.0), 0.3, 20.0, 0.05)
    rest = RestReport(
        12.3, Pose(2.02, 3.33, 21.0), (1e-4, 0, 0, 0, 1e-4, 0, 0, 0, 1e-4), True, 0.04, 0.3
    )
    stopped = _report(2, state="stopped", outcome="guard", reason=guard.reason, guard=guard)
    hub.tap("received", "/ground/onboard_report", stopped)
    rested = _report(
        3, state="stopped", outcome="guard", reason=guard.reason, guard=guard, rest=rest
    )
    hub.tap("received", "/ground/onboard_report", rested)
    clock.now += 0.1
    hub.pump()
    events = _all_events(client)
    log = [data["line"] for kind, data in events if kind == "log"]
    assert log.count("uplink: plan 42 (1 steps) sent to the rover") == 1
    assert "rover: plan 42 accepted" in log
    assert any(
        line.startswith("rover: STOP by its guard at (2.00, 3.30): drift in step 2") for line in log
    )
    assert any("at rest (2.02, 3.33, 21 deg)" in line for line in log)
    stops = [data for kind, data in events if kind == "stop"]
    assert [s["at"] for s in stops] == [[2.0, 3.3]] and "guard on board" in stops[0]["source"]
    state = hub.state()
    assert state["onboard"]["outcome"] == "guard" and state["onboard"]["rest"] is not None
    assert [s["at"] for s in state["stops"]] == [[2.0, 3.3]]
