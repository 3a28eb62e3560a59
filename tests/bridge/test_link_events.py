"""Link events seen from outside the bridge, in virtual time: every dropped step's own
fate, ``/diagnostics`` published at once on a link state change, refusals counted on
``/diagnostics``.

The bridge node, its link and the in-process ROS ports run on one lockstep clock against
the controller model over an in-memory serial line (tests/bridge/lockstep_bridge.py):
the same product code as ``rover bridge``, without threads, so a busy machine cannot
starve a watchdog or a subscription here. The same outages over a real pty in real time
(the link's fates on silence, unplug and reboot, and its recovery) are
tests/bridge/test_link.py's ``[pty]`` cases, the node's topics over a pty
tests/bridge/test_node.py's; the transport's and the link's threads,
tests/bridge/test_transport_threads.py.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Iterator
from typing import Any

import pytest

from bridge.ros.diagnostics import ERROR, OK
from bridge.ros.rosport import RosPort, qos
from bridge.ros.rosport.msgs import Bool, DiagnosticArray, String
from firmware_proto.model.rover import RoverDescription

from .lockstep_bridge import LockstepBridge

Rigs = Callable[..., LockstepBridge]


@pytest.fixture
def rigs(rover: RoverDescription) -> Iterator[Rigs]:
    """``rigs(**params)``: a :class:`LockstepBridge` with these bridge parameters, its
    link ready; closed after the test."""
    made: list[LockstepBridge] = []

    def make(**params: Any) -> LockstepBridge:
        made.append(LockstepBridge(rover, **params))
        return made[-1]

    yield make
    for rig in made:
        rig.close()


def values(msg: DiagnosticArray, name: str) -> dict[str, str]:
    """The key/values of the status called ``rover_bridge: <name>``."""
    for status in msg.status:
        if status.name == f"rover_bridge: {name}":
            return {kv.key: kv.value for kv in status.values}
    raise AssertionError(f"no status {name!r} in {[s.name for s in msg.status]}")


def level(msg: DiagnosticArray, name: str) -> bytes:
    return bytes(next(s.level for s in msg.status if s.name == f"rover_bridge: {name}"))


def _delivered(port: RosPort, count: int) -> bool:
    return port.stats().delivered >= count


# -- 1. every dropped step gets its own fate ----------------------------------------------

STEPS = 9
"""More than the controller holds (8), so one waits in the lane."""


@pytest.mark.parametrize(
    ("cause", "fate", "event"),
    [
        ("silence", "aborted:link_lost", "fault:link_lost"),
        ("unplug", "aborted:link_lost", "fault:link_lost"),
        ("reboot", "aborted:controller_reboot", "fault:controller_reboot"),
    ],
)
def test_every_dropped_step_gets_one_fate_in_order(
    rigs: Rigs, cause: str, fate: str, event: str
) -> None:
    rig = rigs(reconnect_min_s=0.05, reconnect_max_s=0.2)
    node, client = rig.node, rig.client
    mark = client.status.mark()
    base = node.port.stats().delivered
    for n in range(STEPS):
        client.step(1, 60, 30000)  # ~1.3 m each: none ends during the test
        rig.run_until(functools.partial(_delivered, node.port, base + n + 1))
        if n < 8:
            client.status.wait_count("accepted", n + 1, since=mark)
    before = client.status.since(mark)
    assert before == ["accepted"] * 8
    held = node.link.diagnostics()
    assert held.steps_sent == 8 and held.steps_aborted == 0, held
    assert rig.model.queue_depth == 8  # one runs, seven wait in the controller
    if cause == "silence":
        rig.line.cut = True  # the controller runs on; none of its frames arrive
    elif cause == "unplug":
        rig.line.unplug()
    else:
        rig.controller.inject("reboot")
    got = client.status.wait(lambda xs: event in xs, since=mark)
    settled = got[len(before) :]
    # One fate per step, in order (in the controller, in flight, the lane), then the event.
    assert settled == [fate] * STEPS + [event], settled
    assert "completed" not in got
    assert client.port.stats().dropped == 0, (client.port.stats(), client.status.since(mark))
    diag = node.link.diagnostics()
    assert diag.steps_aborted == STEPS
    assert diag.steps_sent == 8  # the lane's step was never sent, and never will be
    # The link comes back (a new session): nothing of the old one is settled twice or
    # sent again.
    rest = mark + len(got)
    rig.line.cut = False
    rig.line.replug()
    client.status.wait_count("ready", 1, since=rest)
    rig.run_until(lambda: not rig.model.stop_latched)  # a watchdog latch: the bridge clears it
    after = client.status.since(rest)
    assert fate not in after and "accepted" not in after, after
    assert node.link.diagnostics().steps_sent == 8
    assert rig.model.queue_depth == 0  # none of them runs again
    if cause == "unplug":
        assert node.link.diagnostics().reconnects == 1 and rig.line.opens >= 2


# -- 2. heartbeat loss: fault:link_lost and /diagnostics ERROR within 3 missed beats -------


def test_heartbeat_loss_publishes_error_diagnostics_at_once(rigs: Rigs) -> None:
    # 0.1 Hz: the periodic sample is 10 s away, i.e. some 100 heartbeat periods; every
    # sample below comes from a state change.
    rig = rigs(diagnostics_hz=0.1)
    node, client, diags = rig.node, rig.client, rig.diagnostics
    diags.wait(lambda m: level(m, "link") == OK)  # READY, published on that change
    period_s = node.link.config.controller_heartbeat_s
    assert node.link.config.link_lost_beats == 3
    mark, dmark = client.status.mark(), diags.mark()
    cut_at = rig.clock.now()
    rig.line.cut = True  # the controller runs on; none of its frames arrive
    client.status.wait_count("fault:link_lost", 1, since=mark)
    lost = diags.wait(lambda m: level(m, "link") == ERROR, since=dmark)
    # Published at once: well before the periodic sample (10 s) was due.
    assert rig.clock.now() - cut_at < 5 * period_s
    link = values(lost, "link")
    assert link["state"] == "lost"
    # Counted in beats by the link itself: declared lost once the third beat was overdue,
    # published before a fifth was due.
    assert 3 <= int(link["lost_after_beats"]) <= 4, link
    assert 3 <= int(link["missed_beats"]) <= 4, link
    assert float(link["heartbeat_age_s"]) >= 3 * period_s
    assert link["heartbeat_losses"] == "1"
    assert level(lost, "controller") == ERROR
    # Back: published as it happens too (changes in quick succession may share a sample).
    dmark = diags.mark()
    rig.line.cut = False
    client.status.wait_count("ready", 1, since=mark)
    ready = diags.wait(lambda m: values(m, "link")["state"] == "ready", since=dmark)
    assert level(ready, "link") == OK
    assert rig.clock.now() - cut_at < 10.0  # none of it waited for the periodic sample


# -- 3. refusals counted on /diagnostics ----------------------------------------------------


def test_rejected_steps_are_counted_on_diagnostics(rigs: Rigs) -> None:
    rig = rigs(diagnostics_hz=5.0)
    node, client, diags = rig.node, rig.client, rig.diagnostics
    first = diags.wait(lambda m: True)
    assert values(first, "input")["rejected_total"] == "0"
    assert "rejected_bad_length" not in values(first, "input")
    mark = client.status.mark()
    client.step(1, 30)  # malformed: two values
    client.step(1, 30, 100, 4)  # malformed: four values
    client.status.wait_count("rejected:bad_length", 2, since=mark)
    dmark = diags.mark()
    counted = diags.wait(lambda m: "rejected_bad_length" in values(m, "input"), since=dmark)
    assert values(counted, "input")["rejected_bad_length"] == "2"
    # A refusal by the link (STOP latched) is counted beside the node's own.
    client.estop.publish(Bool(data=True))
    client.status.wait_count("stopped", 1, since=mark)
    client.step(1, 30, 100)
    client.status.wait_count("rejected:stop_latched", 1, since=mark)
    dmark = diags.mark()
    both = values(
        diags.wait(lambda m: "rejected_stop_latched" in values(m, "input"), since=dmark), "input"
    )
    assert (both["rejected_bad_length"], both["rejected_stop_latched"]) == ("2", "1")
    assert both["rejected_total"] == "3"
    assert node.rejected_counts() == {"bad_length": 2}
    assert rig.model.stop_latched and rig.model.queue_depth == 0  # nothing reached it


def test_the_same_outage_plays_the_same_way_every_time(rover: RoverDescription) -> None:
    """Virtual time: two runs of one outage give the same statuses at the same ticks."""

    def play() -> list[tuple[int, str]]:
        with LockstepBridge(rover) as rig:
            seen: list[tuple[int, str]] = []
            rig.client.port.subscribe(
                "command_status",
                String,
                lambda m: seen.append((rig.clock.ticks, m.data)),
                qos.STATUS,
            )
            for _ in range(3):
                rig.client.step(1, 60, 30000)
            rig.clock.sleep(0.5)
            rig.line.cut = True
            rig.clock.sleep(1.0)
            rig.line.cut = False
            rig.clock.sleep(1.0)
            return seen

    first = play()
    assert [text for _, text in first].count("aborted:link_lost") == 3
    assert first == play()
