"""Shared by the PIL tests: which targets can run here, and ``rover pil`` as a process."""

from __future__ import annotations

import contextlib
import os
import shutil
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

REQUIRE_CROSS_ENV = "ROVER_REQUIRE_CROSS"

NEEDS: dict[str, tuple[tuple[str, str], ...]] = {
    "microbit": (
        ("arm-none-eabi-gcc", "gcc-arm-none-eabi libnewlib-arm-none-eabi"),
        ("qemu-system-arm", "qemu-system-arm"),
    ),
    "atmega2560": (
        ("avr-gcc", "gcc-avr avr-libc binutils-avr"),
        ("gcc", "gcc libc6-dev"),
    ),
}
"""The tools each target needs, with the Debian packages that bring them."""
_HEADERS = {"atmega2560": (("/usr/include/simavr/sim_avr.h", "libsimavr-dev libelf-dev"),)}


def require_target(target: str) -> None:
    """Skip (or fail, under ``ROVER_REQUIRE_CROSS=1``) where ``target``'s tools are missing,
    naming the packages."""
    missing = [pkgs for tool, pkgs in NEEDS[target] if shutil.which(tool) is None]
    missing += [pkgs for path, pkgs in _HEADERS.get(target, ()) if not Path(path).exists()]
    if missing:
        reason = (
            f"the {target} PIL target needs apt-get install {' '.join(missing)} "
            "(or bash .ci/bootstrap --test)"
        )
        if os.environ.get(REQUIRE_CROSS_ENV) == "1":
            pytest.fail(f"{REQUIRE_CROSS_ENV}=1 but {reason}")
        pytest.skip(reason)


def rover(*args: str, timeout: float = 180.0) -> subprocess.CompletedProcess[str]:
    """``rover ARGS`` as a process; its output captured."""
    return subprocess.run(
        [sys.executable, "-m", "firmware_proto.cli", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        check=False,
    )


@contextlib.contextmanager
def pil_process(tmp_path: Path, target: str, *extra: str) -> Iterator[tuple[str, str]]:
    """``rover pil --target T --link ... --control-port 0`` as its own process:
    ``(device link, control address)``; ended (and checked to end) on exit."""
    require_target(target)
    link = tmp_path / f"pil-{target}"
    err_path = tmp_path / f"pil-{target}.err"
    with err_path.open("w") as err:
        proc = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "firmware_proto.cli",
                "pil",
                "--target",
                target,
                "--link",
                str(link),
                "--control-port",
                "0",
                *extra,
            ],
            stdout=subprocess.PIPE,
            stderr=err,
            text=True,
        )
    try:
        assert proc.stdout is not None
        device = proc.stdout.readline().split()
        control = proc.stdout.readline().split()
        assert device[:1] == ["DEVICE"] and control[:1] == ["CONTROL"], (
            device,
            control,
            err_path.read_text(),
        )
        yield str(link), control[1]
    finally:
        proc.terminate()
        try:
            proc.communicate(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.communicate(timeout=5)
    assert proc.returncode == 0, err_path.read_text()
    assert not link.exists(), "rover pil left its link behind"
