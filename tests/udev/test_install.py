"""``rover udev install``: the plan, dry runs, all-or-nothing writes, reloads.

Decided behaviour without udevadm: the install fails before writing anything and says
to pass --no-reload; with --no-reload it installs and reports the reload skipped. The
reload itself is exercised with a stub udevadm on PATH that records its arguments.
"""

from __future__ import annotations

import os
import shutil
import stat
from pathlib import Path

import pytest

from firmware_proto.cli import main
from udev.install import (
    PLACEHOLDER_SERIAL,
    InstallError,
    execute,
    plan_install,
)
from udev.rules import load_rules

UDEV_DIR = Path(__file__).resolve().parents[2] / "udev"
PINNED_SET = {"70-rover-can.rules", "99-rover-motor.rules"}


@pytest.fixture
def dirs(tmp_path: Path) -> tuple[Path, Path]:
    return tmp_path / "etc" / "udev" / "rules.d", tmp_path / "etc" / "systemd" / "network"


@pytest.fixture
def no_tools(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """PATH with neither udevadm nor networkctl, whatever the machine has."""
    empty = tmp_path / "empty-bin"
    empty.mkdir()
    monkeypatch.setenv("PATH", str(empty))
    return empty


@pytest.fixture
def stub_udevadm(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A udevadm on PATH that appends its arguments to a log; returns the log."""
    bin_dir = tmp_path / "stub-bin"
    bin_dir.mkdir()
    log = tmp_path / "udevadm.log"
    stub = bin_dir / "udevadm"
    stub.write_text(f'#!/bin/sh\necho "$@" >> "{log}"\nexit "${{STUB_STATUS:-0}}"\n')
    stub.chmod(0o755)
    monkeypatch.setenv("PATH", str(bin_dir))
    return log


def files_under(*roots: Path) -> list[Path]:
    return sorted(p for root in roots if root.exists() for p in root.rglob("*"))


def run_cli(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    status = main(args)
    out, err = capsys.readouterr()
    return status, out, err


def test_dry_run_prints_the_plan_and_writes_nothing(
    dirs: tuple[Path, Path], no_tools: Path, capsys: pytest.CaptureFixture[str]
):
    rules_dir, network_dir = dirs
    args = ["udev", "install", "--dry-run", "--rules-dir", str(rules_dir)]
    status, out, err = run_cli([*args, "--network-dir", str(network_dir)], capsys)
    assert "dry run: nothing is changed" in out
    for name in sorted(PINNED_SET):
        assert f"would install {rules_dir / name} from {UDEV_DIR / name} (mode 0644)" in out
    assert f"would install {network_dir / '80-rovercan0.network'}" in out
    assert f"would create directory {rules_dir}" in out
    assert "bench" not in out.replace("--bench", "")
    assert "note: 99-rover-motor.rules still has REPLACE_ME_WITH_SERIAL" in out
    # udevadm is not on PATH: the real install would fail, and the dry run says so.
    assert status == 1
    assert "udevadm not found" in err
    assert files_under(rules_dir.parents[1]) == []


def test_dry_run_with_no_reload_succeeds_and_writes_nothing(
    dirs: tuple[Path, Path], no_tools: Path, capsys: pytest.CaptureFixture[str]
):
    rules_dir, network_dir = dirs
    args = ["udev", "install", "--dry-run", "--no-reload"]
    status, out, _ = run_cli(
        [*args, "--rules-dir", str(rules_dir), "--network-dir", str(network_dir)], capsys
    )
    assert status == 0
    assert "reload skipped (--no-reload)" in out
    assert files_under(rules_dir.parents[1]) == []


def test_install_without_udevadm_fails_clearly_and_leaves_nothing(
    dirs: tuple[Path, Path], no_tools: Path, capsys: pytest.CaptureFixture[str]
):
    rules_dir, network_dir = dirs
    status, _out, err = run_cli(
        ["udev", "install", "--rules-dir", str(rules_dir), "--network-dir", str(network_dir)],
        capsys,
    )
    assert status == 1
    assert "nothing was installed" in err
    assert "udevadm not found" in err
    assert "--no-reload" in err
    assert files_under(rules_dir.parents[1]) == []


def test_install_with_no_reload_installs_and_reports_the_reload_skipped(
    dirs: tuple[Path, Path], no_tools: Path, capsys: pytest.CaptureFixture[str]
):
    rules_dir, network_dir = dirs
    status, out, _ = run_cli(
        [
            "udev", "install", "--no-reload", "--serial", "A10KZ4PB",
            "--rules-dir", str(rules_dir), "--network-dir", str(network_dir),
        ],
        capsys,
    )  # fmt: skip
    assert status == 0
    assert {p.name for p in rules_dir.iterdir()} == PINNED_SET
    assert {p.name for p in network_dir.iterdir()} == {"80-rovercan0.network"}
    installed = rules_dir / "99-rover-motor.rules"
    assert stat.S_IMODE(installed.stat().st_mode) == 0o644
    text = installed.read_text()
    assert PLACEHOLDER_SERIAL not in text
    assert 'ATTRS{serial}=="A10KZ4PB"' in text
    assert load_rules(installed).issues == ()
    assert (network_dir / "80-rovercan0.network").read_bytes() == (
        UDEV_DIR / "80-rovercan0.network"
    ).read_bytes()
    assert f"install {installed} from" in out
    assert "reload skipped (--no-reload)" in out
    assert "networkctl not found" not in out  # only looked for when reloading
    assert "still has REPLACE_ME_WITH_SERIAL" not in out
    assert "still has REPLACE_ME_WITH_USB_PORT" in out  # the CH340 rules: said, not fatal
    assert not [p for p in files_under(rules_dir, network_dir) if p.name.endswith(".tmp")]


def test_install_reloads_udev_and_a_second_run_changes_nothing(
    dirs: tuple[Path, Path], stub_udevadm: Path, capsys: pytest.CaptureFixture[str]
):
    rules_dir, network_dir = dirs
    args = ["udev", "install", "--rules-dir", str(rules_dir), "--network-dir", str(network_dir)]
    status, out, _ = run_cli(args, capsys)
    assert status == 0
    assert "udevadm control --reload-rules" in out
    assert "udevadm trigger --action=change --subsystem-match=tty" in out
    assert "networkctl not found" in out
    assert "replug the USB-CAN adapter" in out
    # The stand-in answers no version, so udev's check of the rules cannot run: said.
    assert "the rules were not checked by udev here" in out
    assert [c for c in stub_udevadm.read_text().splitlines() if c != "--version"] == [
        "control --reload-rules",
        "trigger --action=change --subsystem-match=tty",
    ]
    status, out, _ = run_cli(args, capsys)
    assert status == 0
    assert f"{rules_dir / '99-rover-motor.rules'} is up to date" in out
    assert "run:" not in out
    assert len([c for c in stub_udevadm.read_text().splitlines() if c != "--version"]) == 2


def test_failed_reload_keeps_the_files_and_says_what_to_run(
    dirs: tuple[Path, Path], stub_udevadm: Path, monkeypatch: pytest.MonkeyPatch
):
    rules_dir, network_dir = dirs
    monkeypatch.setenv("STUB_STATUS", "3")
    plan = plan_install(rules_dir=rules_dir, network_dir=network_dir)
    lines: list[str] = []
    with pytest.raises(InstallError, match=r"installed, but '.*udevadm control --reload-rules'"):
        execute(plan, out=lines.append)
    assert {p.name for p in rules_dir.iterdir()} == PINNED_SET


def test_bench_variant_replaces_pinned_and_conflicts_are_refused(
    dirs: tuple[Path, Path], no_tools: Path
):
    rules_dir, network_dir = dirs
    plan = plan_install(rules_dir=rules_dir, network_dir=network_dir, bench=True, reload=False)
    assert {a.target.name for a in plan.files} == {
        "70-rover-can.rules",
        "99-rover-motor-bench.rules",
        "80-rovercan0.network",
    }
    execute(plan, out=lambda _line: None)
    pinned = plan_install(rules_dir=rules_dir, network_dir=network_dir, reload=False)
    (problem,) = pinned.problems
    assert "99-rover-motor-bench.rules is installed" in problem
    assert "would both claim /dev/rover-motor" in problem
    with pytest.raises(InstallError, match="nothing was installed"):
        execute(pinned, out=lambda _line: None)
    assert not (rules_dir / "99-rover-motor.rules").exists()


def test_bad_arguments_are_refused(dirs: tuple[Path, Path], capsys: pytest.CaptureFixture[str]):
    rules_dir, network_dir = dirs
    with pytest.raises(InstallError, match="the bench rules match any unit"):
        plan_install(rules_dir=rules_dir, network_dir=network_dir, bench=True, serial="X1")
    with pytest.raises(InstallError, match="serial number 'A\"B'"):
        plan_install(rules_dir=rules_dir, network_dir=network_dir, serial='A"B')
    with pytest.raises(InstallError, match=r"expected a port path such as 1-1\.2"):
        plan_install(rules_dir=rules_dir, network_dir=network_dir, usb_port="usb1")
    status, _, err = run_cli(["udev", "install", "--dry-run", "--source", "/nonexistent"], capsys)
    assert status == 1
    assert "udev source directory /nonexistent (from --source) does not exist" in err


def test_not_root_is_told_to_use_sudo(
    dirs: tuple[Path, Path], stub_udevadm: Path, monkeypatch: pytest.MonkeyPatch
):
    rules_dir, network_dir = dirs
    real_access = os.access

    def no_write_access(path: str | os.PathLike[str], mode: int, **kw: object) -> bool:
        # As root every directory is writable: pretend to be a user for W_OK only.
        return False if mode == os.W_OK else real_access(path, mode)

    monkeypatch.setattr(os, "access", no_write_access)
    plan = plan_install(rules_dir=rules_dir, network_dir=network_dir, euid=lambda: 1000)
    text = "\n".join(plan.problems)
    assert "not root; run 'sudo rover udev install'" in text
    assert "reloading udev needs root" in text
    with pytest.raises(InstallError, match="nothing was installed"):
        execute(plan, out=lambda _line: None)
    assert files_under(rules_dir.parents[1]) == []


def test_a_failure_half_way_rolls_back_everything(
    dirs: tuple[Path, Path], no_tools: Path, monkeypatch: pytest.MonkeyPatch
):
    rules_dir, network_dir = dirs
    rules_dir.mkdir(parents=True)
    old = rules_dir / "70-rover-can.rules"
    old.write_text("# an older version\n")
    other = rules_dir / "10-someone-else.rules"
    other.write_text("# not ours\n")
    plan = plan_install(rules_dir=rules_dir, network_dir=network_dir, reload=False)
    real_replace = os.replace
    calls = 0

    def failing_replace(src: str | os.PathLike[str], dst: str | os.PathLike[str]) -> None:
        nonlocal calls
        calls += 1
        if calls == 3:
            raise OSError(28, "No space left on device")
        real_replace(src, dst)

    monkeypatch.setattr(os, "replace", failing_replace)
    with pytest.raises(InstallError, match=r"rolled back, nothing changed: .*No space left"):
        execute(plan, out=lambda _line: None)
    assert old.read_text() == "# an older version\n"
    assert {p.name for p in rules_dir.iterdir()} == {old.name, other.name}
    assert not network_dir.exists()


def test_rules_udev_rejects_are_not_installed(
    udev_check: str, dirs: tuple[Path, Path], tmp_path: Path
):
    source = tmp_path / "udev"
    shutil.copytree(UDEV_DIR, source, ignore=shutil.ignore_patterns("*.py", "__pycache__"))
    broken = source / "70-rover-can.rules"
    broken.write_text(broken.read_text() + 'SUBSYSTEM="net", NAME="rovercan9"\n')
    last = len(broken.read_text().splitlines())
    rules_dir, network_dir = dirs
    plan = plan_install(source=source, rules_dir=rules_dir, network_dir=network_dir, reload=False)
    assert plan.problems == (f"{broken}:{last}: Invalid operator for SUBSYSTEM.",)
    with pytest.raises(InstallError, match="nothing was installed"):
        execute(plan, out=lambda _line: None)
    assert files_under(rules_dir.parents[1]) == []
