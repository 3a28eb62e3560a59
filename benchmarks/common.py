"""Shared pieces of the benchmark scripts: percentiles, tables, and the pty round trip
that latency figures are set beside (measured in the same run, on the same machine)."""

from __future__ import annotations

import os
import select
import statistics
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import AbstractContextManager, contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import IO

import serial

from firmware_proto.linkio.ptypair import PtyPair

__all__ = [
    "Served",
    "gate_process",
    "percentile",
    "pty_round_trip",
    "readline_within",
    "server_process",
    "summary",
    "table",
    "tree_cpu_s",
]


def tree_cpu_s(pid: int) -> float:
    """CPU time (user + system, s) of a process and its live descendants, from /proc; a
    process that ends meanwhile counts for nothing."""
    tick = os.sysconf("SC_CLK_TCK")
    total = 0.0
    todo = [pid]
    while todo:
        p = todo.pop()
        try:
            fields = Path(f"/proc/{p}/stat").read_text().rsplit(")", 1)[1].split()
            total += (int(fields[11]) + int(fields[12])) / tick
            for task in Path(f"/proc/{p}/task").iterdir():
                todo += [int(c) for c in (task / "children").read_text().split()]
        except (OSError, IndexError, ValueError):
            continue
    return total


def readline_within(stream: IO[str], timeout_s: float, what: str) -> str:
    """One line from a child process's stdout (each of our children answers one line per
    request, so nothing waits in the reader's buffer), or TimeoutError."""
    ready, _, _ = select.select([stream], [], [], timeout_s)
    if not ready:
        raise TimeoutError(f"no answer from {what} within {timeout_s} s")
    return stream.readline()


def percentile(values: list[float], q: float) -> float:
    """The ``q``-th percentile (0..100) by nearest rank."""
    ordered = sorted(values)
    if not ordered:
        return float("nan")
    index = min(len(ordered) - 1, max(0, round(q / 100.0 * (len(ordered) - 1))))
    return ordered[index]


def summary(values_s: list[float]) -> dict[str, float]:
    """p50/p95/p99/max in milliseconds."""
    ms = [v * 1e3 for v in values_s]
    return {
        "n": float(len(ms)),
        "p50": statistics.median(ms) if ms else float("nan"),
        "p95": percentile(ms, 95),
        "p99": percentile(ms, 99),
        "max": max(ms) if ms else float("nan"),
    }


def table(title: str, rows: list[tuple[str, dict[str, float]]], note: str = "") -> str:
    """A Markdown table of latency summaries (ms)."""
    lines = [
        title,
        "",
        "| case | n | p50 ms | p95 ms | p99 ms | max ms |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for name, s in rows:
        lines.append(
            f"| {name} | {s['n']:.0f} | {s['p50']:.3f} | {s['p95']:.3f} | {s['p99']:.3f} | {s['max']:.3f} |"
        )
    if note:
        lines += ["", note]
    return "\n".join(lines)


def pty_round_trip(samples: int = 2000, frame: bytes = bytes(15)) -> list[float]:
    """Host writes a 15-byte frame through pyserial, an echo thread on the other end
    writes it back, the host reads it: seconds per round trip."""
    out: list[float] = []
    with PtyPair() as pair, serial.Serial(pair.device, timeout=1.0) as port:
        stop = threading.Event()

        def echo() -> None:
            while not stop.is_set():
                ready, _, _ = select.select([pair.master_fd], [], [], 0.1)
                if ready:
                    os.write(pair.master_fd, os.read(pair.master_fd, 4096))

        thread = threading.Thread(target=echo, daemon=True)
        thread.start()
        try:
            for _ in range(samples):
                t0 = time.perf_counter()
                port.write(frame)
                got = b""
                while len(got) < len(frame):
                    got += port.read(len(frame) - len(got))
                out.append(time.perf_counter() - t0)
        finally:
            stop.set()
            thread.join(5.0)
    return out


@dataclass(frozen=True)
class Served:
    """A server subprocess: where it listens and its process id."""

    address: tuple[str, int]
    pid: int


@contextmanager
def server_process(argv: list[str], env: dict[str, str]) -> Iterator[Served]:
    """Start a server that prints ``GATE http://host:port`` once listening; SIGTERM on exit."""
    proc = subprocess.Popen(
        argv,
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
        env=dict(os.environ) | env,
    )
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline().split()
        if not line or line[0] != "GATE":
            raise RuntimeError(f"server did not start: {argv}")
        host, port = line[1].removeprefix("http://").split(":")
        yield Served((host, int(port)), proc.pid)
    finally:
        proc.terminate()
        proc.wait(60)


def gate_process(
    env: dict[str, str], pool: str = "process", workers: int = 2
) -> AbstractContextManager[Served]:
    """A ``rover gate`` subprocess on an ephemeral 127.0.0.1 port."""
    rover_exe = str(Path(sys.executable).with_name("rover"))
    return server_process(
        [rover_exe, "gate", "--port", "0", "--pool", pool, "--workers", str(workers)], env
    )
