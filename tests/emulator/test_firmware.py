"""The C firmware core in the loop (:mod:`emulator.firmware`), against the Python model.

The differential test feeds both implementations the same seeded host traffic (valid,
invalid and corrupted; :mod:`tests.emulator.differential`) in lockstep, each on its own
twin built the same way, and requires the same frames back, up to the plant's
measurements (:data:`~tests.emulator.differential.TOLERANCE`). The conformance suite
runs against both in tests/bridge/test_conformance.py.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import os
from collections import Counter
from pathlib import Path

import pytest

from emulator.controller import ControllerConfig, ControllerModel
from emulator.errors import FirmwareBuildError
from emulator.firmware import FirmwareController, build_library, make_controller
from emulator.twin import Twin
from firmware_proto.model.rover import RoverDescription, load_rover
from firmware_proto.wire.messages import (
    PROTOCOL_VERSION,
    SCHEMA_HASH,
    AbortReason,
    AckResult,
    Command,
    ControllerState,
    Hello,
    HostHeartbeat,
    Ident,
    Motion,
    ParamResult,
    Status,
    StepState,
    Stop,
    StopAck,
)
from tests.emulator.differential import Sent, compare, run_lockstep, traffic
from tests.firmware_proto.c_harness import compiler

pytestmark = pytest.mark.firmware

SEEDS = tuple(range(8))
TICKS = 20_000
"""20 s of twin time per seed at the default 1 ms step."""


@pytest.fixture(autouse=True)
def _needs_a_compiler() -> None:
    if compiler() is None:
        pytest.skip("gcc not found (set CC): the C firmware core cannot be built here")


@functools.cache
def _runs(seed: int) -> tuple[list[Sent], list[Sent]]:
    rover = load_rover()
    events = list(traffic(seed, TICKS))
    python = run_lockstep(
        ControllerModel(rover, Twin(rover), ControllerConfig(), seed=seed), events, TICKS
    )
    c = run_lockstep(
        FirmwareController(rover, Twin(rover), ControllerConfig(), seed=seed), events, TICKS
    )
    return python, c


@pytest.mark.parametrize("seed", SEEDS)
def test_both_implementations_send_the_same_frames(seed: int) -> None:
    python, c = _runs(seed)
    assert compare(python, c) == []


@functools.cache
def _runs_across_the_wrap() -> tuple[list[Sent], list[Sent]]:
    """Seed 1's traffic with the encoder counters 500 units short of their wrap: the
    left one forward (at 2^31 - 500), the right one backward (at -2^31 + 500) (a seed
    whose steps cross both wraps)."""
    rover = load_rover()
    events = list(traffic(1, TICKS))
    runs = []
    for kind in (ControllerModel, FirmwareController):
        model = kind(rover, Twin(rover), ControllerConfig(), seed=1)
        model.encoders.set_counts((1 << 31) - 500, -(1 << 31) + 500)
        runs.append(run_lockstep(model, events, TICKS))
    return runs[0], runs[1]


def test_both_implementations_send_the_same_frames_across_the_encoder_wrap() -> None:
    python, c = _runs_across_the_wrap()
    assert compare(python, c) == []
    # ENCODERS carry the count modulo 2^24, in which the 32-bit wrap is the crossing of 0.
    for side in ("left", "right"):
        counts = [s.message.to_dict()[side] for s in c if s.message.NAME == "ENCODERS"]
        assert min(counts) < 0 < max(counts), f"the {side} counter never wrapped"


def test_the_differential_traffic_reaches_every_corner() -> None:
    seen: Counter[str] = Counter()
    for seed in SEEDS:
        for sent in _runs(seed)[1]:
            name, f = sent.message.NAME, sent.message.to_dict()
            seen[name] += 1
            if name == "ACK":
                seen[f"ACK {AckResult(f['result']).name}"] += 1
            elif name == "STATUS":
                seen[f"STATUS {StepState(f['state']).name} {AbortReason(f['reason']).name}"] += 1
            elif name == "PARAM_VALUE":
                seen[f"PARAM_VALUE {ParamResult(f['result']).name}"] += 1
            elif name == "FAULT":
                seen[f"FAULT {f['code']} {f['active']}"] += 1
            elif name == "CLEAR_ACK":
                seen[f"CLEAR_ACK {f['result']}"] += 1
    expected = [
        "ACK ACCEPTED",
        "ACK OUT_OF_RANGE",
        "ACK QUEUE_FULL",
        "ACK STOP_LATCHED",
        "ACK DUPLICATE",
        "ACK NOT_READY",
        "ACK FAULT_ACTIVE",
        "STATUS COMPLETED NONE",
        "STATUS ABORTED STOP",
        "STATUS ABORTED WATCHDOG",
        "STATUS ABORTED SESSION",
        "STOPPED",
        "STOP_ACK",
        "CLEAR_ACK 0",
        "CLEAR_ACK 1",
        "CLEAR_ACK 2",
        "FAULT 1 1",
        "FAULT 1 0",
        "PARAM_VALUE OK",
        "PARAM_VALUE UNKNOWN_PARAM",
        "PARAM_VALUE OUT_OF_RANGE",
        "IDENT",
        "POSE",
        "IMU",
    ]
    missing = [k for k in expected if not seen[k]]
    assert not missing, (missing, seen)


class _ForgetfulModel(ControllerModel):
    """A controller that breaks deduplication: it never remembers a seq."""

    def _remember(self, seq: int) -> None:
        pass


def test_the_comparison_finds_a_controller_that_differs(rover: RoverDescription) -> None:
    events = list(traffic(1, 5000))
    broken = run_lockstep(
        _ForgetfulModel(rover, Twin(rover), ControllerConfig(), seed=1), events, 5000
    )
    good = run_lockstep(
        FirmwareController(rover, Twin(rover), ControllerConfig(), seed=1), events, 5000
    )
    assert compare(good, broken), "a controller without deduplication passed"


def test_a_stop_zeroes_the_targets_in_the_call_that_receives_it(rover: RoverDescription) -> None:
    model = FirmwareController(rover, Twin(rover), ControllerConfig(), seed=4)
    model.boot()
    model.handle(Hello(PROTOCOL_VERSION, SCHEMA_HASH))
    model.handle(Motion(7, Command.FWD, 40, 20_000))
    for tick in range(300):
        if tick % 50 == 0:
            model.handle(HostHeartbeat(tick))
        model.tick()
    assert model.state == ControllerState.EXECUTING and model.wheel_setpoints_mps[0] > 0.1
    out = model.handle(Stop(9, 0))
    assert out[0] == StopAck(9, ControllerState.STOP_LATCHED, model.latch_gen)
    assert [m.NAME for m in out[1:]] == ["STATUS"]
    assert out[1].to_dict()["reason"] == AbortReason.STOP
    assert model.wheel_setpoints_mps == (0.0, 0.0)
    assert model.wheel_commands_mps[0] > 0.1  # braking at the accel limit, not a wall
    assert model.stop_latched and model.queue_depth == 0


@pytest.mark.parametrize("command", [Command.FWD, Command.REV], ids=["fwd", "rev"])
@pytest.mark.parametrize("firmware", ["python", "c"])
def test_a_step_across_the_encoder_counter_wrap_completes_at_its_distance(
    firmware: str, command: int, rover: RoverDescription
) -> None:
    """The 32-bit encoder counters wrap half-way through a 1 m step (forward: from
    2^31 - 1 to -2^31; backward: the other way): the step still completes with travel
    23000 having driven 1 m, in both controllers."""
    model = make_controller(firmware, rover, Twin(rover), ControllerConfig(), seed=3)
    half = 11_500
    start = (1 << 31) - half if command == Command.FWD else -(1 << 31) + half
    model.encoders.set_counts(start, start)
    model.boot()
    model.handle(Hello(PROTOCOL_VERSION, SCHEMA_HASH))
    before = model.twin.pose
    model.handle(Motion(1, command, 60, 23_000))
    ended: Status | None = None
    for tick in range(20_000):  # 20 s of twin time; the step takes about 4 s
        if tick % 50 == 0:
            model.handle(HostHeartbeat(tick))
        for msg in model.tick():
            if isinstance(msg, Status) and msg.seq == 1 and msg.state != StepState.STARTED:
                ended = msg
        if ended is not None:
            break
    assert ended is not None, f"still driving after 20 s: {model.twin.pose}"
    assert (ended.state, ended.travel) == (StepState.COMPLETED, 23_000)
    after = model.twin.pose
    assert math.hypot(after.x_m - before.x_m, after.y_m - before.y_m) == pytest.approx(
        1.0, abs=0.01
    )
    left, right = model.encoders.counts()
    wrapped = -(1 << 31) + half if command == Command.FWD else (1 << 31) - half
    assert left == pytest.approx(wrapped, abs=20) and right == pytest.approx(wrapped, abs=20)


def test_a_reboot_is_a_new_boot_of_the_core(rover: RoverDescription) -> None:
    model = FirmwareController(rover, Twin(rover), ControllerConfig(), seed=4)
    (booted,) = model.boot()
    assert isinstance(booted, Ident)
    model.handle(Hello(PROTOCOL_VERSION, SCHEMA_HASH))
    opened = model.handshake_ok
    (ident,) = model.reboot()
    assert isinstance(ident, Ident)
    assert ident.boot_nonce != booted.boot_nonce and ident.boot_nonce == model.boot_nonce
    assert opened and not model.handshake_ok and model.state == ControllerState.BOOT


def test_a_rover_or_rate_the_core_refuses_is_refused_by_name(rover: RoverDescription) -> None:
    """fw_init's refusal reaches the emulator as FirmwareBuildError naming the field."""
    fast = dataclasses.replace(
        rover, drive=dataclasses.replace(rover.drive, wheel_velocity_scale_rad_s=0.6)
    )  # 60 speed units at 0.06 m/s each: 3.6 m/s
    with pytest.raises(FirmwareBuildError, match="FW_ERR_SPEED: the top wheel speed"):
        FirmwareController(fast, Twin(fast), ControllerConfig())
    with pytest.raises(FirmwareBuildError, match="FW_ERR_RATE"):
        FirmwareController(rover, Twin(rover), ControllerConfig(heartbeat_hz=0))


def test_the_library_is_cached_by_content(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("ROVER_FIRMWARE_CACHE", str(tmp_path))
    first = build_library(sanitize=False)
    mtime = first.stat().st_mtime_ns
    assert build_library(sanitize=False) == first and first.stat().st_mtime_ns == mtime
    assert first.parent == tmp_path and first.name.startswith("librover_fw-")


def test_without_a_compiler_the_c_firmware_says_so(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, rover: RoverDescription
) -> None:
    monkeypatch.setenv("ROVER_FIRMWARE_CACHE", str(tmp_path))
    monkeypatch.setenv("PATH", str(tmp_path))
    monkeypatch.setenv("CC", "no-such-cc")
    with pytest.raises(FirmwareBuildError, match="no C compiler"):
        make_controller("c", rover, Twin(rover))
    with pytest.raises(ValueError, match="unknown firmware 'rust'; known: python, c"):
        make_controller("rust", rover, Twin(rover))
    assert os.environ["PATH"] == str(tmp_path)
