"""The onboard sequencer and guard (bridge/onboard/core.py) driven event by event in
virtual time: the time is an argument, nothing waits. The whole mission against the
bridge's link core, a controller and its twin is tests/sim/test_mission.py."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import pytest

from bridge.onboard.core import (
    OnboardConfig,
    OnboardCore,
    SayStatus,
    SendAck,
    SendReport,
    SendStep,
    SendStop,
)
from bridge.onboard.ekf import Estimate
from firmware_proto.model.pose import Pose
from firmware_proto.model.rover import load_rover
from firmware_proto.model.uplink import CancelUplink, DriftLimits, PlanUplink, PredictedSample
from firmware_proto.wire.messages import Command

ROVER = load_rover(None)
TOKEN = "t0ken"
FWD = int(Command.FWD)
COV = (1e-4, 0.0, 0.0, 0.0, 1e-4, 0.0, 0.0, 0.0, 1e-4)


def _plan(plan_id: int = 10, steps: int = 3) -> PlanUplink:
    """``steps`` drives of 1 m along +x, 2 s each (0.5 m/s)."""
    samples = []
    for k in range(steps):
        samples += [PredictedSample(k, 0.1 * i, k + 0.05 * i, 0.0, 0.0) for i in range(21)]
    return PlanUplink(
        plan_id,
        tuple((FWD, 30, 23000) for _ in range(steps)),
        tuple(2.0 for _ in range(steps)),
        tuple(samples),
        Pose(0.0, 0.0, 0.0),
        Pose(float(steps), 0.0, 0.0),
        DriftLimits.of(ROVER),
        "b" * 64,
    )


def _est(t: float, x: float, y: float = 0.0, yaw: float = 0.0, v: float = 0.5) -> Estimate:
    return Estimate(t, x, y, yaw, COV, v, 0.0, t - 0.1)


BOOT = "0123456789abcdef" * 2
"""The boot id of the onboard program under test."""


class Rover:
    """The core with the time in hand and every action kept; it starts at rest at the
    origin with a fresh POSE fix (what every plan here starts from)."""

    def __init__(self, *, fix: bool = True, **config: Any) -> None:
        config.setdefault("boot", BOOT)
        self.core = OnboardCore(ROVER, OnboardConfig(token=TOKEN, **config))
        self.t = 0.0
        self.actions: list[Any] = []
        if fix:
            self.do("on_estimate", _est(0.0, 0.0, v=0.0))

    def do(self, fn: str, *args: Any) -> list[Any]:
        getattr(self.core, fn)(*args, self.t)
        out = self.core.take_actions()
        self.actions += out
        return out

    def at(self, t: float) -> None:
        self.t = t

    def uplink(self, plan: PlanUplink | CancelUplink) -> list[Any]:
        """Send ``plan`` signed for this core's boot (unless it names one)."""
        if isinstance(plan, PlanUplink) and not plan.boot:
            plan = dataclasses.replace(plan, boot=self.core.boot)
        return self.do("on_uplink", plan.envelope(TOKEN))

    def status(self, text: str) -> list[Any]:
        return self.do("on_status", text)

    def steps(self) -> list[SendStep]:
        return [a for a in self.actions if isinstance(a, SendStep)]

    def acks(self) -> list[Any]:
        return [a.ack for a in self.actions if isinstance(a, SendAck)]

    def reports(self) -> list[Any]:
        return [a.report for a in self.actions if isinstance(a, SendReport)]

    def drive(self, plan: PlanUplink, upto: int) -> None:
        """Run ``plan``'s steps to ``upto`` completed, on the predicted path."""
        for k in range(upto):
            self.status("accepted")
            start = self.t
            for i in range(1, 21):
                self.at(start + 0.1 * i)
                self.do("on_estimate", _est(self.t, k + 0.05 * i))
            self.status("completed")


def test_a_plan_runs_back_to_back_and_ends_completed_with_a_rest_report() -> None:
    r = Rover()
    plan = _plan()
    out = r.uplink(plan)
    assert [a.ack.result for a in out if isinstance(a, SendAck)] == ["accepted"]
    assert [(s.plan_id, s.index) for s in r.steps()] == [(10, 0)]
    r.drive(plan, 3)
    assert [s.index for s in r.steps()] == [0, 1, 2]
    assert not any(isinstance(a, SendStop) for a in r.actions)
    last = r.reports()[-1]
    assert last.state == "completed" and last.outcome == "completed"
    # at rest: wheels still for rest_hold_s
    for _ in range(4):
        r.at(r.t + 0.1)
        r.do("on_estimate", _est(r.t, 3.0, v=0.0))
    rest = r.reports()[-1].rest
    assert rest is not None and rest.at_rest and rest.pose.x == pytest.approx(3.0)
    assert len(rest.covariance) == 9


def test_copies_are_duplicates_and_run_nothing_again() -> None:
    r = Rover()
    plan = _plan()
    r.uplink(plan)
    r.at(0.5)
    r.uplink(plan)
    r.drive(plan, 3)
    r.uplink(plan)
    assert [a.result for a in r.acks()] == ["accepted", "duplicate", "duplicate"]
    assert r.acks()[-1].state == "completed"
    assert [s.index for s in r.steps()] == [0, 1, 2]


def test_stale_and_replayed_plans_are_refused_with_a_reason_and_drive_nothing() -> None:
    r = Rover()
    r.uplink(_plan(10, 1))
    r.drive(_plan(10, 1), 1)
    before = len(r.steps())
    out = r.uplink(_plan(9, 1))
    assert r.acks()[-1].result == "refused" and r.acks()[-1].reason == "stale"
    assert [a.text for a in out if isinstance(a, SayStatus)] == ["plan_refused:stale:9"]
    floor = Rover(min_plan_id=100)
    floor.uplink(_plan(50, 1))
    assert floor.acks()[-1].reason == "stale"
    assert len(r.steps()) == before and floor.steps() == []


def test_a_plan_while_another_runs_is_busy_until_that_one_is_cancelled() -> None:
    r = Rover()
    r.uplink(_plan(10))
    r.status("accepted")
    r.uplink(_plan(11))
    assert r.acks()[-1].reason == "busy"
    out = r.uplink(CancelUplink(10))
    assert isinstance(out[0], SendStop)  # the running step is stopped first
    assert r.acks()[-1].result == "cancelled" and r.acks()[-1].state == "stopped"
    r.do("on_ground_stop")  # the cancel's STOP heard back: the core's own
    r.status("stopped")
    r.uplink(_plan(10))  # a late copy of the cancelled plan: a duplicate, nothing runs
    assert r.acks()[-1].result == "duplicate"
    r.uplink(_plan(11))
    assert r.acks()[-1].result == "accepted" and r.acks()[-1].state == "armed"
    assert [s.plan_id for s in r.steps()] == [10]  # armed: the latch holds
    r.status("cleared")
    assert [s.plan_id for s in r.steps()] == [10, 11]
    r.uplink(CancelUplink(5))
    assert r.core.active  # a cancel of older plans leaves the running one


def test_a_plan_cancelled_before_it_arrives_is_refused() -> None:
    r = Rover()
    r.uplink(CancelUplink(20))
    r.uplink(_plan(15))
    assert r.acks()[-1].reason == "cancelled" and r.steps() == []


def _guard_stopped(r: Rover, plan_id: int = 10) -> None:
    """Run plan ``plan_id`` and let the guard stop it (the rover slides sideways); its
    STOP heard back and the bridge's ``stopped``: the latch is the core's own."""
    r.uplink(_plan(plan_id))
    r.status("accepted")
    for i in range(1, 8):
        r.at(r.t + 0.1)
        r.do("on_estimate", _est(r.t, 0.05 * i, 0.1 * i))
    assert r.reports()[-1].outcome == "guard"
    r.do("on_ground_stop")  # its own STOP, heard back on emergency_stop
    r.status("stopped")


def test_an_armed_plan_gives_up_when_the_latch_is_not_released() -> None:
    r = Rover(arm_timeout_s=5.0, report_period_s=60.0)
    _guard_stopped(r)
    r.do("on_estimate", _est(r.t, 0.0, v=0.0))
    r.uplink(_plan(11))
    assert (r.acks()[-1].result, r.acks()[-1].state) == ("accepted", "armed")
    t0 = r.t
    assert r.core.next_deadline(r.t) <= t0 + 5.0
    r.at(t0 + 5.0)
    r.do("tick")
    assert r.reports()[-1].state == "failed" and "latch" in r.reports()[-1].reason
    r.status("cleared")
    assert [s.plan_id for s in r.steps()] == [10]


def test_a_plan_after_a_stop_the_core_did_not_send_is_refused_until_the_latch_is_released() -> None:
    """Review A1 (E9): after ``rover stop`` a plan arriving was taken armed and started
    when anyone cleared the latch, up to 30 s later. Only the core's own latch arms a
    plan; any other is ``latched``, for now: the ground resends after the release."""
    r = Rover()
    r.do("on_ground_stop")  # the operator's STOP, heard on emergency_stop
    r.status("stopped")
    out = r.uplink(_plan(40))
    assert (r.acks()[-1].result, r.acks()[-1].reason) == ("refused", "latched")
    assert [a.text for a in out if isinstance(a, SayStatus)] == ["plan_refused:latched:40"]
    r.at(20.0)
    r.status("cleared")
    assert r.steps() == []  # nothing starts by itself when someone clears
    r.do("on_estimate", _est(r.t, 0.0, v=0.0))
    r.uplink(_plan(40))  # the ground's next copy, after the release
    assert r.acks()[-1].result == "accepted" and [s.plan_id for s in r.steps()] == [40]


def test_a_stop_the_core_did_not_send_drops_an_armed_plan_for_good() -> None:
    r = Rover()
    _guard_stopped(r)
    r.do("on_estimate", _est(r.t, 0.0, v=0.0))
    r.uplink(_plan(11))
    assert r.acks()[-1].state == "armed"  # the guard's own latch: it waits
    r.do("on_ground_stop")  # then the operator presses STOP
    report = r.reports()[-1]
    assert (report.plan_id, report.state, report.outcome) == (11, "stopped", "ground_stop")
    r.status("stopped")
    r.status("cleared")
    assert [s.plan_id for s in r.steps()] == [10]  # the armed plan never starts
    r.uplink(_plan(11))
    assert r.acks()[-1].result == "duplicate"
    r.uplink(_plan(12))  # a new plan after the release runs
    assert [s.plan_id for s in r.steps()] == [10, 12]


def test_a_foreign_stop_raises_the_cancel_floor_to_the_newest_plan_taken() -> None:
    r = Rover()
    r.uplink(_plan(10))
    r.status("accepted")
    r.status("stopped")  # a STOP of someone else's (no STOP of the core's explains it)
    assert r.reports()[-1].outcome == "ground_stop"
    r.status("cleared")
    r.uplink(_plan(9))
    r.uplink(_plan(10))
    assert [(a.result, a.reason) for a in r.acks()[-2:]] == [
        ("refused", "cancelled"),  # below the floor
        ("duplicate", ""),
    ]
    assert [s.plan_id for s in r.steps()] == [10]


def test_a_plan_signed_for_another_boot_is_refused_and_drives_nothing() -> None:
    """Review A2 (E6): a plan taken, then ``rover onboard`` restarts: the same signed
    uplink was taken again. Every run has its own boot id and takes only plans signed
    for it."""
    first = Rover(boot="1" * 32)
    plan = dataclasses.replace(_plan(10), boot="1" * 32)
    first.uplink(plan)
    assert first.acks()[-1].result == "accepted" and len(first.steps()) == 1
    again = Rover(boot="2" * 32)  # the program after a restart
    out = again.uplink(plan)
    assert (again.acks()[-1].result, again.acks()[-1].reason) == ("refused", "other_boot")
    assert [a.text for a in out if isinstance(a, SayStatus)] == ["plan_refused:other_boot:10"]
    assert again.steps() == []
    again.do("on_uplink", dataclasses.replace(plan, boot="").envelope(TOKEN))  # no boot
    assert again.acks()[-1].reason == "other_boot" and again.steps() == []


def test_every_report_names_the_boot_and_one_goes_out_before_any_plan() -> None:
    r = Rover(report_period_s=1.0, boot="3" * 32)
    r.do("tick")
    idle = r.reports()[-1]
    assert (idle.event, idle.plan_id, idle.boot) == ("idle", 0, "3" * 32)
    assert r.core.next_deadline(r.t) == pytest.approx(1.0)
    r.uplink(_plan())
    assert {rep.boot for rep in r.reports()} == {"3" * 32}
    assert len(OnboardCore(ROVER).boot) == 32  # a random one when none is given


def test_a_plan_from_elsewhere_or_without_a_fix_is_refused() -> None:
    """Review A2 (E7): a plan whose start is 4 m from the rover was taken and driven;
    and without any POSE the program seeded the estimate at the plan's own start, so the
    guard compared the prediction with itself."""
    r = Rover()
    r.do("on_estimate", _est(0.0, 3.0, 3.0, 90.0, v=0.0))
    r.uplink(_plan(20))
    assert (r.acks()[-1].reason, r.steps()) == ("start_mismatch", [])
    assert "3.00" in r.acks()[-1].detail
    blind = Rover(fix=False)
    blind.uplink(_plan(21))
    assert (blind.acks()[-1].reason, blind.steps()) == ("no_fix", [])
    stale = Rover(fix_fresh_s=1.0)
    stale.at(1.5)  # the last fix is 1.5 s old
    stale.uplink(_plan(22))
    assert stale.acks()[-1].reason == "no_fix"
    stale.do("on_estimate", _est(stale.t, 0.0, v=0.0))
    stale.uplink(_plan(22))  # fix again: the ground's next copy is taken
    assert stale.acks()[-1].result == "accepted"


def test_an_estimate_that_is_not_finite_stops_the_plan_at_once() -> None:
    """Review A4 (E2): NaN estimates made every drift NaN, ``NaN > limit`` was false and
    the guard never fired (1 s of them: no STOP)."""
    r = Rover()
    r.uplink(_plan())
    r.status("accepted")
    r.at(0.02)
    out = r.do("on_estimate", _est(r.t, math.nan, 0.0))
    assert isinstance(out[0], SendStop) and "not finite" in out[0].reason
    report = r.reports()[-1]
    assert report.outcome == "blind" and report.drift_linear_m is None
    report.to_json()  # a report with no NaN in it
    assert r.core.counts["bad_estimates"] == 1
    bad_cov = Estimate(0.1, 0.0, 0.0, 0.0, (math.inf, *COV[1:]), 0.0, 0.0, 0.0)
    assert not bad_cov.finite


def test_the_guard_stops_at_the_limit_and_reports_where_and_at_rest() -> None:
    r = Rover(persistence=3)
    plan = _plan()
    r.uplink(plan)
    r.status("accepted")
    # step 0: sliding sideways, 0.1 m more each 0.1 s
    stop_at = None
    for i in range(1, 10):
        r.at(0.1 * i)
        out = r.do("on_estimate", _est(r.t, 0.05 * i, 0.1 * i))
        if out and isinstance(out[0], SendStop):
            stop_at = i
            break
    # over the limit (0.25 m) from 0.3 m on: 3 estimates persist at i = 5
    assert stop_at == 5
    report = r.reports()[-1]
    assert report.outcome == "guard" and report.state == "stopped"
    assert report.guard is not None and report.guard.step == 0
    assert report.guard.linear_m == pytest.approx(math.hypot(0.0, 0.5), abs=1e-6)
    assert "drift in step 1" in report.reason
    r.status("aborted:stop")
    r.status("stopped")
    assert [s.index for s in r.steps()] == [0]  # the rest of the plan is dropped
    r.do("on_ground_stop")  # its own STOP heard back: nothing more
    for _ in range(4):
        r.at(r.t + 0.1)
        r.do("on_estimate", _est(r.t, 0.27, 0.55, v=0.0))
    rest = r.reports()[-1].rest
    assert rest is not None and rest.moved_m == pytest.approx(math.hypot(0.02, 0.05), abs=1e-6)
    assert rest.time_to_rest_s == pytest.approx(0.1, abs=1e-6)


def _stops(out: list[Any]) -> list[SendStop]:
    return [a for a in out if isinstance(a, SendStop)]


def _guard_stop_unanswered(r: Rover) -> float:
    """Run plan 10 until the guard stops it; no answer yet. Returns when it stopped."""
    r.uplink(_plan(10))
    r.status("accepted")
    for i in range(1, 8):
        r.at(0.1 * i)
        if _stops(r.do("on_estimate", _est(r.t, 0.05 * i, 0.1 * i))):
            return r.t
    raise AssertionError("the guard did not stop")


def test_the_guards_stop_goes_out_again_until_the_bridge_answers_stopped() -> None:
    """Review A7: the STOP was published once; lost, the step ran to its end (1.3 m)."""
    r = Rover(stop_repeat_s=0.25, stop_repeats=8, report_period_s=60.0, rest_timeout_s=60.0)
    t0 = _guard_stop_unanswered(r)
    assert r.core.next_deadline(t0) == pytest.approx(t0 + 0.25)
    r.at(t0 + 0.2)
    assert _stops(r.do("tick")) == []  # not yet
    r.at(t0 + 0.25)
    again = _stops(r.do("tick"))
    assert len(again) == 1 and "again: no 'stopped' yet" in again[0].reason
    r.at(t0 + 0.5)
    assert len(_stops(r.do("tick"))) == 1
    r.status("stopped")  # the bridge answers: no more copies
    r.at(t0 + 0.75)
    assert _stops(r.do("tick")) == []
    assert r.core.next_deadline(r.t) > t0 + 10.0
    assert len(_stops(r.actions)) == 3 and r.core.counts["stop_repeats"] == 2


def test_the_copies_are_bounded_when_no_answer_ever_comes() -> None:
    r = Rover(stop_repeat_s=0.25, stop_repeats=4, report_period_s=60.0, rest_timeout_s=60.0)
    t0 = _guard_stop_unanswered(r)
    for k in range(1, 41):  # ten seconds of ticks
        r.at(t0 + 0.25 * k)
        r.do("tick")
    assert len(_stops(r.actions)) == 1 + 4
    assert r.core.next_deadline(r.t) > r.t + 10.0  # nothing more is due


def test_answers_and_echoes_of_its_copies_are_its_own() -> None:
    """A copy that crossed the first ``stopped`` is answered again, and each copy is
    heard back: none of it is someone else's STOP (which would drop an armed plan)."""
    r = Rover(stop_repeat_s=0.25, report_period_s=60.0)
    t0 = _guard_stop_unanswered(r)
    r.at(t0 + 0.25)
    r.do("tick")  # a copy goes out as the answer to the first comes in
    r.at(t0 + 0.26)
    r.do("on_ground_stop")
    r.status("stopped")
    r.at(t0 + 0.3)
    r.do("on_ground_stop")
    r.status("stopped")  # the copy's own answer
    assert r.core.counts["ground_stops"] == 0
    r.do("on_estimate", _est(r.t, 0.0, v=0.0))  # (back at the plan's start)
    r.uplink(_plan(11))
    assert (r.acks()[-1].result, r.acks()[-1].state) == ("accepted", "armed")


def test_a_lost_stopped_does_not_make_a_later_stop_look_like_its_own() -> None:
    """Review A7: with the answer to its STOP lost, the next controller STOP was taken
    for the core's own and did not end the plan then running."""
    r = Rover(stop_repeat_s=0.25, stop_repeats=2, report_period_s=60.0)
    t0 = _guard_stop_unanswered(r)
    r.do("on_ground_stop")  # its echo; the bridge's 'stopped' is lost, every time
    for k in range(1, 4):
        r.at(t0 + 0.25 * k)
        r.do("tick")
    r.at(t0 + 5.0)
    r.status("cleared")  # the operator releases the latch
    r.do("on_estimate", _est(r.t, 0.0, v=0.0))  # (back at the plan's start)
    r.uplink(_plan(11))
    r.status("accepted")
    assert r.core.running is not None and r.core.running.plan_id == 11
    r.at(t0 + 6.0)
    r.status("stopped")  # a STOP of the controller's (its button), nothing of the core's
    report = r.reports()[-1]
    assert (report.plan_id, report.outcome) == (11, "ground_stop")


def test_an_echo_that_never_came_expires() -> None:
    """An echo of its STOP that never came (lost) does not hide the next STOP of
    someone else's."""
    r = Rover(echo_window_s=1.0, report_period_s=60.0)
    t0 = _guard_stop_unanswered(r)
    r.status("stopped")  # answered, but its echo on emergency_stop never comes
    r.at(t0 + 3.0)
    r.status("cleared")
    r.do("on_estimate", _est(r.t, 0.0, v=0.0))  # (back at the plan's start)
    r.uplink(_plan(11))
    r.status("accepted")
    r.at(t0 + 3.5)
    r.do("on_ground_stop")  # the operator's STOP
    assert (r.reports()[-1].plan_id, r.reports()[-1].outcome) == (11, "ground_stop")


def test_one_estimate_over_the_limit_does_not_stop() -> None:
    r = Rover(persistence=3)
    r.uplink(_plan())
    r.status("accepted")
    for i, y in enumerate((0.0, 0.4, 0.4, 0.0, 0.4, 0.0), 1):
        r.at(0.1 * i)
        r.do("on_estimate", _est(r.t, 0.05 * i, y))
    assert not any(isinstance(a, SendStop) for a in r.actions)


def test_the_ground_stop_ends_the_plan_and_nothing_more_is_sent() -> None:
    r = Rover()
    r.uplink(_plan())
    r.status("accepted")
    r.at(0.5)
    out = r.do("on_ground_stop")
    assert not any(isinstance(a, SendStop) for a in out)  # the bridge has it already
    assert r.reports()[-1].outcome == "ground_stop"
    r.status("aborted:stop")
    r.status("completed")
    assert len(r.steps()) == 1


@pytest.mark.parametrize(
    "status", ["aborted:link_lost", "rejected:stop_latched", "fault:stall_left"]
)
def test_a_failed_step_ends_the_plan_with_stop(status: str) -> None:
    r = Rover()
    r.uplink(_plan())
    r.status("accepted")
    out = r.status(status)
    assert isinstance(out[0], SendStop)
    assert r.reports()[-1].outcome == "failed" and status in r.reports()[-1].reason
    assert len(r.steps()) == 1


@pytest.mark.parametrize(
    ("statuses", "what"),
    [
        (["accepted", "accepted"], "a second 'accepted' for one step"),
        (["accepted", "completed", "completed"], "'completed' before the step was accepted"),
    ],
    ids=["foreign-accepted", "repeated-completed"],
)
def test_a_foreign_step_ends_the_plan_with_stop_instead_of_advancing_it(
    statuses: list[str], what: str
) -> None:
    """Review A13: a step someone else publishes while a plan runs gets an ``accepted``
    and a ``completed`` of its own, which the plan took for its step's and ran on: a
    step skipped. A status that cannot be the fate of the step outstanding ends the plan
    with STOP, and no further step goes out."""
    r = Rover()
    r.uplink(_plan())
    for text in statuses[:-1]:
        r.status(text)
    sent = len(r.steps())
    out = r.status(statuses[-1])
    assert isinstance(out[0], SendStop)
    last = r.reports()[-1]
    assert last.outcome == "failed" and what in last.reason and "foreign_step" in last.reason
    assert len(r.steps()) == sent
    r.status("completed")  # what follows changes nothing
    assert len(r.steps()) == sent


def test_a_lost_sensor_does_not_end_the_plan() -> None:
    r = Rover()
    plan = _plan()
    r.uplink(plan)
    r.status("accepted")
    r.status("fault:pose")
    assert r.core.active and r.reports()[-1].status == "fault:pose"


def test_a_step_without_completed_times_out_and_no_estimate_is_blind() -> None:
    r = Rover(step_margin_s=1.0, blind_s=10.0, report_period_s=60.0)
    r.uplink(_plan())
    r.status("accepted")
    assert r.core.next_deadline(0.0) == pytest.approx(1.5 * 2.0 + 1.0)
    r.at(4.0)
    out = r.do("tick")
    assert isinstance(out[0], SendStop) and r.reports()[-1].outcome == "failed"
    blind = Rover(blind_s=0.5)
    blind.uplink(_plan())
    blind.at(0.5)
    out = blind.do("tick")
    assert isinstance(out[0], SendStop) and blind.reports()[-1].outcome == "blind"


def test_a_plan_stops_blind_when_it_drives_the_linear_limit_without_a_fix() -> None:
    """Review A6: with POSE lost the plan ran on encoders alone (which cannot see a slip
    along the track) to its end."""
    r = Rover(report_period_s=60.0)
    r.uplink(_plan())
    r.status("accepted")
    for i in range(1, 40):  # the last fix at 0.0; 0.5 m/s on the predicted path
        r.at(0.02 * i)
        x = 0.01 * i
        out = r.do("on_estimate", Estimate(r.t, x, 0.0, 0.0, COV, 0.5, 0.0, 0.0, x))
        if _stops(out):
            break
    report = r.reports()[-1]
    assert report.outcome == "blind" and "driven since the last POSE fix" in report.reason
    assert r.t == pytest.approx(0.5 + 0.1, abs=0.021)  # 0.25 m unseen, then the grace


def test_a_pose_read_just_behind_the_odometry_is_no_blindness() -> None:
    """CI (the walkthrough): after a 0.37 s stall of the onboard program the backlog's
    odometry was read before the POSE that covered it, and the plan stopped ``blind``
    with the fix in the queue. A POSE within ``unseen_grace_s`` keeps it going; the
    linear limit unseen for the grace stops it."""
    r = Rover(report_period_s=60.0)
    r.uplink(_plan())
    r.status("accepted")
    r.at(0.4)  # the backlog: odometry 0.3 m past the last fix, read late
    r.do("on_estimate", Estimate(0.35, 0.175, 0.0, 0.0, COV, 0.5, 0.0, 0.0, 0.3))
    r.at(0.45)  # the POSE behind it
    r.do("on_estimate", Estimate(0.35, 0.175, 0.0, 0.0, COV, 0.5, 0.0, 0.3, 0.03))
    r.at(0.5)
    r.do("on_estimate", Estimate(0.5, 0.25, 0.0, 0.0, COV, 0.5, 0.0, 0.4, 0.05))
    assert _stops(r.actions) == [] and r.core.running is not None
    r.at(0.55)  # no POSE since: the limit unseen again, and for the grace
    r.do("on_estimate", Estimate(0.55, 0.275, 0.0, 0.0, COV, 0.5, 0.0, 0.3, 0.26))
    assert _stops(r.actions) == []
    r.at(0.66)
    r.do("on_estimate", Estimate(0.66, 0.33, 0.0, 0.0, COV, 0.5, 0.0, 0.3, 0.32))
    assert len(_stops(r.actions)) == 1 and r.reports()[-1].outcome == "blind"


def test_fresh_fixes_keep_it_going_and_a_turn_without_one_stops_in_time() -> None:
    r = Rover(report_period_s=60.0, pose_gap_s=2.0)
    r.uplink(_plan())
    r.status("accepted")
    for i in range(1, 60):  # 1.2 s with a fix 0.1 s old each time: nothing
        r.at(0.02 * i)
        r.do("on_estimate", _est(r.t, 0.01 * i))
    assert _stops(r.actions) == []
    turning = Rover(report_period_s=60.0, pose_gap_s=2.0, blind_s=10.0)
    samples = tuple(PredictedSample(0, 0.1 * i, 0.0, 0.0, 3.0 * i) for i in range(31))
    spin = PlanUplink(
        10,
        ((int(Command.LEFT), 30, 9000),),
        (3.0,),
        samples,
        Pose(0.0, 0.0, 0.0),
        Pose(0.0, 0.0, 90.0),
        DriftLimits.of(ROVER),
        "b" * 64,
    )
    turning.uplink(spin)
    turning.status("accepted")
    for i in range(1, 150):  # turning in place (no distance), the last fix at 0.0
        turning.at(0.02 * i)
        est = Estimate(turning.t, 0.0, 0.0, 30.0 * turning.t, COV, 0.0, 0.52, 0.0)
        if _stops(turning.do("on_estimate", est)):
            break
    assert "no POSE fix for 2.0 s while moving" in turning.reports()[-1].reason
    assert turning.t == pytest.approx(2.0, abs=0.03)


def test_a_plan_stops_blind_when_the_estimate_is_too_uncertain() -> None:
    r = Rover(report_period_s=60.0)
    r.uplink(_plan())
    r.status("accepted")
    wide = (0.07, 0.0, 0.0, 0.0, 0.07, 0.0, 0.0, 0.0, 1e-4)  # 1-sigma 0.26 m
    out = r.do("on_estimate", Estimate(0.0, 0.0, 0.0, 0.0, wide, 0.0, 0.0, -0.1))
    assert _stops(out) and "position error reached 0.26 m" in r.reports()[-1].reason


def test_bad_uplinks_are_refused_and_the_status_says_why() -> None:
    r = Rover()
    r.do("on_uplink", "garbage")
    r.do("on_uplink", _plan().envelope("wrong token"))
    r.do("on_uplink", _plan().envelope(None))
    assert [(a.result, a.reason) for a in r.acks()] == [
        ("refused", "malformed"),
        ("refused", "bad_tag"),
        ("refused", "unauthenticated"),
    ]
    says = [a.text for a in r.actions if isinstance(a, SayStatus)]
    assert says == [
        "plan_refused:malformed:0",
        "plan_refused:bad_tag:10",
        "plan_refused:unauthenticated:10",
    ]
    assert r.steps() == [] and r.core.counts["refused"] == 3
    r.uplink(_plan())  # and the genuine one still runs
    assert len(r.steps()) == 1


def test_the_latest_report_goes_out_again_every_period() -> None:
    r = Rover(report_period_s=1.0, blind_s=5.0)
    r.uplink(_plan())
    n = len(r.reports())
    assert r.core.next_deadline(0.0) == pytest.approx(1.0)
    r.at(1.0)
    r.do("tick")
    assert len(r.reports()) == n + 1 and r.reports()[-1].event == "periodic"
    assert r.reports()[-1].seq > r.reports()[-2].seq


def test_the_guard_aligns_each_step_on_when_its_wheels_began_to_move() -> None:
    r = Rover()
    plan = _plan()
    r.uplink(plan)
    r.status("accepted")
    r.at(2.0)
    r.status("completed")  # step 1 goes out at 2.0; the bridge holds it until 2.7
    for i in range(36):
        r.at(2.0 + 0.02 * i)
        r.do("on_estimate", _est(r.t, 1.0, v=0.0))
    r.at(2.72)
    r.do("on_estimate", _est(r.t, 1.01))  # the first estimate in motion
    aligned = r.core.predicted_at(3.7)
    assert aligned is not None
    assert aligned[1] == 1 and aligned[2].x == pytest.approx(1.5)
    assert r.core.predicted_at(1.0) is not None and r.core.predicted_at(1.0)[1] == 0  # type: ignore[index]


def test_a_late_accepted_callback_does_not_shift_the_prediction() -> None:
    """Review A5: the step's start was the time the program ran its ``accepted``
    callback; on a busy computer 250-350 ms late, and a turn exactly as predicted was
    stopped for 14 deg of heading error."""
    r = Rover()
    plan = _plan()
    r.uplink(plan)  # published at 0.0; the wheels move from 0.02
    for i in range(1, 30):
        r.at(0.02 * i)
        if i == 18:
            r.status("accepted")  # 0.36 s late
        r.do("on_estimate", _est(r.t, 0.01 * i))  # 0.5 m/s, exactly as predicted
    aligned = r.core.predicted_at(0.5)
    assert aligned is not None and aligned[2].x == pytest.approx(0.25)
    assert _stops(r.actions) == [] and r.core.counts["guard_stops"] == 0
    assert r.core._plan is not None and r.core._plan.worst[0] < 0.02


def test_the_package_exports_are_pinned() -> None:
    import bridge.onboard

    assert bridge.onboard.__all__ == [
        "Action",
        "EkfConfig",
        "Estimate",
        "OnboardConfig",
        "OnboardCore",
        "PlanState",
        "PoseEkf",
        "SayStatus",
        "SendAck",
        "SendReport",
        "SendStep",
        "SendStop",
    ]
