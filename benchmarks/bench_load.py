"""The controller link beside load: missions, heartbeat gaps and STOP latency with and
without real-time scheduling, against the controller's 250 ms watchdog.

Run (in the private network namespace, as the demo tests run)::

    unshare -n -- bash -c 'ip link set lo up && ip link set lo multicast on &&
        exec .venv/bin/python -m benchmarks.bench_load --busy 0,2,4,8 --runs 10'

For each number of busy processes (:mod:`benchmarks.load`) and for real time off and on
(``rover demo --no-realtime``, and the default):

- ``rover demo --speed 4``, ``--runs`` times: how many reached the goal; the longest and
  p99 heartbeat gaps at each end of the controller link, worst over the runs (the
  bridge's ``/diagnostics``, the emulator's control port); the emulator's catch-ups;
  the stalls over 100 ms the stack's processes logged;
- STOP: ``ControllerLink.emergency_stop`` in this process -> wheel targets zero in an
  emulator process over a pty (``bench_bridge``'s trials), ``--stop-trials`` times.

``--quick`` (the smoke test): 3 STOP trials beside 2 busy processes. Each figure stands
beside the same load without real time, from the same run, and beside the limits
(250 ms watchdog, 100 ms heartbeat period).
"""

from __future__ import annotations

import argparse
import json
import random
import re
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

from benchmarks.bench_bridge import EmulatorProcess, Statuses
from benchmarks.common import percentile
from benchmarks.load import BusyLoad
from bridge.link.controllerlink import ControllerLink, LinkConfig, StepRequest
from firmware_proto.runtime.realtime import (
    BRIDGE_PRIORITY,
    EMULATOR_PRIORITY,
    RealtimeConfig,
    apply_realtime,
)
from firmware_proto.wire.messages import Command

_TIMING = re.compile(
    r"bridge rx (\S+)/(\S+), bridge tx (\S+)/(\S+), emulator rx (\S+)/(\S+); "
    r"emulator catch-ups (\S+) \(latest (\S+) ms\)"
)
_DEMO_TIMEOUT_S = 300.0


def _number(text: str) -> float | None:
    return None if text == "n/a" else float(text)


@dataclass
class DemoRuns:
    """What ``--runs`` demos at one load showed."""

    reached: int = 0
    runs: int = 0
    ends: list[str] = field(default_factory=list)
    gaps: dict[str, list[float]] = field(default_factory=dict)
    catchups: int = 0
    late_max_ms: float = 0.0
    stalls: int = 0
    stall_max_ms: float = 0.0
    stalled: set[str] = field(default_factory=set)

    def add_gap(self, name: str, value: float | None) -> None:
        if value is not None:
            self.gaps.setdefault(name, []).append(value)

    def worst(self, name: str) -> str:
        values = self.gaps.get(name)
        return f"{max(values):.0f}" if values else "n/a"


def run_demo(realtime: bool, workdir: Path, index: int) -> tuple[bool, str, list[str]]:
    """One ``rover demo --speed 4``; (reached, how it ended, its stdout lines)."""
    command = [
        sys.executable,
        "-m",
        "firmware_proto.cli",
        "demo",
        "--speed",
        "4",
        "--no-record",
        "--picture",
        str(workdir / f"demo-{index}.png"),
    ]
    if not realtime:
        command.append("--no-realtime")
    try:
        done = subprocess.run(
            command, capture_output=True, text=True, timeout=_DEMO_TIMEOUT_S, check=False
        )
    except subprocess.TimeoutExpired:
        return False, "timed out", []
    lines = done.stdout.splitlines()
    verdict = next((line for line in lines if line.startswith("mission to ")), "")
    reached = verdict.endswith("REACHED") and "NOT REACHED" not in verdict
    end = "reached" if reached else (verdict.partition(": ")[2] or f"exit {done.returncode}")
    return reached, end, lines


def demos(count: int, runs: int, realtime: bool, workdir: Path) -> DemoRuns:
    """``runs`` demos beside ``count`` busy processes."""
    out = DemoRuns()
    with BusyLoad(count, duration_s=runs * _DEMO_TIMEOUT_S + 60):
        for index in range(runs):
            reached, end, lines = run_demo(realtime, workdir, index)
            out.runs += 1
            out.reached += reached
            out.ends.append(end)
            for line in lines:
                match = _TIMING.search(line)
                if match:
                    values = [_number(v) for v in match.groups()]
                    for name, value in zip(
                        ("bridge_rx_max", "bridge_rx_p99", "bridge_tx_max", "bridge_tx_p99"),
                        values[:4],
                        strict=True,
                    ):
                        out.add_gap(name, value)
                    out.add_gap("emulator_rx_max", values[4])
                    out.add_gap("emulator_rx_p99", values[5])
                    out.catchups += int(values[6] or 0)
                    out.late_max_ms = max(out.late_max_ms, values[7] or 0.0)
                if line.startswith("logs: "):
                    _read_stalls(Path(line.split()[1]) / "stalls.jsonl", out)
    return out


def _read_stalls(path: Path, out: DemoRuns) -> None:
    try:
        text = path.read_text()
    except OSError:
        return
    for line in text.splitlines():
        try:
            record = json.loads(line)
        except ValueError:
            continue
        out.stalls += 1
        out.stall_max_ms = max(out.stall_max_ms, float(record["ms"]))
        out.stalled.add(str(record["process"]))


@dataclass
class StopRuns:
    """STOP trials at one load: latencies (s), trials that could not run (the link
    faulted before the STOP: a watchdog trip or a lost link), and the link's counts."""

    zeroed: list[float] = field(default_factory=list)
    failed: int = 0
    watchdog_trips: int = 0
    link_losses: int = 0


def _wait_any(statuses: Statuses, mark: int, words: tuple[str, ...], timeout_s: float) -> str:
    """The first status after ``mark`` that starts with one of ``words`` ('' on timeout)."""
    found = statuses.log.wait(lambda text: text.startswith(words), since=mark, timeout_s=timeout_s)
    return found[1] if found is not None else ""


def stop_latency(count: int, trials: int, realtime: bool, seed: int) -> StopRuns:
    """API call -> wheel targets zero, ``trials`` times beside ``count`` busy processes.
    This process's link threads and the emulator child at real-time priority or not."""
    apply_realtime(RealtimeConfig(BRIDGE_PRIORITY if realtime else 0, lock_memory=False))
    rng = random.Random(seed)
    out = StopRuns()
    with (
        BusyLoad(count, duration_s=600),
        EmulatorProcess(seed, EMULATOR_PRIORITY if realtime else 0) as emu,
    ):
        statuses = Statuses()
        link = ControllerLink(LinkConfig(emu.device), on_status=statuses)
        with link:
            statuses.wait("ready", 0, timeout=30.0)
            for _ in range(trials):
                mark = statuses.mark()
                link.submit_step(StepRequest(Command.FWD, 60, 30000))
                if (
                    _wait_any(statuses, mark, ("accepted", "rejected", "fault", "aborted"), 10.0)
                    != "accepted"
                ):
                    out.failed += 1  # the link faulted: clear and go on
                else:
                    time.sleep(rng.uniform(0.05, 0.25))  # STOP at a random moment
                    before = emu.stops()
                    t0 = time.monotonic()
                    link.emergency_stop()
                    handled = emu.stop_handled(before)
                    if handled is None:
                        out.failed += 1
                    else:
                        out.zeroed.append(handled - t0)
                mark = statuses.mark()
                link.clear_stop()
                _wait_any(statuses, mark, ("cleared", "fault"), 10.0)
                deadline = time.monotonic() + 30.0
                while not link.ready and time.monotonic() < deadline:
                    time.sleep(0.05)  # a lost link handshakes again by itself
            diag = link.diagnostics()
            out.watchdog_trips, out.link_losses = diag.watchdog_trips, diag.heartbeat_losses
    apply_realtime(RealtimeConfig(0))
    return out


def _ms(values: list[float], q: float) -> str:
    return f"{percentile(values, q) * 1e3:.2f}" if values else "n/a"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--busy", default="0,2,4,8", help="busy-process counts, comma-separated (0,2,4,8)"
    )
    parser.add_argument("--runs", type=int, default=10, help="demos per case (default 10)")
    parser.add_argument(
        "--stop-trials", type=int, default=50, help="STOP trials per case (default 50)"
    )
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument(
        "--quick", action="store_true", help="STOP trials only: 3, beside 2 busy processes"
    )
    args = parser.parse_args(argv)
    try:
        counts = [int(x) for x in args.busy.split(",") if x.strip()]
    except ValueError:
        parser.error(f"--busy: expected numbers separated by commas, got {args.busy!r}")
    if args.quick:
        counts, args.runs, args.stop_trials = [2], 0, 3
    if args.runs < 0 or args.stop_trials < 1 or any(c < 0 for c in counts):
        parser.error("--runs >= 0, --stop-trials >= 1 and busy counts >= 0")

    rows = []
    with tempfile.TemporaryDirectory(prefix="bench-load-") as tmp:
        for count in counts:
            for realtime in (False, True):
                runs = demos(count, args.runs, realtime, Path(tmp)) if args.runs else None
                stops = stop_latency(count, args.stop_trials, realtime, args.seed)
                rows.append((count, realtime, runs, stops))
                print(
                    f"  measured: {count} busy, real time {'on' if realtime else 'off'}",
                    file=sys.stderr,
                )

    print("The controller link beside load (bench_load)")
    print()
    print(
        "| busy | real time | missions reached | bridge rx gap max/p99 ms | "
        "bridge tx gap max/p99 ms | emulator rx gap max/p99 ms | emulator catch-ups "
        "(latest ms) | stalls > 100 ms (longest ms; who) | STOP p50/p99 ms (n) | "
        "STOP trials failed; watchdog trips; links lost |"
    )
    print("|---:|---|---|---|---|---|---|---|---|---|")
    for count, realtime, runs, stops in rows:
        if runs is None:
            demo_cells = ["not run"] * 6
        else:
            ends = [e for e in runs.ends if e != "reached"]
            demo_cells = [
                f"{runs.reached}/{runs.runs}" + (f" ({'; '.join(ends)})" if ends else ""),
                f"{runs.worst('bridge_rx_max')}/{runs.worst('bridge_rx_p99')}",
                f"{runs.worst('bridge_tx_max')}/{runs.worst('bridge_tx_p99')}",
                f"{runs.worst('emulator_rx_max')}/{runs.worst('emulator_rx_p99')}",
                f"{runs.catchups} ({runs.late_max_ms:.0f})",
                f"{runs.stalls} ({runs.stall_max_ms:.0f}; {','.join(sorted(runs.stalled)) or '-'})",
            ]
        stop_cell = f"{_ms(stops.zeroed, 50)}/{_ms(stops.zeroed, 99)} ({len(stops.zeroed)})"
        faults = f"{stops.failed}; {stops.watchdog_trips}; {stops.link_losses}"
        print(
            f"| {count} | {'on' if realtime else 'off'} | "
            + " | ".join(demo_cells)
            + f" | {stop_cell} | {faults} |"
        )
    print()
    print(
        "Limits: the controller's watchdog stops the rover after 250 ms without a valid "
        "frame; heartbeats are sent every 100 ms (a gap of 100 ms is on time). Gaps are the "
        "worst of the runs. Real time off is the peer, measured in the same run."
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
