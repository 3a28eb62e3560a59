"""Every benchmark with a small mode runs to the end and prints its tables.

Smoke tests, not measurements: each script runs as a real subprocess in its ``--quick``
mode (``bench_rosport`` with small counts), must exit 0 and print the headers of its
tables. No figure is compared with a limit (a shared 2-core machine makes timings
noisy), except counts that do not depend on speed: the codec's recovery run must
deliver no altered frame and recover every intact one.

``bench_emulator``'s STOP trials survive a stall of their own process (the controller's
watchdog fires, the trial is run again): one test stalls it on purpose, in virtual
time (a lockstep controller).

``bench_view --quick`` runs its synthetic feed with the Python client only (its
``--browser`` and ``--demo`` parts are left out). ``bench_hostile --view --quick``
probes the view's STOP 20 times idle and beside a small flood.

``bench_calibration --quick`` asserts the issue's bar (a 5x cut of the prediction error, or
within 1.5x of the floor) on its ground (a development seed: the held-out ones are for
the full run): its missions are seeded and driven in lockstep, so the figures do not
depend on the machine's speed.

``bench_uncertain --quick --no-cluster`` plays its batches and posts its verdicts to
gates with one and two worker processes (its Dask rows are left out).

``bench_console --quick`` starts a ``rover stack up`` and runs each operator command
twice through its console (the ``rclpy`` marker: the stack talks DDS).

Left out: ``bench_gate`` (about 20 s even at its smallest settings, most of it CPU)
and ``bench_mission`` (minutes). ``bench_rosport``, ``bench_discovery`` and the ROS 2 case
of ``bench_bridge`` talk DDS, so they run only in the private network namespace of
``.ci/test`` (the ``rclpy`` marker; tests/conftest.py); ``bench_socketcan`` needs vcan0
(marker ``socketcan``: in ``.ci/vcan-vm`` here).
"""

from __future__ import annotations

import argparse
import contextlib
import itertools
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from benchmarks.bench_emulator import _full_speed_or_latched, _release
from emulator.controller import ControllerConfig, ControllerModel
from emulator.lockstep import lockstep_pair
from emulator.twin import Twin
from firmware_proto.linkio.host import ProtocolHost
from firmware_proto.model.rover import load_rover
from firmware_proto.wire.messages import Command, Fault, FaultCode, Motion

REPO_ROOT = Path(__file__).resolve().parents[1]
TIMEOUT_S = 180.0
"""Per script; the quick modes take 1-15 s here, the margin is for a loaded machine."""


def run_benchmark(name: str, *args: str) -> str:
    """Run ``python -m benchmarks.<name> args...``; its stdout, after checking it exited 0."""
    done = subprocess.run(
        [sys.executable, "-m", f"benchmarks.{name}", *args],
        cwd=REPO_ROOT,
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
        check=False,
    )
    assert done.returncode == 0, f"{name} exited {done.returncode}:\n{done.stderr[-3000:]}"
    return done.stdout


def table_row(text: str, header: str) -> dict[str, str]:
    """The first data row of the Markdown table whose header line starts with ``header``,
    as {column: cell}."""
    lines = text.splitlines()
    at = next(i for i, line in enumerate(lines) if line.startswith(header))
    columns = [c.strip() for c in lines[at].strip("|").split("|")]
    cells = [c.strip() for c in lines[at + 2].strip("|").split("|")]
    return dict(zip(columns, cells, strict=True))


def test_bench_codec_quick_prints_rates_and_a_clean_recovery() -> None:
    out = run_benchmark("bench_codec", "--quick")
    assert "| codec | operation | frames/s |" in out
    for codec in ("ours serial MOTION", "ours CAN ENCODERS", "pymavlink COMMAND_LONG"):
        assert f"| {codec} |" in out
    assert "cantools MOTION" in out
    assert "Ratio against pymavlink" in out
    assert "Recovery from a stream with 1% corrupted frames" in out
    outcome = table_row(out, "| frames | corrupted |")
    assert outcome["frames"] == "20,000"
    assert outcome["altered delivered"] == "0"
    assert outcome["intact recovered"] == outcome["intact"]
    drops = table_row(out, "| crc | framing |")
    assert int(drops["rejected (all reasons)"].replace(",", "")) >= int(
        outcome["corrupted"].replace(",", "")
    )


def test_bench_emulator_quick_prints_its_tables() -> None:
    out = run_benchmark("bench_emulator", "--quick")
    assert "| case | steps/s | x real time |" in out
    assert "CPU share serving a driving host" in out
    assert "STOP reaction in the emulator" in out
    assert "Stopping distance from full speed" in out
    assert "Trials lost and run again" in out


def test_the_stop_bench_runs_a_trial_again_after_a_stall_fires_the_watchdog() -> None:
    """A stall of the bench's own process past the controller's 250 ms watchdog (beside
    load: a fresh-clone run beside four busy processes failed there) latches the
    controller: the trial is known lost at once, the latch is cleared, and the next
    trial drives to full speed. In virtual time: the controller model on a lockstep
    clock (emulator/lockstep.py), the same host."""
    rover = load_rover()
    controller, endpoint, clock = lockstep_pair(
        ControllerModel(rover, Twin(rover), ControllerConfig(), seed=2)
    )
    ids = itertools.count(1)
    controller.open()
    with contextlib.closing(controller), ProtocolHost(endpoint, clock=clock) as host:
        host.handshake()
        mark = host.mark()
        with host.silent():  # the stall: no frame from the host after this MOTION
            host.send(Motion(next(ids), Command.FWD, 60, 30000))
            assert not _full_speed_or_latched(host, mark)
        assert host.find(Fault, lambda f: f.code == FaultCode.WATCHDOG, since=mark) is not None
        _release(host, ids)
        mark = host.mark()
        host.send(Motion(next(ids), Command.REV, 60, 30000))
        assert _full_speed_or_latched(host, mark)


def test_bench_odomcdr_quick_puts_packing_and_reading_beside_rclpy() -> None:
    out = run_benchmark("bench_odomcdr", "--quick")
    assert "| case | us/msg p50 | us/msg worst |" in out
    for case in ("build + serialize (rclpy", "pack (odomcdr)", "deserialize (rclpy", "read in"):
        assert f"| {case}" in out, case


def test_bench_twin_quick_prints_its_table() -> None:
    out = run_benchmark("bench_twin", "--quick")
    assert "steps/s" in out and "x real time" in out
    assert "12-step plan, 10 m + 4 turns, scn01" in out
    assert "playback (gate step)" in out


@pytest.mark.usefixtures("c_compiler")
def test_bench_batch_quick_puts_the_c_kernel_beside_numpy() -> None:
    out = run_benchmark("bench_batch", "--quick")
    assert "librover_batch-" in out
    for first in ("jobs", "twins"):
        assert f"| {first} | twin-steps | numpy p50 ms |" in out
    rows = [line.split("|") for line in out.splitlines() if line.startswith(("| 8 ", "| 4 "))]
    assert len(rows) == 2 and all(float(row[-2]) <= 1e-9 for row in rows)  # the difference


def test_bench_bridge_quick_prints_its_table() -> None:
    out = run_benchmark("bench_bridge", "--quick")
    assert "STOP latency through the bridge" in out
    assert "| case | n | p50 ms | p95 ms | p99 ms | max ms |" in out
    assert "ROS message (in-process) -> wheel targets zero (load)" in out
    assert "- API call: " in out and " trials lost to the link; heartbeat losses " in out
    assert "Sustained steps through the bridge" in out


@pytest.mark.rclpy
def test_bench_rosport_small_counts_print_its_tables() -> None:
    out = run_benchmark(
        "bench_rosport", "--latency-count", "50", "--rate-count", "200", "--kind", "String"
    )
    assert "Latency, publish -> subscriber callback" in out
    assert "Sustained rate, nothing lost" in out
    assert "raw rclpy (2 processes)" in out
    assert "rosport rclpy, STOP lane (2 proc.)" in out
    assert "rosport rclpy-process (2 processes)" in out and "call p99" in out
    assert "sub CPU us/msg" in out


@pytest.mark.rclpy
def test_bench_discovery_quick_prints_both_profiles() -> None:
    out = run_benchmark("bench_discovery", "--quick")
    assert "| profile | n | p50 ms | p99 ms | max ms | idle CPU, % of a core |" in out
    assert "| Fast DDS default (3 s) | 2 |" in out and "| our profile (0.5 s) | 2 |" in out


@pytest.mark.rclpy
def test_bench_bridge_ros2_case_prints_its_rows() -> None:
    out = run_benchmark("bench_bridge", "--quick", "--ros2")
    for backend in ("rclpy-process", "rclpy"):
        assert f"ROS 2 STOP -> bridge on {backend}: STOP callback (load)" in out
        assert f"ROS 2 STOP -> bridge on {backend}: wheel targets zero (load)" in out


@pytest.mark.rclpy
@pytest.mark.timeout(300)
def test_bench_console_quick_prints_its_table() -> None:
    """A ``rover stack up`` and each operator command twice through its console."""
    out = run_benchmark("bench_console", "--quick")
    assert "Operator commands against a running stack, beside 0 busy processes" in out
    for command in ("status", "stop", "clear-stop", "echo command_status --count 1"):
        assert f"| rover {command} (console) | 2 |" in out


@pytest.mark.socketcan
@pytest.mark.skipif(
    not Path("/sys/class/net/vcan0").exists(),
    reason="no vcan0 here (.ci/test runs this in .ci/vcan-vm)",
)
def test_bench_socketcan_quick_prints_every_case_beside_the_floor() -> None:
    out = run_benchmark("bench_socketcan", "--quick", "--flood-hz", "300", "--telemetry-hz", "20")
    assert "| vcan round trip (python-can, floor) |" in out
    for case in ("idle", "flood", "malformed"):
        assert f"| STOP -> STOP_ACK, {case} | 3 |" in out
        assert f"{case}: 3/3 trials passed every check" in out


def test_bench_view_quick_prints_push_latency_beside_its_limit() -> None:
    out = run_benchmark("bench_view", "--quick")
    assert "Push latency, tap to client, synthetic feed" in out
    client = table_row(out, "| case | n |")
    assert client["case"] == "Python socket client (peer: no browser)"
    assert int(client["n"]) > 50  # 60 poses/s for 2 s, all delivered
    assert "| limit: the view's update period (10 Hz) |" in out
    assert "View threads' CPU during the feed" in out


@pytest.mark.firmware
def test_bench_hostile_quick_times_the_views_stop_beside_a_flood() -> None:
    out = run_benchmark("bench_hostile", "--view", "--quick")
    assert "View: POST /stop on a fresh connection, every 20 ms" in out
    row = table_row(out, "| case |")
    assert row["case"].startswith("this tree: answer, idle") and float(row["p99 ms"]) > 0


def test_bench_load_quick_measures_stop_latency_beside_busy_processes() -> None:
    out = run_benchmark("bench_load", "--quick")
    assert "The controller link beside load (bench_load)" in out
    header = next(line for line in out.splitlines() if line.startswith("| busy |"))
    columns = [c.strip() for c in header.strip("|").split("|")]
    rows = [
        dict(zip(columns, (c.strip() for c in line.strip("|").split("|")), strict=True))
        for line in out.splitlines()
        if line.startswith("| 2 |")
    ]
    assert [row["real time"] for row in rows] == ["off", "on"]
    for row in rows:
        p50, _, rest = row["STOP p50/p99 ms (n)"].partition("/")
        failed = row["STOP trials failed; watchdog trips; links lost"].split(";")[0]
        assert float(p50) > 0 and rest.endswith(f"({3 - int(failed)})"), row
    assert "250 ms" in out


def test_bench_firmware_quick_prints_the_c_core_beside_the_python_model() -> None:
    out = run_benchmark("bench_firmware", "--quick")
    assert "| C core, fw_on_bytes(STOP frame), measured in C | 50 |" in out
    assert "| Python model (ControllerModel.handle) | 50 |" in out
    assert "| C core + twin (FirmwareController) |" in out
    assert "Instructions per fw_tick (callgrind, x86-64 -O2, driving): " in out


@pytest.mark.timeout(900)
def test_bench_calibration_quick_cuts_the_error_on_every_ground() -> None:
    out = run_benchmark("bench_calibration", "--quick")
    header = "| ground | driving s |"
    assert header in out
    lines = out.splitlines()
    at = next(i for i, line in enumerate(lines) if line.startswith(header))
    columns = [c.strip() for c in lines[at].strip("|").split("|")]
    row = dict(zip(columns, (c.strip() for c in lines[at + 2].strip("|").split("|")), strict=True))
    assert row["ground"] == "loose-1000"
    # Deterministic (seeded grounds, lockstep missions), so the bar itself is asserted.
    assert float(row["driving s"]) <= 30.0
    assert float(row["after/floor"]) <= 1.5, row
    assert "| loose-1000 | turn_efficiency |" in out and "coverage " in out
    assert "the median error the bands themselves expect" in out


def test_bench_calibration_names_its_grounds_by_kind_and_seed() -> None:
    from benchmarks.bench_calibration import (
        GROUND_SEEDS,
        QUICK_SEED,
        SEEN_SEEDS,
        parse_seed,
    )

    assert parse_seed("packed=90533") == ("packed", 90533)
    for bad in ("packed", "gravel=3", "loose=", "loose=-1", "loose=x"):
        with pytest.raises(argparse.ArgumentTypeError, match="KIND=SEED"):
            parse_seed(bad)
    # The held-out seeds are used by the full run alone.
    held_out = set(GROUND_SEEDS.values())
    seen = {seed for seeds in SEEN_SEEDS.values() for seed in seeds}
    assert not held_out & (seen | {QUICK_SEED})


def test_bench_calibration_width_over_error_against_the_bands_own() -> None:
    from benchmarks.bench_calibration import (
        HeldOutResult,
        width_over_error,
    )

    def outcome(error_m: float, width_m: float, samples: tuple[float, ...]) -> HeldOutResult:
        return HeldOutResult(
            {"after": error_m},
            {"after": 0.0},
            (True, True, True),
            (0.0, width_m, 0.0),
            (0.0, 0.0, 0.0),
            samples,
        )

    outcomes = [
        outcome(0.002, 0.010, (0.001, 0.002, 0.003)),
        outcome(0.004, 0.012, (0.004, 0.005, 0.006)),
        outcome(0.006, 0.020, (0.007, 0.008, 0.009)),
    ]
    ratio, own = width_over_error(outcomes)
    # median width 12 mm; median error 4 mm; the pooled samples' median 5 mm.
    assert ratio == pytest.approx(3.0) and own == pytest.approx(12.0 / 5.0)


def test_bench_uncertain_quick_prints_both_tables() -> None:
    """The local rows only: the Dask cluster's start-up (about 5 s) is the cluster test's
    business (tests/gate/test_uncertainty.py)."""
    out = run_benchmark("bench_uncertain", "--quick", "--no-cluster")
    batch = table_row(out, "| 12-step plan, scn01, 10 ms, one process")
    assert batch["twins"] == "1" and float(batch["wall p50 s"]) > 0
    verdicts = table_row(out, "| engine | N |")
    assert verdicts["engine"] == "local pool, 1 worker" and verdicts["N"] == "1"
    assert "| local pool, 2 workers | 20 |" in out


@pytest.mark.timeout(300)  # eleven missions in virtual time: CPU, about 20 s on a quiet host
def test_bench_onboard_quick_prints_the_three_tables() -> None:
    out = run_benchmark("bench_onboard", "--quick")
    for header in ("## Overshoot", "## Mission time at a 3 s round trip", "## Loss"):
        assert header in out, out
    assert "| lab | step-by-step |" in out and "| lab | onboard |" in out, out
    assert "| 0.3 | onboard | 1/1 | 0 |" in out, out  # reached, nothing run twice


def test_a_busy_load_ends_with_the_process_that_started_it() -> None:
    # A benchmark killed by a signal must not leave its busy loops beside the next job.
    script = (
        "import os, sys\n"
        "from benchmarks.load import BusyLoad\n"
        "load = BusyLoad(2, duration_s=600).start()\n"
        "print(' '.join(str(p.pid) for p in load._procs), flush=True)\n"
        "os._exit(0)\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=60, check=True
    )
    pids = [int(p) for p in out.stdout.split()]
    assert len(pids) == 2
    for pid in pids:
        assert _ends_within(pid, 30.0), f"busy process {pid} outlived its parent"


def _ends_within(pid: int, timeout_s: float) -> bool:
    """Whether ``pid`` (not our child) is gone within ``timeout_s``, polled (no event exists)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return True
        time.sleep(0.05)
    with contextlib.suppress(ProcessLookupError):
        os.kill(pid, 9)
    return False
