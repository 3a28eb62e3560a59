"""Where a command's CPU goes: its processes' CPU-seconds by name, beside the machine's.

Run as root (process accounting is the kernel's, for the whole machine)::

    sudo .venv/bin/python -m benchmarks.cpu_map -- bash .ci/test

The kernel writes one record for every process that ends while accounting is on (BSD
process accounting, ``acct(2)``: its name, user and system time). The command's
processes are named after what they run (``rover-bridge``, ``pytest-host-gw0``:
docs/realtime.md, "Which process is which"; docs/testing.md, "Where the CPU goes"),
so the table says which kind of process took the CPU. Beside it, in the same run: the
machine's busy CPU from ``/proc/stat`` and the limit, the cores times the wall time.

What it cannot see: a process still running when the command ends (none of a test
run's), and it counts every process on the machine that ended meanwhile, ours or not.
Accounting is one switch per PID namespace: two maps at once in the same namespace take
it from each other (the second to start writes the file; the first to end turns it off).
A map inside a mapped run runs in a namespace of its own (``unshare --pid --fork``): the
kernel writes each ended process to its namespace's file and to every one above.
"""

from __future__ import annotations

import argparse
import ctypes
import os
import struct
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

__all__ = ["ProcessRecord", "by_name", "read_records", "table"]

RECORD_BYTES = 64
"""``struct acct_v3`` (linux/acct.h)."""
AHZ = 100
"""Accounting ticks per second in a version-3 record."""
_VERSION = 3


@dataclass(frozen=True)
class ProcessRecord:
    """One ended process, as the kernel accounted it.

    Attributes:
        name: its name (``/proc/PID/comm`` when it ended, at most 15 bytes).
        pid: its process id.
        cpu_s: user and system time, s (to the kernel's 10 ms).
    """

    name: str
    pid: int
    cpu_s: float


def _comp_t(value: int) -> int:
    """A ``comp_t``: a 13-bit mantissa and a 3-bit base-8 exponent."""
    return (value & 0x1FFF) << (3 * (value >> 13))


def read_records(data: bytes) -> list[ProcessRecord]:
    """The records of a version-3 accounting file.

    Raises:
        ValueError: a record of another version (a kernel without version 3 records).
    """
    records = []
    for offset in range(0, len(data) - RECORD_BYTES + 1, RECORD_BYTES):
        raw = data[offset : offset + RECORD_BYTES]
        if raw[1] != _VERSION:
            raise ValueError(
                f"accounting record {offset // RECORD_BYTES} is version {raw[1]}, not 3"
            )
        (pid,) = struct.unpack_from("<I", raw, 16)
        utime, stime = struct.unpack_from("<HH", raw, 32)
        name = raw[48:64].split(b"\0", 1)[0].decode("ascii", errors="replace")
        records.append(ProcessRecord(name, pid, (_comp_t(utime) + _comp_t(stime)) / AHZ))
    return records


def _kind(name: str) -> str:
    """Kernel threads by kind (``kworker/u8:1`` -> ``kworker/*``); others as named."""
    return name.split("/", 1)[0] + "/*" if "/" in name else name


def by_name(records: Iterable[ProcessRecord]) -> list[tuple[str, int, float]]:
    """``(name, processes, CPU-seconds)``, most CPU first."""
    totals: dict[str, list[float]] = {}
    for record in records:
        row = totals.setdefault(_kind(record.name), [0, 0.0])
        row[0] += 1
        row[1] += record.cpu_s
    return sorted(
        ((name, int(n), cpu) for name, (n, cpu) in totals.items()), key=lambda r: (-r[2], r[0])
    )


def table(rows: Sequence[tuple[str, int, float]], *, wall_s: float, busy_s: float, top: int) -> str:
    """A Markdown table of the first ``top`` rows, the rest summed, and the totals beside
    the machine's busy CPU and the limit (cores times ``wall_s``)."""
    accounted = sum(cpu for _, _, cpu in rows)
    share = (lambda cpu: f"{100.0 * cpu / accounted:.1f} %") if accounted > 0 else (lambda _: "-")
    lines = ["| process | processes | CPU s | share |", "|---|---:|---:|---:|"]
    for name, n, cpu in rows[:top]:
        lines.append(f"| `{name}` | {n} | {cpu:.1f} | {share(cpu)} |")
    rest = rows[top:]
    if rest:
        cpu = sum(r[2] for r in rest)
        lines.append(
            f"| {len(rest)} others | {sum(r[1] for r in rest)} | {cpu:.1f} | {share(cpu)} |"
        )
    cores = os.cpu_count() or 1
    lines += [
        f"| **ended processes** | {sum(r[1] for r in rows)} | **{accounted:.1f}** | |",
        f"| the machine, busy (/proc/stat) | | {busy_s:.1f} | |",
        f"| the limit: {cores} cores x {wall_s:.1f} s | | {cores * wall_s:.1f} | |",
    ]
    return "\n".join(lines)


def _busy_s() -> float:
    """The machine's busy CPU-seconds since boot (``/proc/stat``: all but idle and iowait)."""
    fields = [int(v) for v in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]]
    idle = fields[3] + (fields[4] if len(fields) > 4 else 0)
    return (sum(fields[:8]) - idle) / os.sysconf("SC_CLK_TCK")


def _acct(path: str | None) -> None:
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.acct(None if path is None else os.fsencode(path)) != 0:
        errno = ctypes.get_errno()
        why = "process accounting needs root (CAP_SYS_PACCT)" if errno == 1 else ""
        raise OSError(errno, why or os.strerror(errno))


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command under process accounting; print the table; its exit status."""
    parser = argparse.ArgumentParser(
        prog="python -m benchmarks.cpu_map",
        description="Run COMMAND under BSD process accounting (root) and print its "
        "processes' CPU-seconds by process name, beside the machine's busy CPU and the "
        "cores times the wall time.",
    )
    parser.add_argument("--top", type=int, default=25, help="rows to show (default 25)")
    parser.add_argument("-o", "--output", type=Path, help="also write the table here")
    parser.add_argument("command", nargs=argparse.REMAINDER, help="-- COMMAND [ARGS...]")
    args = parser.parse_args(argv)
    command = args.command[1:] if args.command[:1] == ["--"] else args.command
    if not command:
        parser.error("no command: python -m benchmarks.cpu_map -- COMMAND [ARGS...]")
    if args.top < 1:
        parser.error("--top must be 1 or more")
    with tempfile.TemporaryDirectory(prefix="cpu-map-") as tmp:
        log = Path(tmp) / "pacct"
        log.touch()
        try:
            _acct(str(log))
        except OSError as exc:
            print(f"cpu_map: error: {exc.strerror}", file=sys.stderr)
            return 2
        busy0, start = _busy_s(), time.monotonic()
        try:
            status = subprocess.run(command, check=False).returncode
        except OSError as exc:
            print(f"cpu_map: error: {command[0]}: {exc.strerror}", file=sys.stderr)
            status = 127
        except KeyboardInterrupt:
            status = 130
        finally:
            _acct(None)
        wall_s, busy_s = time.monotonic() - start, _busy_s() - busy0
        rows = by_name(read_records(log.read_bytes()))
    text = table(rows, wall_s=wall_s, busy_s=busy_s, top=args.top)
    print(text)
    if args.output is not None:
        args.output.write_text(text + "\n", encoding="utf-8")
    return status


if __name__ == "__main__":
    sys.exit(main())
