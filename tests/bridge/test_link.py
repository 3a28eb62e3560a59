"""ControllerLink against the real emulator, over a real pty and a python-can bus
(``virtual`` here; ``socketcan`` on ``vcan0`` where the kernel has it). Tests that make
sense on every medium are parametrized over :data:`~tests.bridge.conftest.MEDIA`."""

from __future__ import annotations

import math
import threading
from collections.abc import Callable
from pathlib import Path

import pytest

from bridge.errors import TransportError
from bridge.link.controllerlink import ControllerLink, LinkConfig, LinkState, StepRequest
from bridge.link.transport import open_transport
from emulator.engine import Emulator
from emulator.errors import InjectionError
from emulator.serial_frontend import SerialFrontEnd
from firmware_proto.linkio.errors import LinkUrlError
from firmware_proto.linkio.urls import parse_can_url
from firmware_proto.model.rover import RoverDescription
from firmware_proto.wire.messages import SCHEMA_HASH, Command, Encoders

from .conftest import MEDIA, Links, Recorder, link_url, serve, wait_emulator

Emus = Callable[..., Emulator]
FWD = Command.FWD


def _serial(emu: Emulator) -> SerialFrontEnd:
    assert isinstance(emu.frontend, SerialFrontEnd)
    return emu.frontend


@pytest.mark.parametrize("kind", MEDIA)
def test_steps_complete_once_each_in_order(
    emulators: Emus, links: Links, kind: str, can_channel: str
) -> None:
    emu = serve(emulators, kind, can_channel, node=3)
    link, rec = links(link_url(emu))
    rec.wait_count("ready", 1)
    # 0.1 m each: the order and the count are the test, not the distance (at 0.25 m each
    # it took 4-5 s in the VM, whose software CPU plays the emulator; 3 s now).
    for _ in range(4):
        link.submit_step(StepRequest(FWD, 60, 2300))
    got = rec.wait_count("completed", 4)
    assert got[0] == "ready"
    assert (got.count("accepted"), got.count("completed"), len(got)) == (4, 4, 9)
    assert emu.status().x_m == pytest.approx(0.4, abs=0.015)
    diag = link.diagnostics()
    assert (diag.steps_sent, diag.steps_completed, diag.retries) == (4, 4, 0)
    assert diag.rtt_median_ms is not None
    # How regularly the two ends heard each other (docs/realtime.md).
    rx_max, rx_p99 = diag.heartbeat_rx_gap_max_ms, diag.heartbeat_rx_gap_p99_ms
    tx_max, tx_p99 = diag.heartbeat_tx_gap_max_ms, diag.heartbeat_tx_gap_p99_ms
    assert rx_max is not None and rx_p99 is not None and 0 < rx_p99 <= rx_max
    assert tx_max is not None and tx_p99 is not None and 0 < tx_p99 <= tx_max


@pytest.mark.parametrize("kind", MEDIA)
def test_stop_lane_latches_and_clear_resumes(
    emulators: Emus, links: Links, kind: str, can_channel: str
) -> None:
    emu = serve(emulators, kind, can_channel)
    link, rec = links(link_url(emu))
    rec.wait_count("ready", 1)
    link.submit_step(StepRequest(FWD, 60, 30000))
    link.submit_step(StepRequest(FWD, 60, 30000))
    rec.wait_count("accepted", 1)
    mark = rec.mark()
    link.emergency_stop()
    got = rec.wait(lambda xs: "stopped" in xs and xs.count("aborted:stop") >= 2, since=mark)
    assert "completed" not in got
    assert link.stop_latched
    mark = rec.mark()
    link.submit_step(StepRequest(FWD, 10, 10))
    assert rec.wait(bool, since=mark) == ["rejected:stop_latched"]
    link.clear_stop()
    rec.wait_count("cleared", 1, since=mark)
    link.submit_step(StepRequest(FWD, 60, 2300))
    rec.wait_count("completed", 1, since=mark)
    assert link.diagnostics().last_stop_latency_ms is not None
    assert emu.status().stop_latched is False


def test_stop_step_is_an_emergency_stop(emulators: Emus, links: Links) -> None:
    emu = emulators()
    link, rec = links(link_url(emu))
    rec.wait_count("ready", 1)
    link.submit_step(StepRequest(FWD, 60, 30000))
    rec.wait_count("accepted", 1)
    link.submit_step(StepRequest(Command.STOP, 0, 0))
    rec.wait(lambda xs: "stopped" in xs and "aborted:stop" in xs)
    assert emu.status().stop_latched


@pytest.mark.parametrize("kind", MEDIA)
def test_corrupted_and_dropped_frames_lose_nothing_and_run_nothing_twice(
    emulators: Emus, links: Links, kind: str, can_channel: str
) -> None:
    emu = serve(emulators, kind, can_channel, seed=11)
    link, rec = links(link_url(emu))
    rec.wait_count("ready", 1)
    if kind == "pty":
        emu.inject("link-corrupt=0.05")
    else:  # CAN's own CRC drops a damaged frame: on a bus, corruption is a drop
        with pytest.raises(InjectionError, match="link-drop instead"):
            emu.inject("link-corrupt=0.05")
    emu.inject("link-drop=0.05")
    mark = rec.mark()
    for _ in range(6):
        link.submit_step(StepRequest(FWD, 60, 3833))  # 6 x 1/6 m
    got = rec.wait(
        lambda xs: xs.count("completed") + xs.count("fault:no_ack") >= 6, since=mark, timeout=30
    )
    assert got.count("completed") == 6, got
    assert not any(s.startswith(("rejected", "aborted", "fault")) for s in got), got
    # Nothing ran twice: the ground distance is exactly six steps.
    assert emu.status().x_m == pytest.approx(1.0, abs=0.02)
    assert emu.frontend.stats.fault_dropped > 0
    if kind == "pty":
        assert link.diagnostics().rx_dropped > 0  # the host saw damaged frames, dropped them


def test_delayed_acks_are_retransmitted_and_deduplicated(emulators: Emus, links: Links) -> None:
    emu = emulators()
    link, rec = links(link_url(emu), ack_timeout_s=0.02, motion_retries=10)
    rec.wait_count("ready", 1)
    emu.inject("link-delay=0.05")  # each way: acks come after 0.1 s, retries every 0.02 s
    mark = rec.mark()
    link.submit_step(StepRequest(FWD, 60, 11500))
    got = rec.wait_count("completed", 1, since=mark, timeout=20)
    assert got == ["accepted", "completed"]
    assert link.diagnostics().retries > 0
    assert emu.status().x_m == pytest.approx(0.5, abs=0.01)  # executed once


@pytest.mark.parametrize("kind", MEDIA)
def test_heartbeat_loss_reports_link_lost_then_recovers(
    emulators: Emus, links: Links, kind: str, can_channel: str
) -> None:
    emu = serve(emulators, kind, can_channel)
    link, rec = links(link_url(emu))
    rec.wait_count("ready", 1)
    link.submit_step(StepRequest(FWD, 60, 30000))
    rec.wait_count("accepted", 1)
    mark = rec.mark()
    emu.inject("link-drop=1.0")
    rec.wait_count("fault:link_lost", 1, since=mark, timeout=5)
    assert link.state is LinkState.LOST
    # The line stays cut until the controller's watchdog has tripped (on a slow machine
    # the bridge may notice the loss first).
    wait_emulator(emu, lambda s: "watchdog" in s.latch, "the watchdog latch")
    emu.inject("clear:link-drop")
    rec.wait_count("ready", 1, since=mark)
    # The bridge clears the watchdog latch itself.
    rec.wait(lambda xs: "cleared" in xs, since=mark)
    mark = rec.mark()
    link.submit_step(StepRequest(FWD, 30, 1000))
    assert rec.wait_count("completed", 1, since=mark) == ["accepted", "completed"]


def test_unplug_and_replug_fault_then_recover(
    emulators: Emus, links: Links, tmp_path: Path
) -> None:
    path = tmp_path / "rover-motor"
    emu = emulators(link=path)
    link, rec = links(str(path), reconnect_min_s=0.05, reconnect_max_s=0.2)
    rec.wait_count("ready", 1)
    link.submit_step(StepRequest(FWD, 60, 30000))
    rec.wait_count("accepted", 1)
    mark = rec.mark()
    _serial(emu).unplug()
    rec.wait_count("fault:link_lost", 1, since=mark)
    assert not path.exists()
    _serial(emu).replug()
    rec.wait_count("ready", 1, since=mark)
    got = rec.since(mark)
    assert "completed" not in got  # the step in flight was dropped, not replayed
    assert link.diagnostics().reconnects >= 1
    # The watchdog latch of the outage, if it tripped, is cleared by the bridge itself;
    # it cannot trip after the handshake (our frames arrive again).
    if emu.status().stop_latched:
        rec.wait(lambda xs: "cleared" in xs, since=mark)
    mark = rec.mark()
    link.submit_step(StepRequest(FWD, 30, 1000))
    rec.wait_count("completed", 1, since=mark)


@pytest.mark.parametrize("kind", MEDIA)
def test_controller_reboot_is_detected_and_nothing_replayed(
    emulators: Emus, links: Links, kind: str, can_channel: str
) -> None:
    emu = serve(emulators, kind, can_channel)
    link, rec = links(link_url(emu))
    rec.wait_count("ready", 1)
    nonce = link.diagnostics().boot_nonce
    link.submit_step(StepRequest(FWD, 60, 30000))
    link.submit_step(StepRequest(FWD, 60, 30000))
    rec.wait_count("accepted", 2)
    mark = rec.mark()
    emu.inject("reboot")
    got = rec.wait(lambda xs: "fault:controller_reboot" in xs and "ready" in xs, since=mark)
    assert "completed" not in got
    diag = link.diagnostics()
    assert diag.reboots == 1 and diag.boot_nonce != nonce
    x_before = emu.status().x_m
    mark = rec.mark()
    link.submit_step(StepRequest(FWD, 60, 2300))
    rec.wait_count("completed", 1, since=mark)
    assert emu.status().x_m == pytest.approx(x_before + 0.1, abs=0.01)  # only the new step ran


@pytest.mark.parametrize("kind", MEDIA)
def test_estop_survives_a_reboot(
    emulators: Emus, links: Links, kind: str, can_channel: str
) -> None:
    emu = serve(emulators, kind, can_channel)
    link, rec = links(link_url(emu))
    rec.wait_count("ready", 1)
    link.emergency_stop()
    rec.wait_count("stopped", 1)
    mark = rec.mark()
    emu.inject("reboot")  # the controller forgets its latch...
    rec.wait(
        lambda xs: "ready" in xs and "stopped" in xs, since=mark
    )  # ...the bridge re-latches it
    assert emu.status().stop_latched


@pytest.mark.parametrize("kind", MEDIA)
def test_schema_mismatch_refuses_to_drive(
    emulators: Emus, links: Links, kind: str, can_channel: str
) -> None:
    emu = serve(emulators, kind, can_channel, schema_hash=SCHEMA_HASH ^ 0x5A5A)
    link, rec = links(link_url(emu))
    rec.wait_count("fault:schema_mismatch", 1)
    link.submit_step(StepRequest(FWD, 30, 100))
    assert rec.wait(lambda xs: "rejected:schema_mismatch" in xs)
    diag = link.diagnostics()
    assert diag.state == "mismatch" and "mismatch" in diag.last_error
    assert diag.schema_hash == f"0x{SCHEMA_HASH ^ 0x5A5A:04X}"
    assert emu.status().x_m == 0.0


def test_steps_while_the_link_is_down_are_rejected(links: Links, tmp_path: Path) -> None:
    link, rec = links(str(tmp_path / "no-such-device"), reconnect_min_s=0.05)
    link.submit_step(StepRequest(FWD, 30, 100))
    assert rec.wait(bool) == ["rejected:link_down"]
    assert "no-such-device" in link.diagnostics().last_error or link.diagnostics().last_error == ""
    stop_id = link.emergency_stop()  # accepted and kept for when the link comes back
    assert stop_id >= 1 and link.stop_latched


def test_no_ack_after_retries_is_a_fault(emulators: Emus, links: Links) -> None:
    emu = emulators()
    link, rec = links(link_url(emu), ack_timeout_s=0.01, motion_retries=2)
    rec.wait_count("ready", 1)
    emu.inject("link-delay=0.2")
    link.submit_step(StepRequest(FWD, 30, 100))
    got = rec.wait(lambda xs: "fault:no_ack" in xs)
    assert "fault:link_lost" in got
    emu.inject("clear:link-delay")


def test_no_ack_fate_follows_the_fates_of_older_steps(emulators: Emus, links: Links) -> None:
    """A step the controller already holds is older than the one that got no ACK: its
    ``aborted:link_lost`` comes first, so a client matching fates to steps in order gives
    ``fault:no_ack`` to the right step (docs/bridge.md: every fate, oldest first)."""
    emu = emulators()
    link, rec = links(link_url(emu), ack_timeout_s=0.01, motion_retries=2)
    rec.wait_count("ready", 1)
    link.submit_step(StepRequest(FWD, 60, 30000))  # ~1.3 m: still running at the loss
    rec.wait_count("accepted", 1)
    mark = rec.mark()
    emu.inject("link-delay=0.2")  # the next MOTION's ACKs come long after 3 tries
    link.submit_step(StepRequest(FWD, 60, 30000))
    got = rec.wait(lambda xs: "fault:link_lost" in xs, since=mark)
    emu.inject("clear:link-delay")
    settled = got[: got.index("fault:link_lost") + 1]
    assert settled == ["aborted:link_lost", "fault:no_ack", "fault:link_lost"], got
    assert link.diagnostics().steps_aborted == 2


def test_statuses_keep_their_order_while_a_subscriber_is_slow(emulators: Emus) -> None:
    """Statuses from two threads: while the dispatcher is still handing out the fates of
    a reboot (its subscriber slow), a step refused on the caller's thread is reported
    after them, not in the middle (the link's contract: in the order events happened)."""
    emu = emulators()
    rec = Recorder()
    slow, release = threading.Event(), threading.Event()

    def on_status(text: str) -> None:
        rec(text)
        if text == "aborted:controller_reboot" and not slow.is_set():
            slow.set()
            assert release.wait(10.0), "the test never released the subscriber"

    link = ControllerLink(LinkConfig(link_url(emu)), on_status=on_status)
    with link:
        rec.wait_count("ready", 1)
        link.submit_step(StepRequest(FWD, 60, 30000))
        link.submit_step(StepRequest(FWD, 60, 30000))
        rec.wait_count("accepted", 2)
        mark = rec.mark()
        emu.inject("reboot")
        assert slow.wait(10.0)
        link.submit_step(StepRequest(FWD, 30, 100))  # handshaking again: refused
        release.set()
        got = rec.wait(
            lambda xs: "rejected:link_down" in xs and "fault:controller_reboot" in xs, since=mark
        )
    assert got[:4] == [
        "aborted:controller_reboot",
        "aborted:controller_reboot",
        "fault:controller_reboot",
        "rejected:link_down",
    ], got


def test_transport_registry() -> None:
    assert parse_can_url("can://socketcan/vcan0?node=3&bitrate=500000") == (
        "socketcan",
        "vcan0",
        {"node": 3, "bitrate": 500000},
    )
    with pytest.raises(TransportError, match="known"):
        open_transport("warp://x")
    with pytest.raises(LinkUrlError, match="INTERFACE/CHANNEL"):
        parse_can_url("can://virtual")
    transport = open_transport("loop://")
    assert transport.kind == "serial"
    transport = open_transport("can://virtual/x?node=2")
    assert transport.kind == "can"


def test_odometry_tracks_the_emulator_encoders(emulators: Emus, rover: RoverDescription) -> None:
    from bridge.link.odometry import OdometryEstimator

    estimator = OdometryEstimator(rover)
    emu = emulators()
    seen: list[float] = []

    def on_telemetry(msg: object, t: float) -> None:
        if isinstance(msg, Encoders):
            seen.append(estimator.update_encoders(msg).x_m)

    rec = Recorder()
    with ControllerLink(
        LinkConfig(url=link_url(emu)), on_status=rec, on_telemetry=on_telemetry
    ) as link:
        rec.wait_count("ready", 1)
        link.submit_step(StepRequest(FWD, 60, 23000))
        rec.wait_count("completed", 1)
        rec.wait(lambda _: len(seen) > 5 and seen[-1] > 0.99, timeout=5)
    assert seen[-1] == pytest.approx(1.0, abs=0.002)
    assert math.hypot(emu.status().x_m, emu.status().y_m) == pytest.approx(seen[-1], abs=0.01)
