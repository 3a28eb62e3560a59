"""The lanes of tests/lanes.py name tests that exist: a renamed test must not leave the
test command by accident, nor stay in it by accident."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

from tests.lanes import EXTENDED, SLOW_MODULES, VIRTUAL_MODULES

ROOT = Path(__file__).resolve().parents[1]


def test_every_slow_module_exists() -> None:
    assert [m for m in SLOW_MODULES if not (ROOT / m).is_file()] == []


def test_every_virtual_module_is_a_slow_one() -> None:
    assert [m for m in VIRTUAL_MODULES if m not in SLOW_MODULES] == []


def _collect(expression: str) -> set[str]:
    done = subprocess.run(
        [sys.executable, "-m", "pytest", "--collect-only", "-q", "-p", "no:cacheprovider",
         "-m", expression],
        capture_output=True, text=True, cwd=ROOT, timeout=110, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    return {line for line in done.stdout.splitlines() if "::" in line}


def test_the_parts_of_the_test_command_run_every_test_once() -> None:
    """.ci/test's parts (background, host, serial, vm; SocketCAN in the VM) select each
    test of the command exactly once, whatever its marks."""
    script = (ROOT / ".ci" / "test").read_text()
    expressions = [
        e.replace("${not_can}", " and not socketcan") for e in re.findall(r'-m "([^"]+)"', script)
    ]
    parts = list(dict.fromkeys(e for e in expressions if "not extended" in e))
    assert len(parts) == 4, expressions  # background, host, serial, and the VM's
    selected = [_collect(e) for e in parts]
    every = _collect("not extended")
    assert sum(len(s) for s in selected) == len(every) > 1000
    assert set().union(*selected) == every


def test_every_extended_entry_names_collected_tests_and_says_where_they_are_covered() -> None:
    done = subprocess.run(
        [sys.executable, "-m", "pytest", "--collect-only", "-q", "-p", "no:cacheprovider"],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=110,
        check=False,
    )
    ids = [line for line in done.stdout.splitlines() if "::" in line]
    assert len(ids) > 1000, done.stdout[-2000:] + done.stderr[-2000:]
    unmatched = [p for p in EXTENDED if not any(i.startswith(p) for i in ids)]
    assert unmatched == []
    assert all(reason.strip() for reason in EXTENDED.values())
