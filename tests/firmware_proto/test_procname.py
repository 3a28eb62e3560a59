"""Process names (firmware_proto/runtime/procname.py): what ``top`` and ``pgrep`` show."""

from __future__ import annotations

import subprocess
import sys

import pytest

from firmware_proto.runtime.procname import COMM_MAX_BYTES, process_name, set_process_name

_NAMED = (
    "import sys\n"
    "from firmware_proto.runtime.procname import process_name, set_process_name\n"
    "print(set_process_name(sys.argv[1]), process_name())\n"
)


def _named(name: str) -> str:
    done = subprocess.run(
        [sys.executable, "-c", _NAMED, name], capture_output=True, text=True, timeout=60, check=True
    )
    return done.stdout.strip()


def test_a_process_takes_its_name_cut_to_what_the_kernel_keeps() -> None:
    assert _named("rover-bridge") == "True rover-bridge"
    long = "rover-calibrate-drive"
    assert _named(long) == f"True {long[:COMM_MAX_BYTES]}"


@pytest.mark.parametrize("bad", ["", "rover\n", "röver"])
def test_an_unprintable_name_is_refused(bad: str) -> None:
    with pytest.raises(ValueError, match="printable ASCII"):
        set_process_name(bad)


def test_a_gone_process_has_no_name() -> None:
    assert process_name(2**22 + 1) == ""  # above the largest pid_max: never a process
    assert process_name() != ""
