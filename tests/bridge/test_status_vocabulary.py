"""The /command_status vocabulary and topic names of bridge/ros/rosport/contract.py: what the
bridge says and what the executor reads come from one definition."""

from __future__ import annotations

import pytest

from bridge.ros.params import BridgeParams
from bridge.ros.rosport.contract import (
    ACCEPTED,
    CLEARED,
    COMMAND_STATUS,
    COMPLETED,
    READY,
    STOPPED,
    CommandStatus,
    Outcome,
    aborted,
    ends_step,
    fault,
    parse_status,
    rejected,
)
from planner.ground.executor import REPORTING_FAULTS
from planner.ground.relay import DEFAULT_ROUTES


def test_builders_and_parse_are_inverse() -> None:
    assert rejected("out_of_range:speed") == "rejected:out_of_range:speed"
    assert parse_status(rejected("out_of_range:speed")) == CommandStatus(
        "rejected", "out_of_range:speed"
    )
    assert parse_status(aborted("stop")) == CommandStatus(Outcome.ABORTED.value, "stop")
    assert parse_status(fault("link_lost")) == CommandStatus("fault", "link_lost")
    assert parse_status(COMPLETED) == CommandStatus("completed", "")


@pytest.mark.parametrize(
    ("text", "ends"),
    [
        (COMPLETED, True),
        (rejected("queue_full"), True),
        (aborted("watchdog"), True),
        (fault("no_ack"), True),
        (ACCEPTED, False),
        (READY, False),
        (STOPPED, False),
        (CLEARED, False),
        ("completedx", False),
        ("rejectedx:y", False),
    ],
)
def test_which_statuses_end_a_step(text: str, ends: bool) -> None:
    assert ends_step(text) is ends


def test_the_executor_and_the_relay_use_the_bridges_names() -> None:
    assert {"fault:pose", "fault:imu"} == REPORTING_FAULTS
    params = BridgeParams()
    assert params.topic_command_status == COMMAND_STATUS == "command_status"
    assert {route.topic for route in DEFAULT_ROUTES} >= {
        params.topic_wheel_instructions,
        params.topic_emergency_stop,
        params.topic_clear_stop,
        params.topic_command_status,
    }
