"""The executor's time rules for one step, in virtual time (planner/ground/stepwatch.py): the
same rules tests/planner/test_executor.py checks in real time, here at any moment."""

from __future__ import annotations

import pytest

from planner.ground.stepwatch import WAIT_SLICE_S, StepWatch


def _watch(blind: float | None = 4.0) -> StepWatch:
    # Published at t=10, 6 s to complete, progress every second, blind after 4 s.
    return StepWatch(10.0, 6.0, 1.0, blind, plan_started_s=9.0)


def test_the_step_times_out_at_its_deadline_and_waits_in_slices_until_then() -> None:
    w = _watch()
    assert not w.expired(15.999) and w.expired(16.0)
    assert w.wait_s(10.0) == WAIT_SLICE_S
    assert w.wait_s(15.95) == pytest.approx(0.05)
    assert w.wait_s(17.0) == 0.0


def test_published_then_accepted_once_then_running_every_period() -> None:
    w = _watch()
    assert w.poll(10.5, last_pose_s=10.4, accepted_s=None).report is None
    said = w.poll(11.0, last_pose_s=10.9, accepted_s=None)
    assert said.report == "published"  # never 'running' before the rover confirmed it
    said = w.poll(11.3, last_pose_s=11.2, accepted_s=11.2)
    assert (said.report, said.accepted_now, said.started_s) == ("accepted", True, 10.6)
    assert w.poll(11.4, last_pose_s=11.3, accepted_s=11.2).report is None
    said = w.poll(12.3, last_pose_s=12.2, accepted_s=11.2)
    assert (said.report, said.accepted_now) == ("running", False)
    assert w.poll(12.5, last_pose_s=12.4, accepted_s=11.2).report is None
    assert w.next_due_s() == pytest.approx(13.3)


def test_no_pose_for_the_blind_limit_ends_the_step_blind() -> None:
    w = _watch()
    assert w.poll(12.9, last_pose_s=0.0, accepted_s=None).end is None  # counts from 9.0
    assert w.poll(13.01, last_pose_s=0.0, accepted_s=None).end == "blind"
    assert _watch().poll(13.01, last_pose_s=12.0, accepted_s=None).end is None
    assert _watch(blind=None).poll(100.0, last_pose_s=0.0, accepted_s=None).end is None
