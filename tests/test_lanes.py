"""The lanes of tests/lanes.py name tests that exist: a renamed test must not leave the
test command by accident, nor stay in it by accident."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from tests.lanes import EXTENDED, SLOW_MODULES

ROOT = Path(__file__).resolve().parents[1]


def test_every_slow_module_exists() -> None:
    assert [m for m in SLOW_MODULES if not (ROOT / m).is_file()] == []


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
