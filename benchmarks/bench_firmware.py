"""The C firmware core beside the Python controller model, in the same run: STOP frame in
-> wheel targets zero, control ticks per second, and instructions per ``fw_tick``.

Run: ``.venv/bin/python -m benchmarks.bench_firmware [--quick]``

- STOP: each trial drives a step at cruise speed (40 speed units, 0.2 m/s) with seven
  more queued, then hands the controller one STOP, timed from the call to its return
  (wheel targets checked zero then). Rows: the C core in C (``fw_on_bytes``,
  ``firmware_proto/wire/c/fw/tests/bench_fw.c``, -O2); the same core in the emulator
  (:meth:`FirmwareController.handle`, ctypes and codecs included); the Python model
  (:meth:`ControllerModel.handle`).
- Ticks/s: lockstep control ticks with the twin at the 1 ms step, telemetry on, for both
  controllers (the twin's physics is in both figures).
- Instructions per ``fw_tick``: ``valgrind --tool=callgrind --toggle-collect=fw_tick``
  over 20,000 ticks of driving with telemetry at the default rates, host x86-64 -O2
  build, an ideal plant behind the HAL: an estimate for an MCU (a Cortex-M0+ needs more
  for the 64-bit arithmetic).
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import subprocess
import tempfile
import time
from pathlib import Path

from benchmarks.common import percentile
from emulator.controller import ControllerConfig, ControllerModel
from emulator.firmware import C_DIR, FirmwareController
from emulator.twin import Twin
from firmware_proto.model.rover import RoverDescription, load_rover
from firmware_proto.wire.messages import (
    PROTOCOL_VERSION,
    SCHEMA_HASH,
    ClearStop,
    Command,
    Hello,
    HostHeartbeat,
    Motion,
    Stop,
)

CORE = ("fw/fw.c", "rover_msgs.c", "rover_proto.c")


def build_bench(out_dir: Path) -> Path:
    """Compile ``bench_fw.c`` with the core (-O2 -g)."""
    exe = out_dir / "bench_fw"
    cc = shutil.which("gcc") or shutil.which("cc")
    if cc is None:
        raise SystemExit("bench_firmware: no C compiler")
    subprocess.run(
        [
            cc,
            "-std=c99",
            "-Wall",
            "-Wextra",
            "-Werror",
            "-pedantic",
            "-O2",
            "-g",
            f"-I{C_DIR}",
            *(str(C_DIR / s) for s in CORE),
            str(C_DIR / "fw" / "tests" / "bench_fw.c"),
            "-o",
            str(exe),
        ],
        check=True,
        timeout=120,
    )
    return exe


def c_stop_ns(exe: Path, trials: int) -> list[float]:
    """Nanoseconds per STOP inside the core, measured by bench_fw."""
    out = subprocess.run(
        [str(exe), "stop", str(trials)], capture_output=True, text=True, check=True, timeout=300
    ).stdout
    rows = [line.split() for line in out.splitlines()]
    if not all(row[1] == "9" for row in rows):
        raise RuntimeError("bench_fw: expected STOP_ACK and 8 aborted STATUS per trial")
    return [float(row[0]) for row in rows]


def model_stop_ns(model: ControllerModel, trials: int) -> list[float]:
    """Nanoseconds per ``model.handle(Stop)`` in the same scenario as bench_fw."""
    model.boot()
    model.handle(Hello(PROTOCOL_VERSION, SCHEMA_HASH))
    out: list[float] = []
    seq = 0
    for trial in range(trials):
        stop_id = trial % 60000 + 1
        model.handle(ClearStop(stop_id, model.latch_gen))
        for _ in range(8):
            model.handle(Motion(seq & 0xFFFF, Command.FWD, 40, 30000))
            seq += 1
        for k in range(400):
            if k % 50 == 0:
                model.handle(HostHeartbeat(k))
            model.tick()
        if model.wheel_setpoints_mps[0] <= 0.1 or model.queue_depth != 8:
            raise RuntimeError(f"trial {trial}: not driving with 8 steps queued")
        msg = Stop(stop_id, 4)
        t0 = time.perf_counter_ns()
        answers = model.handle(msg)
        t1 = time.perf_counter_ns()
        if model.wheel_setpoints_mps != (0.0, 0.0) or len(answers) != 9:
            raise RuntimeError(f"trial {trial}: STOP did not zero the targets and purge")
        out.append(float(t1 - t0))
        while model.wheel_commands_mps[0] != 0.0:
            model.handle(HostHeartbeat(0))
            model.tick()
    return out


def tick_rate(model: ControllerModel, seconds: float) -> float:
    """Lockstep ticks/s driving with telemetry."""
    model.boot()
    model.handle(Hello(PROTOCOL_VERSION, SCHEMA_HASH))
    for seq in range(8):
        model.handle(Motion(seq, Command.FWD, 40, 30000))
    ticks = 0
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        for _ in range(100):
            model.tick()
        model.handle(HostHeartbeat(ticks & 0xFFFF))
        ticks += 100
    return ticks / (time.perf_counter() - t0)


def instructions_per_tick(exe: Path, ticks: int, work: Path) -> float | None:
    """Callgrind's instruction count inside ``fw_tick``, per call; ``None`` without valgrind."""
    valgrind = shutil.which("valgrind")
    if valgrind is None:
        return None
    out_file = work / "callgrind.out"
    subprocess.run(
        [
            valgrind,
            "--tool=callgrind",
            "--toggle-collect=fw_tick",
            f"--callgrind-out-file={out_file}",
            str(exe),
            "ticks",
            str(ticks),
        ],
        capture_output=True,
        check=True,
        timeout=600,
    )
    for line in out_file.read_text().splitlines():
        if line.startswith("summary:"):
            return int(line.split()[1]) / ticks
    return None


def _row(name: str, ns: list[float]) -> str:
    us = [v / 1000.0 for v in ns]
    return (
        f"| {name} | {len(us)} | {statistics.median(us):.2f} | {percentile(us, 99):.2f} |"
        f" {max(us):.2f} |"
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--quick", action="store_true", help="shorter runs (smoke test)")
    args = parser.parse_args(argv)
    trials, seconds, ticks = (50, 0.3, 2000) if args.quick else (1000, 3.0, 20000)
    rover: RoverDescription = load_rover()
    with tempfile.TemporaryDirectory(prefix="bench-fw-") as tmp:
        work = Path(tmp)
        exe = build_bench(work)
        c_ns = c_stop_ns(exe, trials)
        ctypes_ns = model_stop_ns(
            FirmwareController(rover, Twin(rover), ControllerConfig()), trials
        )
        py_ns = model_stop_ns(ControllerModel(rover, Twin(rover), ControllerConfig()), trials)
        print("STOP frame in -> wheel targets zero (a step at cruise, 7 queued; host, one core)\n")
        print("| controller | n | p50 us | p99 us | max us |")
        print("|---|---:|---:|---:|---:|")
        print(_row("C core, fw_on_bytes(STOP frame), measured in C", c_ns))
        print(_row("C core in the emulator (FirmwareController.handle, ctypes)", ctypes_ns))
        print(_row("Python model (ControllerModel.handle)", py_ns))
        ratio = statistics.median(py_ns) / statistics.median(c_ns)
        print(f"\nPython model p50 / C core p50: {ratio:.0f}x\n")

        c_rate = tick_rate(FirmwareController(rover, Twin(rover), ControllerConfig()), seconds)
        py_rate = tick_rate(ControllerModel(rover, Twin(rover), ControllerConfig()), seconds)
        print("Lockstep control ticks with the twin (1 ms step, driving, telemetry on)\n")
        print("| controller | ticks/s | x real time |")
        print("|---|---:|---:|")
        print(f"| C core + twin (FirmwareController) | {c_rate:,.0f} | {c_rate / 1000:,.0f} |")
        print(f"| Python model + twin (ControllerModel) | {py_rate:,.0f} | {py_rate / 1000:,.0f} |")

        per_tick = instructions_per_tick(exe, ticks, work)
        shown = "n/a (valgrind not installed)" if per_tick is None else f"{per_tick:,.0f}"
        print(f"\nInstructions per fw_tick (callgrind, x86-64 -O2, driving): {shown}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
