"""benchmarks/cpu_map.py: a command's CPU by process name, from process accounting."""

from __future__ import annotations

import os
import struct
import subprocess
import sys

import pytest

from benchmarks.cpu_map import ProcessRecord, by_name, read_records, table


def _record(name: str, pid: int, utime: int, stime: int, version: int = 3) -> bytes:
    """A ``struct acct_v3`` with the fields the map reads (times as ``comp_t``)."""
    raw = bytearray(64)
    raw[1] = version
    struct.pack_into("<I", raw, 16, pid)
    struct.pack_into("<HH", raw, 32, utime, stime)
    raw[48 : 48 + len(name)] = name.encode()
    return bytes(raw)


def test_records_are_read_with_their_comp_t_times() -> None:
    # 150 ticks; 8191 << 3 (exponent 1) = 65528 ticks.
    data = _record("rover-bridge", 7, 100, 50) + _record("pytest-host-gw0", 8, 0x3FFF, 0)
    assert read_records(data) == [
        ProcessRecord("rover-bridge", 7, 1.5),
        ProcessRecord("pytest-host-gw0", 8, 655.28),
    ]


def test_another_version_is_refused_by_name() -> None:
    with pytest.raises(ValueError, match="record 1 is version 2, not 3"):
        read_records(_record("a", 1, 1, 1) + _record("b", 2, 1, 1, version=2))


def test_processes_are_summed_by_name_and_kernel_threads_by_kind() -> None:
    records = [
        ProcessRecord("rover-bridge", 1, 2.0),
        ProcessRecord("kworker/u8:1", 2, 0.5),
        ProcessRecord("rover-bridge", 3, 1.0),
        ProcessRecord("kworker/u8:3", 4, 0.25),
        ProcessRecord("cc1", 5, 3.0),
    ]
    rows = by_name(records)
    assert rows == [("cc1", 1, 3.0), ("rover-bridge", 2, 3.0), ("kworker/*", 2, 0.75)]
    text = table(rows, wall_s=10.0, busy_s=9.0, top=2)
    assert "| `cc1` | 1 | 3.0 | 44.4 % |" in text
    assert "| 1 others | 2 | 0.8 | 11.1 % |" in text
    assert "| **ended processes** | 5 | **6.8** | |" in text
    assert (
        f"| the limit: {os.cpu_count()} cores x 10.0 s | | {10.0 * (os.cpu_count() or 1):.1f} | |"
        in text
    )


_PROBE = (
    "import sys\n"
    "from firmware_proto.runtime.procname import set_process_name\n"
    "set_process_name('cpu-map-probe')\n"
    "sum(range(3_000_000))\n"
    "sys.exit(3)\n"
)


@pytest.mark.skipif(os.geteuid() != 0, reason="process accounting needs root")
def test_a_command_run_under_accounting_is_mapped_and_keeps_its_exit_status() -> None:
    # In a PID namespace of its own: the kernel keeps one accounting file per namespace
    # and writes each ended process to its own namespace's and to every one above, so
    # this test never turns off a map of the whole test run (which it is part of).
    mapped = [sys.executable, "-m", "benchmarks.cpu_map", "--top", "50", "--"]
    done = subprocess.run(
        ["unshare", "--pid", "--fork", "--", *mapped, sys.executable, "-c", _PROBE],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert done.returncode == 3, done.stderr
    [row] = [line for line in done.stdout.splitlines() if line.startswith("| `cpu-map-probe` |")]
    assert row.split("|")[2].strip() == "1"  # one process of that name
    assert float(row.split("|")[3]) > 0.0
    assert "| the machine, busy (/proc/stat) |" in done.stdout


def test_no_command_is_a_usage_error() -> None:
    done = subprocess.run(
        [sys.executable, "-m", "benchmarks.cpu_map", "--"],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert done.returncode == 2 and "no command" in done.stderr
