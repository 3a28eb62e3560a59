"""``.ci/venv-python``: the interpreter ``.ci/bootstrap`` makes ``.venv`` from
(docs/testing.md, "The interpreter"): ``$ROVER_PYTHON``, else the system's Python 3.11,
else ``python3`` on PATH."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[1] / ".ci" / "venv-python"


def _choose(*args: str, rover_python: str | None = None) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if k != "ROVER_PYTHON"}
    if rover_python is not None:
        env["ROVER_PYTHON"] = rover_python
    return subprocess.run(
        ["bash", str(SCRIPT), *args],
        capture_output=True,
        text=True,
        timeout=30,
        check=False,
        env=env,
    )


@pytest.mark.skipif(sys.version_info[:2] != (3, 11), reason="the wheels' version is 3.11")
def test_a_system_python_311_is_chosen_over_python3_on_path() -> None:
    out = _choose(sys.executable)
    assert (out.returncode, out.stdout, out.stderr) == (0, f"{sys.executable}\n", "")


def test_without_a_system_python_311_python3_on_path_is_chosen(tmp_path: Path) -> None:
    assert _choose(str(tmp_path / "none")).stdout == "python3\n"
    # An interpreter of another version is passed over too.
    other = tmp_path / "python3"
    other.write_text("#!/bin/sh\nexit 1\n")  # as a 3.12 answers the version check
    other.chmod(0o755)
    assert _choose(str(other)).stdout == "python3\n"


def test_rover_python_wins_and_a_missing_one_is_an_error(tmp_path: Path) -> None:
    out = _choose(sys.executable, rover_python="python3")
    assert (out.returncode, out.stdout) == (0, "python3\n")
    out = _choose(sys.executable, rover_python=str(tmp_path / "nope"))
    assert out.returncode == 2 and out.stdout == ""
    assert out.stderr == f"venv-python: ROVER_PYTHON={tmp_path / 'nope'}: no such interpreter\n"
