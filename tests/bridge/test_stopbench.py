"""The STOP bench against the real emulator, over a pty and a python-can bus (``virtual``
here; ``socketcan`` on ``vcan0`` where the kernel has it): every trial measures, latches
and clears; the reports are written and readable; a bad controller is refused."""

from __future__ import annotations

import csv
import json
import math
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from PIL import Image

from bridge.errors import TransportError
from bridge.tools import benchreport
from bridge.tools.benchreport import format_table, summarize, write_reports
from bridge.tools.stopbench import (
    BenchConfig,
    BenchError,
    BenchRun,
    FloodConfig,
    StopBench,
    TrialResult,
    judged_wheel_speeds,
)
from emulator.can_frontend import CanFrontEnd
from emulator.emulator_replay import ReplayOptions, replay_into_emulator
from emulator.engine import Emulator
from firmware_proto.cli import main as rover_cli
from firmware_proto.linkio.host import Received
from firmware_proto.linkio.trafficio import read_log
from firmware_proto.linkio.trafficlog import decode_records
from firmware_proto.runtime.realtime import EMULATOR_PRIORITY
from firmware_proto.wire.message import Message
from firmware_proto.wire.messages import SCHEMA_HASH, Param, Stopped, WheelSpeeds
from tests.conftest import IN_VCAN_VM
from tests.firmware_proto.c_harness import compiler
from tests.scheduling import threads_at

from .conftest import SPEED

Emus = Callable[..., Emulator]
HAVE_VCAN0 = os.path.exists("/sys/class/net/vcan0")
NO_VCAN0 = "no vcan0 here: this kernel has no SocketCAN (udev/vcan-up.sh says why)"


def _check_run(run: BenchRun, trials: int) -> None:
    assert len(run.trials) == trials
    assert run.passed == trials, format_table(run)
    for t in run.trials:
        assert t.ok
        assert t.ack_ms is not None
        assert t.stopped_ms is not None
        assert t.zero_ms is not None
        # The acknowledgement comes no later than the report of rest: from a slow rover
        # both can come in one read, with one arrival time (38.354 ms both, once).
        assert 0 < t.ack_ms <= t.stopped_ms
        assert t.zero_ms > t.ack_ms
        assert t.queued == t.purged == 8  # MOTION_QUEUE_DEPTH: the queue was full
        assert t.speed_mm_s is not None
        assert t.speed_mm_s >= 10  # STOP caught a moving rover
        assert t.controller_duration_ms is not None
        assert t.controller_distance_mm is not None
        assert t.clear_result == "CLEARED"
    assert len({t.stop_id for t in run.trials}) == trials
    assert run.telemetry_hz_set == run.config.telemetry_hz


@pytest.mark.parametrize(
    "kind",
    [
        "pty",
        "virtual",
        "virtual-malformed",
        pytest.param(
            "socketcan",
            marks=[pytest.mark.socketcan, pytest.mark.skipif(not HAVE_VCAN0, reason=NO_VCAN0)],
        ),
    ],
)
def test_stop_is_acknowledged_stops_latches_and_clears_under_load(
    emulators: Emus, kind: str, can_channel: str, tmp_path: Path
) -> None:
    flood = None
    if kind == "pty":
        emu = emulators("pty")
        url = emu.frontend.device
    else:
        interface = kind.removesuffix("-malformed")
        channel = "vcan0" if kind == "socketcan" else can_channel
        emu = emulators("can", interface=interface, channel=channel, node=3)
        url = f"can://{interface}/{channel}?node=3"
        # 1 kHz; 100 Hz on the VM's emulated CPU (6 to 20 times slower), where more
        # beside 100 Hz telemetry overruns the Python readers (as in test_socketcan.py).
        # "-malformed": a flood of malformed frames aimed at the controller instead.
        flood = FloodConfig(
            interface,
            channel,
            rate_hz=100 if IN_VCAN_VM else 1000,
            malformed=kind.endswith("-malformed"),
        )
    # Telemetry at 100 Hz; at 20 Hz in the VM, as its `rover bench stop` runs it
    # (test_socketcan.py): there an emulator, the bench's readers and a flood sender share
    # one interpreter on the emulated CPU, and its loop fell 140 ms behind.
    telemetry_hz = 20 if IN_VCAN_VM else 100
    config = BenchConfig(
        url=url, trials=3, seed=4, max_delay_s=0.1, flood=flood, telemetry_hz=telemetry_hz
    )
    seen: list[TrialResult] = []
    with StopBench(config) as bench:
        run = bench.run(seen.append)
    _check_run(run, 3)
    assert seen == list(run.trials)
    # Every STOP frame reached the controller once: one per trial, plus the repeats sent
    # when a STOP_ACK took longer than STOP_REPEAT_MS (a slow or flooded machine).
    repeats = sum(t.stop_repeats for t in run.trials)
    assert len(emu.stop_reactions) == 3 + repeats
    assert emu.status().stop_latched is False  # the bench leaves it released
    if kind == "pty":
        assert run.flood is None
        assert "ahead of anything the host has queued" in run.arbitration_note
    else:
        assert run.flood is not None
        assert run.flood.sent > 0
        assert "no arbitration" in run.arbitration_note
        frontend = emu.frontend
        assert isinstance(frontend, CanFrontEnd)
        rejected = frontend.decoder.counters.rejected
        if kind.endswith("-malformed"):
            assert "malformed frames" in run.load
            assert rejected >= run.flood.sent // 2  # counted and ignored; every trial passed
        else:
            assert rejected == 0
            assert "CAN flood 0x63F" in run.load  # PARAM_VALUE of node 15: lowest priority


@pytest.mark.firmware
@pytest.mark.parametrize("kind", ["pty", "virtual"])
def test_the_stop_bench_passes_against_the_c_firmware(
    emulators: Emus, kind: str, can_channel: str
) -> None:
    if compiler() is None:
        pytest.skip("gcc not found (set CC): the C firmware core cannot be built here")
    if kind == "pty":
        emu = emulators("pty", firmware="c")
        url = emu.frontend.device
    else:
        emu = emulators("can", interface="virtual", channel=can_channel, node=3, firmware="c")
        url = f"can://virtual/{can_channel}?node=3"
    with StopBench(BenchConfig(url=url, trials=3, seed=4, max_delay_s=0.1)) as bench:
        run = bench.run()
    _check_run(run, 3)
    assert emu.status().stop_latched is False


def test_the_stop_moments_follow_the_seed(emulators: Emus) -> None:
    delays = []
    for _ in range(2):
        emu = emulators("pty")
        config = BenchConfig(url=emu.frontend.device, trials=2, seed=11, max_delay_s=0.05)
        with StopBench(config) as bench:
            delays.append([t.delay_s for t in bench.run().trials])
    assert delays[0] == delays[1]
    assert len(set(delays[0])) == 2


def test_reports_table_csv_json_and_histogram(emulators: Emus, tmp_path: Path) -> None:
    emu = emulators("pty")
    config = BenchConfig(url=emu.frontend.device, trials=2, seed=1, max_delay_s=0.05)
    with StopBench(config) as bench:
        run = bench.run()
    table = format_table(run)
    for text in (
        "STOP -> STOP_ACK",
        "STOP -> STOPPED",
        "STOP -> wheels at zero",
        "p50",
        "p99",
        "latch held (MOTION refused STOP_LATCHED): 2/2",
        "CLEAR_STOP released (CLEARED): 2/2",
        "trials passed: 2/2",
    ):
        assert text in table
    csv_path, json_path, png_path = write_reports(run, tmp_path / "out")
    with csv_path.open(newline="") as f:
        rows = list(csv.DictReader(f))
    assert [int(r["trial"]) for r in rows] == [1, 2]
    assert all(r["ok"] == "True" for r in rows)
    doc = json.loads(json_path.read_text())
    assert doc["passed"] == 2
    assert doc["config"]["url"] == config.url
    assert set(doc["summary"]) == {"ack_ms", "stopped_ms", "zero_ms"}
    assert doc["summary"]["ack_ms"]["n"] == 2
    assert doc["summary"]["ack_ms"]["max"] == max(t.ack_ms for t in run.trials if t.ack_ms)
    with Image.open(png_path) as image:
        assert image.format == "PNG"
        assert image.size == (900, 40 + 3 * 230)


def _speeds(speed: int, target: int) -> WheelSpeeds:
    return WheelSpeeds(
        t_ms=0, left_mm_s=speed, right_mm_s=speed, left_target_mm_s=target, right_target_mm_s=target
    )


def test_a_trial_judges_a_wheel_speeds_sent_after_the_stop_however_slow_the_telemetry() -> None:
    """At 20 Hz (the VM's) none may come between STOP_ACK and STOPPED: the one at zero
    speed after STOPPED is judged, never the first on CAN alone (queued before the STOP)."""
    queued_before = _speeds(120, 150)  # moving, its targets set before the STOP
    at_zero = _speeds(0, 0)
    stopped = Stopped(stop_id=1, duration_ms=60, distance_mm=2)
    arrived: list[tuple[int, Message]] = [(4, queued_before), (5, stopped), (6, at_zero)]
    after_ack = [(i, Received(0.0, m, None)) for i, m in arrived]
    judged = judged_wheel_speeds(after_ack, stopped_at=5, zero_at=6, grace=1)
    assert judged == [at_zero]
    # On a serial line nothing was queued before: every one is judged.
    assert judged_wheel_speeds(after_ack, stopped_at=5, zero_at=6, grace=0) == [
        queued_before,
        at_zero,
    ]
    # The only one after STOP_ACK is the one at zero speed: that one.
    only = [(6, Received(0.0, at_zero, None))]
    assert judged_wheel_speeds(only, stopped_at=5, zero_at=6, grace=1) == [at_zero]
    # Those after both STOPPED and the one at zero speed are not judged.
    later = [*after_ack, (7, Received(0.0, _speeds(0, 90), None))]
    assert judged_wheel_speeds(later, stopped_at=5, zero_at=6, grace=1) == [at_zero]


def test_summary_percentiles_and_missing_measures() -> None:
    def trial(n: int, ack: float | None) -> TrialResult:
        return TrialResult(
            n, n, 0.0, 100.0, 8, ack, None, None, None, None, 0, 8, True, True, "CLEARED", True
        )

    summary = summarize([trial(i, float(i)) for i in range(1, 101)])
    ack, stopped, _zero = summary
    assert (ack.n, ack.p50, ack.p95, ack.p99, ack.max) == (100, 50.5, 95.05, 99.01, 100.0)
    assert stopped.n == 0
    assert math.isnan(stopped.p50)
    assert not trial(1, 1.0).ok  # STOPPED never seen


def test_a_mismatched_controller_is_refused(emulators: Emus) -> None:
    emu = emulators("pty", schema_hash=SCHEMA_HASH ^ 0x1111)
    config = BenchConfig(url=emu.frontend.device, trials=1, timeout_s=2.0)
    with StopBench(config) as bench, pytest.raises(BenchError, match="refusing to drive"):
        bench.run()
    assert emu.status().x_m == 0.0


def test_nobody_there_says_so(tmp_path: Path) -> None:
    config = BenchConfig(url=str(tmp_path / "no-such-device"), trials=1)
    with StopBench(config) as bench, pytest.raises(TransportError, match="no-such-device"):
        bench.run()


def test_rover_bench_stop_cli_records_and_reports(
    emulators: Emus,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The CLI end to end; its trials keep real time where permitted (as root), and its
    report is written after it has left real time (a second of CPU at real-time
    priority held a core from everything else: docs/realtime.md)."""
    emu = emulators("pty")
    out = tmp_path / "bench"
    log = tmp_path / "bench.rlog"
    policies: dict[str, int] = {}
    run_trials, report = StopBench.run, benchreport.write_reports

    def trials_seen(self: StopBench, *args: Any, **kwargs: Any) -> BenchRun:
        policies["trials"] = os.sched_getscheduler(0)
        return run_trials(self, *args, **kwargs)

    def report_seen(*args: Any, **kwargs: Any) -> list[Path]:
        policies["report"] = os.sched_getscheduler(0)
        return report(*args, **kwargs)

    monkeypatch.setattr(StopBench, "run", trials_seen)
    monkeypatch.setattr(benchreport, "write_reports", report_seen)
    argv = ["bench", "stop", "--serial", emu.frontend.device, "--trials", "2"]
    argv += ["--max-delay", "0.05", "--out", str(out), "--record", str(log)]
    assert rover_cli(argv) == 0
    if os.geteuid() == 0:
        assert policies["trials"] == os.SCHED_RR
    assert policies["report"] == os.SCHED_OTHER
    captured = capsys.readouterr()
    assert "trials passed: 2/2" in captured.out
    assert f"wrote {out / 'stop_trials.csv'}" in captured.out
    assert captured.err.count(" ok") == 2  # one progress line per trial
    assert sorted(p.name for p in out.iterdir()) == [
        "stop_hist.png",
        "stop_trials.csv",
        "stop_trials.json",
    ]
    names = [d.message.NAME for d in decode_records(read_log(log).records) if d.message]
    assert names.count("STOP") >= 2
    assert names.count("STOPPED") == 2
    # The telemetry rate was raised for the run and put back afterwards.
    set_params = [
        d.message
        for d in decode_records(read_log(log).records)
        if d.message is not None and d.message.NAME == "SET_PARAM"
    ]
    assert [(m.param, m.value) for m in set_params] == [  # type: ignore[attr-defined]
        (Param.TELEMETRY_HZ, 100),
        (Param.TELEMETRY_HZ, 50),
    ]
    # A closed-loop session (every request waits on an answer) replays alike.
    with threads_at(EMULATOR_PRIORITY):  # as `rover replay` keeps time
        result = replay_into_emulator(read_log(log), ReplayOptions(seed=1, speed_factor=SPEED))
    assert result.ok, result.report()
    assert result.recorded_answers > 30


def test_bench_config_is_checked() -> None:
    with pytest.raises(ValueError, match="trials"):
        BenchConfig(url="x", trials=0)
    with pytest.raises(ValueError, match="speed"):
        BenchConfig(url="x", speed=61)
    with pytest.raises(ValueError, match="telemetry"):
        BenchConfig(url="x", telemetry_hz=500)
