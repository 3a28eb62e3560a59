"""The lanes of tests/lanes.py name tests that exist: a renamed test must not leave the
test command by accident, nor stay in it by accident."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from _pytest.mark.expression import Expression

from tests.lanes import (
    EXTENDED,
    HEAVY,
    IDLE,
    SLOW_MODULES,
    SOAK_LONGEST_FIRST,
    VIRTUAL_MODULES,
    VIRTUAL_TESTS,
    soak_rank,
)

ROOT = Path(__file__).resolve().parents[1]


def test_every_slow_module_exists() -> None:
    assert [m for m in SLOW_MODULES if not (ROOT / m).is_file()] == []


def test_every_virtual_module_is_a_slow_one() -> None:
    assert [m for m in VIRTUAL_MODULES if m not in SLOW_MODULES] == []


@pytest.fixture(scope="module")
def marks(tmp_path_factory: pytest.TempPathFactory) -> dict[str, frozenset[str]]:
    """Every collected test's node id and the names of its marks, lanes included: one
    collection of the whole tree (tests/_dump_marks.py), as pytest itself sees it."""
    out = tmp_path_factory.mktemp("marks") / "marks.tsv"
    done = subprocess.run(
        [sys.executable, "-m", "pytest", "--collect-only", "-q", "-p", "no:cacheprovider",
         "-p", "tests._dump_marks"],
        capture_output=True, text=True, cwd=ROOT, timeout=110, check=False,
        env={**os.environ, "ROVER_DUMP_MARKS": str(out)},
    )  # fmt: skip
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    dumped = {}
    for line in out.read_text().splitlines():
        nodeid, _, names = line.partition("\t")
        dumped[nodeid] = frozenset(filter(None, names.split(",")))
    assert len(dumped) > 1000
    return dumped


def _select(marks: dict[str, frozenset[str]], expression: str) -> set[str]:
    """The tests ``pytest -m EXPRESSION`` selects, by pytest's own expression matcher."""
    compiled = Expression.compile(expression)

    def selected(names: frozenset[str]) -> bool:
        def has(name: str, /, **kwargs: str | int | bool | None) -> bool:
            return not kwargs and name in names

        return compiled.evaluate(has)

    return {nodeid for nodeid, names in marks.items() if selected(names)}


def test_the_parts_of_the_test_command_run_every_test_once(
    marks: dict[str, frozenset[str]],
) -> None:
    """.ci/test's parts (background, soak, host, serial and the serial tests beside it,
    vm; SocketCAN in the VM) select each test of the command exactly once, whatever its
    marks."""
    script = (ROOT / ".ci" / "test").read_text()
    expressions = [
        e.replace("${not_can}", " and not socketcan") for e in re.findall(r'-m "([^"]+)"', script)
    ]
    parts = list(dict.fromkeys(e for e in expressions if "not extended" in e))
    assert len(parts) == 6, expressions  # background, soak, host, serial, beside, VM
    selected = [_select(marks, e) for e in parts]
    every = _select(marks, "not extended")
    assert sum(len(s) for s in selected) == len(every) > 1000
    assert set().union(*selected) == every


def test_the_matcher_selects_as_pytest_does(marks: dict[str, frozenset[str]]) -> None:
    """The expression matcher above agrees with a real ``pytest -m`` collection."""
    expression = "serial and not extended"
    done = subprocess.run(
        [sys.executable, "-m", "pytest", "--collect-only", "-q", "-p", "no:cacheprovider",
         "-m", expression, "tests/planner", "tests/bridge/test_link.py"],
        capture_output=True, text=True, cwd=ROOT, timeout=110, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    # Node ids only: the stall report after them (tests/stalls.py) names tests too, those
    # of the run's other processes that stalled meanwhile.
    collected = {line for line in done.stdout.splitlines() if line.startswith("tests/")}
    mine = {
        n for n in _select(marks, expression)
        if n.startswith(("tests/planner/", "tests/bridge/test_link.py::"))
    }  # fmt: skip
    assert collected == mine and len(mine) >= 3


def test_every_extended_entry_names_collected_tests_and_says_where_they_are_covered(
    marks: dict[str, frozenset[str]],
) -> None:
    unmatched = [p for p in EXTENDED if not any(i.startswith(p) for i in marks)]
    assert unmatched == []
    assert all(reason.strip() for reason in EXTENDED.values())


def test_every_heavy_entry_names_collected_tests_none_of_them_real_time(
    marks: dict[str, frozenset[str]],
) -> None:
    """Each :data:`tests.lanes.HEAVY` prefix names tests, all out of the fast lane and in
    the no-wall-clock part, none of them in a real-time module."""
    for prefix, kept in HEAVY.items():
        named = [n for n in marks if n.startswith(prefix)]
        assert named and kept.strip(), prefix
        assert all({"slow", "virtual"} <= marks[n] for n in named), prefix
        assert prefix.split("::", 1)[0] not in SLOW_MODULES, prefix


def test_every_virtual_test_entry_names_collected_tests_of_a_slow_module(
    marks: dict[str, frozenset[str]],
) -> None:
    """Each :data:`tests.lanes.VIRTUAL_TESTS` prefix names tests of a real-time module that
    the no-wall-clock part runs instead of the real-time one."""
    for prefix in VIRTUAL_TESTS:
        named = [n for n in marks if n.startswith(prefix)]
        assert named, prefix
        assert prefix.split("::", 1)[0] in SLOW_MODULES, prefix
        assert all({"slow", "virtual"} <= marks[n] for n in named), prefix


def test_every_idle_entry_names_collected_tests_that_keep_no_clock(
    marks: dict[str, frozenset[str]],
) -> None:
    """Each :data:`tests.lanes.IDLE` prefix names tests, all marked ``soak`` (the test
    command's part under ``SCHED_IDLE``), none of a real-time module, none serial."""
    for prefix in IDLE:
        named = [n for n in marks if n.startswith(prefix)]
        assert len(named) > 1, prefix
        assert all("soak" in marks[n] and "serial" not in marks[n] for n in named), prefix
        assert prefix.split("::", 1)[0] not in SLOW_MODULES, prefix


def test_every_soak_order_entry_names_soak_tests_of_its_own(
    marks: dict[str, frozenset[str]],
) -> None:
    """Each :data:`tests.lanes.SOAK_LONGEST_FIRST` prefix names tests of the soak part,
    none of them named by an earlier prefix; the soak part's other tests rank after."""
    soak = [n for n, names in marks.items() if "soak" in names]
    for rank, prefix in enumerate(SOAK_LONGEST_FIRST):
        named = [n for n in soak if n.startswith(prefix)]
        assert named and all(soak_rank(n) == rank for n in named), prefix
    rest = [n for n in soak if not n.startswith(SOAK_LONGEST_FIRST)]
    assert rest and {soak_rank(n) for n in rest} == {len(SOAK_LONGEST_FIRST)}


def test_the_soak_part_collects_its_longest_tests_first(
    marks: dict[str, frozenset[str]],
) -> None:
    """With ``ROVER_TEST_PART=soak`` (the test command's soak part) the collection comes
    in :func:`tests.lanes.soak_rank` order, each rank in collection order; elsewhere (the
    whole tree's collection, above) in collection order."""
    plain = [n for n, names in marks.items() if "soak" in names]  # in collection order
    modules = sorted({n.split("::", 1)[0] for n in plain})  # as .ci/test names them
    done = subprocess.run(
        [sys.executable, "-m", "pytest", "--collect-only", "-q", "-p", "no:cacheprovider",
         "-m", "soak", *modules],
        capture_output=True, text=True, cwd=ROOT, timeout=110, check=False,
        env={**os.environ, "ROVER_TEST_PART": "soak"},
    )  # fmt: skip
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    soak = [line for line in done.stdout.splitlines() if line.startswith("tests/")]
    assert soak == sorted(plain, key=soak_rank) and len(soak) > 50
    assert soak[0].startswith(SOAK_LONGEST_FIRST[0]) and soak_rank(soak[-1]) > 0
    assert plain[0].startswith("tests/bridge/test_mutants.py::")
