"""The test process's garbage collector (tests/heap.py, docs/testing.md "Garbage
collection"): a full collection before each test that keeps wall time, none before the
others."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: A conftest that counts full collections during each test's setup; automatic
#: collections are off, so every one counted is an explicit ``gc.collect()``.
CONFTEST = """
import gc
import pytest

pytest_plugins = ["tests.heap"]
FULL = [0]
SEEN = {}


def _count(phase, info):
    if phase == "start" and info["generation"] == 2:
        FULL[0] += 1


gc.disable()
gc.callbacks.append(_count)


@pytest.hookimpl(hookwrapper=True, tryfirst=True)
def pytest_runtest_setup(item):
    before = FULL[0]
    yield
    SEEN[item.name] = FULL[0] - before


def pytest_sessionfinish(session):
    print("collections in setup:", sorted(SEEN.items()))
"""


@pytest.mark.slow
@pytest.mark.virtual
def test_a_full_collection_comes_before_each_wall_time_test_only(tmp_path: Path) -> None:
    """Of a plain test, a ``slow`` one and a ``slow`` and ``virtual`` one, only the
    ``slow`` one (real time) has the garbage collected before it."""
    (tmp_path / "conftest.py").write_text(CONFTEST)
    (tmp_path / "test_kinds.py").write_text(
        textwrap.dedent(
            """
            import pytest

            def test_plain():
                pass

            @pytest.mark.slow
            def test_real_time():
                pass

            @pytest.mark.slow
            @pytest.mark.virtual
            def test_virtual():
                pass
            """
        )
    )
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    env.pop("PYTEST_XDIST_WORKER", None)
    done = subprocess.run(
        [sys.executable, "-m", "pytest", "-W", "ignore::pytest.PytestUnknownMarkWarning",
         "-p", "no:cacheprovider", "-q", "-s", "test_kinds.py"],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=100, check=False,
    )  # fmt: skip
    out = done.stdout + done.stderr
    assert done.returncode == 0, out
    assert (
        "collections in setup: [('test_plain', 0), ('test_real_time', 1), ('test_virtual', 0)]"
        in out
    ), out
