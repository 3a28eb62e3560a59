"""The ATmega2560 image and its twin in lockstep (virtual time): the MCU's cycles and the
twin's steps advance together with the host's clock, so a run is exact and repeatable
(docs/firmware.md, "Processor in the loop")."""

from __future__ import annotations

import math
from collections.abc import Callable

import pytest

from bridge.errors import ConformanceError
from bridge.tools.conformance import RULES, Context, WireHost, run_suite
from emulator.pil.avr import AvrLockstep, avr_lockstep_pair, make_system
from emulator.pil.images import build_image
from emulator.playback import play
from emulator.twin import Twin
from firmware_proto.linkio.host import ProtocolHost
from firmware_proto.model.rover import load_rover
from firmware_proto.model.worldmap import load_map
from firmware_proto.wire.messages import (
    ClearAck,
    Command,
    Motion,
    PoseMsg,
    Status,
    StepState,
    Stop,
    StopAck,
    Stopped,
)

from .pil_helpers import require_target

DRIFT_LINEAR_M = 0.25
"""Drift control's threshold (docs/architecture.md, Contracts 6)."""


class _Control:
    def __init__(self, avr: AvrLockstep) -> None:
        self._avr = avr

    def inject(self, fault: str) -> dict[str, object]:
        try:
            return self._avr.inject(fault)
        except ValueError as exc:
            raise ConformanceError(f"control refused {fault!r}: {exc}") from exc


@pytest.fixture(scope="module")
def image_ready() -> None:
    require_target("atmega2560")
    build_image("atmega2560")


def test_every_conformance_rule_passes_in_lockstep(image_ready: None) -> None:
    system = make_system(build_image("atmega2560"), map_name=None, seed=2)
    avr, endpoint, clock = avr_lockstep_pair(system)
    avr.open()
    try:
        with WireHost(endpoint, clock=clock) as host:
            ctx = Context(host, _Control(avr), load_rover())
            results = run_suite(ctx, list(RULES.values()))
    finally:
        avr.close()
    failed = {r.rule.id: r.detail for r in results if r.outcome.value != "pass"}
    assert not failed, failed
    assert len(results) >= 37
    print(f"\n{len(results)} rules in {clock.now():.1f} s of virtual time, {avr.ticks} steps")


def _seq_is(seq: int) -> Callable[[Status], bool]:
    return lambda m: m.seq == seq


def _completed(seq: int) -> Callable[[Status], bool]:
    return lambda m: m.seq == seq and m.state == StepState.COMPLETED


def _mission(seed: int, slip: str | None) -> tuple[str, tuple[float, float, float], list[int]]:
    """A plan of three steps on the lab map, ``slip`` injected when the second starts;
    the wire digest, the final pose and each step's reported travel."""
    system = make_system(build_image("atmega2560"), map_name="lab", seed=seed)
    avr, endpoint, clock = avr_lockstep_pair(system)
    avr.open()
    travels = []
    try:
        with ProtocolHost(endpoint, clock=clock) as host:
            host.handshake()
            plan = [(Command.FWD, 40, 9000), (Command.LEFT, 30, 2500), (Command.FWD, 40, 9000)]
            for i, (command, speed, distance) in enumerate(plan):
                seq = 100 + i
                mark = host.mark()
                host.send(Motion(seq, command, speed, distance))
                host.expect(Status, _seq_is(seq), since=mark, timeout_s=1.0)
                if i == 1 and slip is not None:
                    avr.inject(slip)
                done = host.expect(Status, _completed(seq), since=mark, timeout_s=20.0)
                travels.append(done.travel)
            host.settle(0.5)
    finally:
        avr.close()
    p = system.plant.twin.pose
    return avr.digest, (p.x_m, p.y_m, p.yaw_deg), travels


def test_a_mission_repeats_exactly_from_its_seed(image_ready: None) -> None:
    first = _mission(5, "slip:left=0.3")
    again = _mission(5, "slip:left=0.3")
    other = _mission(6, "slip:left=0.3")
    assert first == again
    # The encoders count the full steps (slip or not), within one 10 ms tick of travel at
    # 0.2 m/s (46 units): the ATmega2560's control period.
    assert all(d <= t <= d + 46 for t, d in zip(first[2], [9000, 2500, 9000], strict=True))
    assert other[0] != first[0]  # another seed: other sensor noise, other boot nonce
    print(f"\nwire digest {first[0][:16]}..., final pose {first[1]}")


def _drive_and_watch(slip: float | None) -> tuple[float, bool, int]:
    """Two 1.3 m FWD steps back to back on the lab map, ``slip`` on the left wheels, the
    host watching POSE against the gate's playback of the same steps and stopping at
    0.25 m of drift (three fixes in a row), as drift control does; the worst drift seen,
    whether it stopped, STOPPED's distance (mm, -1: none)."""
    rover = load_rover()
    step = (int(Command.FWD), 60, 30000)
    predicted = play(Twin(rover, load_map("lab")), [step, step]).samples
    system = make_system(build_image("atmega2560"), map_name="lab", seed=3)
    if slip is not None:
        system.plant.set_slip(0, slip)
    avr, endpoint, clock = avr_lockstep_pair(system)
    avr.open()
    worst, over, stopped_mm = 0.0, 0, -1
    try:
        with ProtocolHost(endpoint, clock=clock) as host:
            host.handshake()
            mark = host.mark()
            host.send(Motion(7, *step))
            host.expect(Status, lambda m: m.seq == 7, since=mark)
            t0 = host.now()
            host.send(Motion(8, *step))
            seen = mark
            while True:
                found = host.find(PoseMsg, since=seen, timeout_s=0.5)
                done = host.find(
                    Status,
                    lambda m: m.seq == 8 and m.state != StepState.STARTED,
                    since=mark,
                    timeout_s=0.0,
                )
                if found is None or done is not None:
                    break
                seen = found[0] + 1
                pose = found[1].message
                assert isinstance(pose, PoseMsg)
                t = found[1].arrived - t0 - pose.age_4ms * 0.004
                ref = min(predicted, key=lambda s: abs(s.time_s - t)).pose
                err = math.hypot(pose.x_mm / 1000 - ref.x_m, pose.y_mm / 1000 - ref.y_m)
                worst = max(worst, err)
                over = over + 1 if err > DRIFT_LINEAR_M else 0
                if over >= 3:
                    host.send(Stop(41, 1))
                    host.expect(StopAck, lambda m: m.stop_id == 41, since=seen)
                    stopped_mm = host.expect(
                        Stopped, lambda m: m.stop_id == 41, since=seen, timeout_s=3.0
                    ).distance_mm
                    host.send(host.clear_stop_for(41))
                    host.expect(ClearAck, since=seen)
                    break
    finally:
        avr.close()
    return worst, stopped_mm >= 0, stopped_mm


def test_slip_on_the_twin_trips_a_drift_stop_on_the_atmega2560(image_ready: None) -> None:
    worst, stopped, distance_mm = _drive_and_watch(0.05)  # the demo's slip:left=0.05
    assert stopped and worst > DRIFT_LINEAR_M
    assert 0 <= distance_mm <= 80  # braking from at most 0.3 m/s at 0.8 m/s^2: 56 mm
    calm, calm_stopped, _ = _drive_and_watch(None)
    assert not calm_stopped and calm < 0.1, calm  # PIL and the gate's twin agree
    print(f"\ndrift with slip {worst:.3f} m (stopped), without {calm:.3f} m")
