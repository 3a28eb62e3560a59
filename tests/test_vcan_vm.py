""".ci/vcan-vm's pure parts (docs/vcan-vm.md): which host paths the guest keeps on top
of its tmpfs, and the guest script. The VM itself runs every ``socketcan`` test in
``.ci/test``; here it is only asked whether it can run (``--check``)."""

from __future__ import annotations

import importlib.machinery
import importlib.util
import subprocess
import sys
import tempfile
from pathlib import Path
from types import ModuleType

import pytest

SCRIPT = Path(__file__).resolve().parents[1] / ".ci" / "vcan-vm"


@pytest.fixture(scope="module")
def vm() -> ModuleType:
    loader = importlib.machinery.SourceFileLoader("vcan_vm", str(SCRIPT))
    spec = importlib.util.spec_from_loader("vcan_vm", loader)
    assert spec is not None
    module = importlib.util.module_from_spec(spec)
    loader.exec_module(module)
    return module


def test_a_checkout_under_tmp_is_kept_once_and_others_are_not(vm: ModuleType) -> None:
    with tempfile.TemporaryDirectory(dir="/tmp") as tmp:
        checkout = Path(tmp) / "checkout"
        (checkout / "tests").mkdir(parents=True)
        kept = vm.kept_paths([checkout / "tests", checkout, Path("/usr/lib"), Path(tmp) / "absent"])
        assert kept == [checkout.resolve()]


def test_nothing_is_kept_outside_the_tmpfs_directories(vm: ModuleType) -> None:
    assert vm.kept_paths([Path("/usr"), Path("/etc"), Path("/")]) == []


def test_the_guest_script_brings_up_both_interfaces_and_runs_the_command_in_its_directory(
    vm: ModuleType,
) -> None:
    script = vm.guest_script(
        ["pytest", "-m", "socketcan", "a b"], Path("/src/x y"), {"A": "1 2"}, "@T@", "tcg"
    )
    assert "vcan-up.sh' --name vcan0" in script or "vcan-up.sh --name vcan0" in script
    assert "--name rovercan0" in script and "can-up.sh" in script
    assert "cd '/src/x y'" in script
    assert "pytest -m socketcan 'a b' </dev/null" in script
    assert "export A='1 2'" in script
    assert "ROVER_REQUIRE_SOCKETCAN=1" in script and "ROVER_VCAN_VM_ACCEL=tcg" in script
    assert 'echo "@T@ $1"' in script


def test_check_answers_0_or_125_with_the_reason() -> None:
    done = subprocess.run(
        [sys.executable, str(SCRIPT), "--check"],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert done.returncode in (0, 125), done
    if done.returncode == 125:
        assert "vcan-vm:" in done.stdout + done.stderr


def test_a_live_directory_is_shared_uncached_at_its_own_path(vm: ModuleType) -> None:
    """``--live DIR``: qemu shares DIR as a second 9p tag, and the guest mounts it at DIR
    with no cache before the command runs (so that a file the host makes there is seen)."""
    live = Path("/tmp/go dir")
    script = vm.guest_script(["true"], Path("/src"), {}, "@T@", "tcg", live)
    mount = script.index(f"cache=none {vm.LIVE_TAG} '/tmp/go dir'")
    assert "mkdir -p '/tmp/go dir'" in script and mount < script.index("true </dev/null")
    argv = vm.qemu_command(Path("/k"), Path("/i"), "tcg", 512, 1, live)
    assert f"local,path={live},mount_tag={vm.LIVE_TAG},security_model=none,readonly=on" in argv
    assert vm.LIVE_TAG not in vm.guest_script(["true"], Path("/src"), {}, "@T@", "tcg")
    assert not any(vm.LIVE_TAG in a for a in vm.qemu_command(Path("/k"), Path("/i"), "tcg", 512, 1))


def test_the_guest_kernel_skips_the_timer_check_that_a_starved_boot_fails(vm: ModuleType) -> None:
    """Booted at nice 19 beside four busy processes, a guest panicked in the kernel's
    IO-APIC timer check (2026-11-29): the command line turns the check off."""
    argv = vm.qemu_command(Path("/k"), Path("/i"), "tcg", 512, 1)
    assert "no_timer_check" in argv[argv.index("-append") + 1].split()
