"""The CAN bring-up scripts in udev/: help, usage errors, and the specific failures.

This machine's kernel has no vcan and no AF_CAN: vcan-up.sh must fail here with its
"no vcan module" message. Where the kernel has SocketCAN, the same test brings a vcan
interface up instead (inside the private network namespace of .ci/test) and removes it.
Every run has a timeout, so a script that hangs fails the test instead of the suite.
"""

from __future__ import annotations

import os
import platform
import shutil
import subprocess
from pathlib import Path

import pytest

from udev.devices import socketcan_support

UDEV_DIR = Path(__file__).resolve().parents[2] / "udev"
VCAN_UP = UDEV_DIR / "vcan-up.sh"
CAN_UP = UDEV_DIR / "can-up.sh"
SCRIPTS = [VCAN_UP, CAN_UP]
TIMEOUT_S = 60
IS_ROOT = os.geteuid() == 0
SOCKETCAN = socketcan_support()


def run(*args: str | Path, as_user: str | None = None) -> subprocess.CompletedProcess[str]:
    cmd = [str(a) for a in args]
    if as_user is not None:
        cmd = ["setpriv", f"--reuid={as_user}", f"--regid={as_user}", "--clear-groups", *cmd]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=TIMEOUT_S, check=False)


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda p: p.name)
def test_help_explains_usage_and_exit_status(script: Path):
    assert os.access(script, os.X_OK), f"{script.name} is not executable"
    result = run(script, "--help")
    assert result.returncode == 0
    assert result.stdout.startswith(f"Usage: {script.name}")
    assert "Exit status:" in result.stdout
    assert "Examples:" in result.stdout
    assert result.stderr == ""


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda p: p.name)
def test_unknown_option_is_a_usage_error(script: Path):
    result = run(script, "--frobnicate")
    assert result.returncode == 2
    assert "unknown" in result.stderr
    assert f"try '{script.name} --help'" in result.stderr


def test_can_up_rejects_a_bitrate_classic_can_cannot_do():
    result = run(CAN_UP, "can0", "--bitrate", "2M")
    assert result.returncode == 2
    assert "not a classic CAN bitrate" in result.stderr


@pytest.mark.skipif(not IS_ROOT, reason="the kernel checks run as root; run the suite as root")
@pytest.mark.skipif(SOCKETCAN.available, reason=f"this kernel has SocketCAN ({SOCKETCAN.detail})")
def test_vcan_up_fails_here_saying_there_is_no_vcan_module_and_how_to_fix_it():
    result = run(VCAN_UP, "--name", "rovtest0")
    assert result.returncode == 4, result.stderr
    assert result.stdout == ""
    err = result.stderr
    assert "vcan-up.sh: error: no vcan module: the running kernel" in err
    assert "cannot create vcan interfaces" in err
    assert f"linux-modules-extra-{platform.release()}" in err
    if not Path("/proc/modules").exists():
        assert "built without loadable module support" in err
        assert "no package fixes it on this" in err
    if not Path("/proc/net/can").exists():
        assert "no SocketCAN (AF_CAN)" in err
    assert not Path("/sys/class/net/rovtest0").exists()


@pytest.mark.socketcan
@pytest.mark.skipif(not IS_ROOT, reason="creating a vcan interface needs root")
@pytest.mark.skipif(not SOCKETCAN.available, reason=f"no SocketCAN here: {SOCKETCAN.detail}")
def test_vcan_up_brings_an_interface_up_and_is_idempotent():
    try:
        first = run(VCAN_UP, "--name", "rovtest0")
        assert first.returncode == 0, first.stderr
        again = run(VCAN_UP, "--name", "rovtest0")
        assert again.returncode == 0, again.stderr
        assert "already exists" in again.stdout
        assert Path("/sys/class/net/rovtest0/type").read_text().strip() == "280"
    finally:
        run("ip", "link", "del", "dev", "rovtest0")


@pytest.mark.skipif(not IS_ROOT, reason="the interface checks run as root")
def test_can_up_on_a_missing_interface_says_so_and_lists_what_there_is():
    if Path("/sys/class/net/rovertest9").exists():
        pytest.skip("an interface named rovertest9 exists here")
    result = run(CAN_UP, "rovertest9")
    assert result.returncode == 5
    assert "can-up.sh: error: interface rovertest9 does not exist" in result.stderr
    assert "CAN interfaces" in result.stderr
    assert "lsusb" in result.stderr


@pytest.mark.skipif(not IS_ROOT, reason="the interface checks run as root")
def test_can_up_refuses_an_interface_that_is_not_can():
    result = run(CAN_UP, "lo")
    assert result.returncode == 6
    assert "lo is not a CAN interface (ARPHRD type 772, CAN is 280)" in result.stderr


@pytest.mark.skipif(
    not IS_ROOT or shutil.which("setpriv") is None,
    reason="needs root and setpriv to run the scripts as an unprivileged user",
)
@pytest.mark.parametrize("script", SCRIPTS, ids=lambda p: p.name)
def test_not_root_is_refused_before_touching_anything(script: Path):
    result = run(script, as_user="65534")
    assert result.returncode == 3
    assert "must be run as root" in result.stderr
    assert "fix: sudo" in result.stderr


@pytest.mark.skipif(shutil.which("shellcheck") is None, reason="shellcheck is not installed")
def test_scripts_are_shellcheck_clean():
    result = run("shellcheck", *SCRIPTS)
    assert result.returncode == 0, result.stdout
