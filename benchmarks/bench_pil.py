"""Processor in the loop, side by side in one run: the host build of the firmware core,
the nRF51 image under qemu and the ATmega2560 image under simavr.

Run: ``.venv/bin/python -m benchmarks.bench_pil [--trials N] [--quick] [--busy K]``

1. **In the silicon** (emulated cycles, from the port's ``pil_stats``): a STOP frame's
   last byte at the UART to STOP_ACK queued (wheel targets zero), and a HELLO's to IDENT
   queued, with a step at cruise, seven more queued and telemetry at 100 Hz; the host
   build's STOP inside ``fw_on_bytes`` (``bench_fw.c``) beside them. The ATmega2560 runs
   in lockstep (exact cycles at 16 MHz); the nRF51 under ``-icount shift=6``, so its
   figure is an instruction count, not an M0's cycles. On a real wire the frame's own
   time on the 115200 line comes first.
2. **Over the pty, in real time** (wall): ``rover bench stop`` (STOP written -> STOP_ACK
   read, p50 and p99) and HELLO -> IDENT through a ``ProtocolHost``, against ``rover
   emulate --firmware c`` (the host build in the loop), ``rover pil --target microbit``
   and ``rover pil --target atmega2560``; and each emulator's CPU (its processes'
   user+system time over the run's wall time, % of one core).
3. **fw_tick's worst case** since boot (``pil_stats.tick_max``) against the 1 ms period
   (16,000 cycles at 16 MHz) and against the tick each port runs.

``--busy K`` runs everything beside K busy processes (``benchmarks.load``).
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

from benchmarks.bench_firmware import build_bench, c_stop_ns
from benchmarks.common import percentile, tree_cpu_s
from benchmarks.load import BusyLoad
from emulator.pil.avr import avr_lockstep_pair, make_system
from emulator.pil.images import build_image
from emulator.pil.qemu import MicrobitTarget
from emulator.pil.view import PilStats
from firmware_proto.linkio.endpoint import HOST
from firmware_proto.linkio.host import ProtocolHost
from firmware_proto.linkio.media import open_endpoint
from firmware_proto.wire.messages import (
    PROTOCOL_VERSION,
    SCHEMA_HASH,
    Command,
    Hello,
    Ident,
    Motion,
    Param,
    SetParam,
    Stop,
    StopAck,
)

CPU_HZ = 16_000_000
WIRE_MS = 15 * 10 / 117_647 * 1e3
"""A 15-byte frame on the ATmega2560's 117,647 baud line, ms."""


def _ack_of(stop_id: int) -> Callable[[StopAck], bool]:
    return lambda m: m.stop_id == stop_id


def _script(
    host: ProtocolHost, trials: int, get: Callable[[], PilStats]
) -> tuple[list[int], list[int]]:
    """HELLO -> IDENT and STOP -> STOP_ACK, ``trials`` each; the port's own counts of each
    (``get()`` reads ``pil_stats``)."""
    idents, stops = [], []
    for _ in range(trials):
        mark = host.mark()
        host.send(Hello(PROTOCOL_VERSION, SCHEMA_HASH))
        host.expect(Ident, since=mark, timeout_s=2.0)
        host.settle(0.05)
        idents.append(get().ident_last)
    host.send(SetParam(Param.TELEMETRY_HZ, 100))
    seq = 1000
    for trial in range(trials):
        stop_id = trial + 1
        for _ in range(8):
            host.send(Motion(seq, Command.FWD, 40, 30000))
            seq += 1
        host.settle(0.4 + 0.01 * (trial % 7))
        mark = host.mark()
        host.send(Stop(stop_id, 4))
        host.expect(StopAck, _ack_of(stop_id), since=mark, timeout_s=2.0)
        host.settle(0.05)
        stops.append(get().stop_ack_last)
        host.settle(0.45)
        host.send(host.clear_stop_for(stop_id))
        host.settle(0.05)
    return idents, stops


def in_silicon(trials: int) -> list[str]:
    """Table 1 and the tick figures of table 3."""
    rows = []
    # ATmega2560, lockstep: exact cycles.
    system = make_system(build_image("atmega2560"), map_name=None, seed=1)
    avr, endpoint, clock = avr_lockstep_pair(system)
    avr.open()
    try:
        with ProtocolHost(endpoint, clock=clock) as host:
            host.handshake()
            idents, stops = _script(host, trials, lambda: system.view()[1])
        avr_stats = system.view()[1]
    finally:
        avr.close()
    # nRF51 under qemu -icount shift=6.
    with MicrobitTarget(build_image("microbit"), icount=6) as mb:
        endpoint = open_endpoint(mb.device, HOST)
        with ProtocolHost(endpoint) as host:
            host.handshake(every_s=0.2)
            mb_idents, mb_stops = _script(host, trials, mb.port_stats)
        mb_stats = mb.port_stats()
    with tempfile.TemporaryDirectory() as tmp:
        host_ns = c_stop_ns(build_bench(Path(tmp)), max(trials, 200))

    def row(name: str, counts: list[int], per_us: float, unit: str) -> str:
        p50, p99 = statistics.median(counts), percentile([float(c) for c in counts], 99)
        return (
            f"| {name} | {len(counts)} | {p50:,.0f} {unit} | {p99:,.0f} {unit} | "
            f"{p50 / per_us:,.1f} | {p99 / per_us:,.1f} |"
        )

    rows += [
        "### 1. In the silicon: last byte received -> answer queued (STOP_ACK: targets zero)",
        "",
        "| case | n | p50 | p99 | p50 us | p99 us |",
        "|---|---:|---:|---:|---:|---:|",
        row("STOP -> STOP_ACK, ATmega2560 @ 16 MHz (simavr, lockstep)", stops, 16.0, "cycles"),
        row(
            "STOP -> STOP_ACK, nRF51 (qemu -icount 6: ~1.024 counts/instruction; us at 16 MHz)",
            mb_stops,
            16.0,
            "counts",
        ),
        f"| STOP inside fw_on_bytes, host build x86-64 -O2 (bench_fw.c) | {len(host_ns)} | "
        f"{statistics.median(host_ns):,.0f} ns | {percentile(host_ns, 99):,.0f} ns | "
        f"{statistics.median(host_ns) / 1e3:.2f} | {percentile(host_ns, 99) / 1e3:.2f} |",
        row("HELLO -> IDENT, ATmega2560", idents, 16.0, "cycles"),
        row("HELLO -> IDENT, nRF51 (icount)", mb_idents, 16.0, "counts"),
        "",
        f"On a 115200 line each frame takes {WIRE_MS:.2f} ms (15 bytes) before the first "
        "byte above is counted.",
        "",
        "### 3. fw_tick's worst case since boot (pil_stats.tick_max)",
        "",
        "| MCU | worst fw_tick | of a 1 ms period (16,000 cycles) | its own tick |",
        "|---|---:|---:|---:|",
        f"| ATmega2560 @ 16 MHz | {avr_stats.tick_max:,} cycles | "
        f"{avr_stats.tick_max / 16000:.0%} | 10 ms: {avr_stats.tick_max / 160000:.0%} |",
        f"| nRF51 (qemu -icount 6) | {mb_stats.tick_max:,} counts (~{mb_stats.tick_max / 1.024:,.0f}"
        f" instructions) | {mb_stats.tick_max / 16000:.0%} | 1 ms: {mb_stats.tick_max / 16000:.0%} |",
        "",
    ]
    return rows


def _serve(args: list[str], tmp: Path) -> tuple[subprocess.Popen[str], str]:
    link = tmp / "motor"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "firmware_proto.cli",
            *args,
            "--link",
            str(link),
            "--control-port",
            "0",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )
    assert proc.stdout is not None
    for _ in range(2):
        proc.stdout.readline()
    return proc, str(link)


def over_the_pty(trials: int) -> list[str]:
    """Table 2."""
    cases = [
        (
            "host build in the loop (rover emulate --firmware c)",
            ["emulate", "--serial", "--firmware", "c"],
        ),
        ("nRF51 image (rover pil --target microbit)", ["pil", "--target", "microbit"]),
        ("ATmega2560 image (rover pil --target atmega2560)", ["pil", "--target", "atmega2560"]),
    ]
    rows = [
        "### 2. Over the pty, in real time (wall, ms)",
        "",
        "| controller | STOP -> STOP_ACK p50 | p99 | HELLO -> IDENT p50 | p99 | emulator CPU |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for name, args in cases:
        with tempfile.TemporaryDirectory() as tmp_name:
            tmp = Path(tmp_name)
            proc, link = _serve(args, tmp)
            try:
                cpu0, wall0 = tree_cpu_s(proc.pid), time.monotonic()
                hellos = []
                with ProtocolHost(open_endpoint(link, HOST)) as host:
                    host.handshake(every_s=0.2)
                    for _ in range(trials):
                        mark = host.mark()
                        t0 = host.now()
                        host.send(Hello(PROTOCOL_VERSION, SCHEMA_HASH))
                        found = host.find(Ident, since=mark, timeout_s=2.0)
                        if found is None:
                            raise RuntimeError(f"{name}: no IDENT")
                        hellos.append((found[1].arrived - t0) * 1e3)
                        host.settle(0.05)
                out = subprocess.run(
                    [
                        sys.executable,
                        "-m",
                        "firmware_proto.cli",
                        "bench",
                        "stop",
                        "--serial",
                        link,
                        "--trials",
                        str(trials),
                        "--seed",
                        "7",
                        "--out",
                        str(tmp / "b"),
                    ],
                    capture_output=True,
                    text=True,
                    timeout=600,
                    check=False,
                )
                cpu = (tree_cpu_s(proc.pid) - cpu0) / (time.monotonic() - wall0)
                doc = json.loads((tmp / "b" / "stop_trials.json").read_text())
                acks = [t["ack_ms"] for t in doc["trials"] if t["ack_ms"] is not None]
                lost = trials - sum(1 for t in doc["trials"] if t["ok"])
                rows.append(
                    f"| {name} | {statistics.median(acks):.2f} | {percentile(acks, 99):.2f} | "
                    f"{statistics.median(hellos):.2f} | {percentile(hellos, 99):.2f} | "
                    f"{cpu:.0%} of a core{f' ({lost} trials lost)' if lost else ''} |"
                )
                if out.returncode not in (0, 1):
                    raise RuntimeError(out.stderr)
            finally:
                proc.terminate()
                proc.wait(20)
    rows.append("")
    return rows


def main(argv: list[str] | None = None) -> int:
    """Print the three tables (Markdown)."""
    p = argparse.ArgumentParser(prog="python -m benchmarks.bench_pil")
    p.add_argument("--trials", type=int, default=20)
    p.add_argument("--quick", action="store_true", help="5 trials")
    p.add_argument("--busy", type=int, default=0, help="beside this many busy processes")
    args = p.parse_args(argv)
    trials = 5 if args.quick else args.trials
    load = BusyLoad(args.busy, 3600) if args.busy else None
    if load is not None:
        load.__enter__()
    try:
        started = time.monotonic()
        rows = [f"## PIL, {trials} trials, load: {args.busy} busy processes", ""]
        rows += in_silicon(trials)
        rows += over_the_pty(trials)
        rows.append(f"({time.monotonic() - started:.0f} s)")
    finally:
        if load is not None:
            load.__exit__(None, None, None)
    print("\n".join(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
