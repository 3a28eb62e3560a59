"""The bridge's systemd unit (``bridge/ros/systemd/rover-bridge.service``), checked by
systemd's own ``systemd-analyze verify`` and against what the rest of the package says:
it restarts on failure, binds to the device unit the udev rules make, asks for the
real-time limits of docs/realtime.md, and the udev rules name it."""

from __future__ import annotations

import configparser
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from firmware_proto.runtime.realtime import BRIDGE_PRIORITY

ROOT = Path(__file__).resolve().parents[2]
UNIT = ROOT / "bridge" / "ros" / "systemd" / "rover-bridge.service"
SHIPPED_ROVER = "/opt/rover/.venv/bin/rover"
"""Where the unit expects ``rover`` (docs/realtime.md's example); adapted on install."""


def _unit() -> configparser.ConfigParser:
    parser = configparser.ConfigParser(interpolation=None, strict=False)
    parser.optionxform = str  # type: ignore[assignment,method-assign]
    parser.read_string(UNIT.read_text())
    return parser


def test_the_unit_restarts_the_bridge_binds_its_device_and_keeps_time() -> None:
    unit = _unit()
    service, section = unit["Service"], unit["Unit"]
    assert service["Restart"] == "on-failure"
    assert service["RestartPreventExitStatus"] == "2"  # a usage error is not retried
    assert service["ExecStart"] == f"{SHIPPED_ROVER} bridge --device /dev/rover-motor"
    # /dev/rover-motor's device unit (systemd-escape --path: '-' -> \x2d).
    assert section["BindsTo"] == section["After"] == r"dev-rover\x2dmotor.device"
    # docs/realtime.md, "Granting it": SCHED_RR at the bridge's priority, room above it.
    assert service["CPUSchedulingPolicy"] == "rr"
    assert int(service["CPUSchedulingPriority"]) == BRIDGE_PRIORITY
    assert int(service["LimitRTPRIO"]) > BRIDGE_PRIORITY
    assert service["LimitMEMLOCK"] == "infinity"
    assert service["KillSignal"] == "SIGTERM"
    docs = (ROOT / "docs" / "realtime.md").read_text()
    assert "bridge/ros/systemd/rover-bridge.service" in docs


def test_the_udev_rules_start_it_with_the_controller() -> None:
    for rules in ("99-rover-motor.rules", "99-rover-motor-bench.rules"):
        text = (ROOT / "udev" / rules).read_text()
        line = next(x for x in text.splitlines() if "SYSTEMD_WANTS" in x and "==" in x)
        assert 'SYMLINK=="rover-motor"' in line and 'TAG+="systemd"' in line
        assert f'ENV{{SYSTEMD_WANTS}}+="{UNIT.name}"' in line


def test_systemd_analyze_verify_accepts_the_unit(tmp_path: Path) -> None:
    """systemd's own check, with ``ExecStart`` pointed at this checkout's ``rover`` (verify
    also checks that the program exists). It exits 0 on warnings too, so it must also say
    nothing."""
    verify = shutil.which("systemd-analyze")
    if verify is None:
        pytest.skip("systemd-analyze is not installed (systemd)")
    rover = str(Path(sys.executable).parent / "rover")  # this environment's console script
    assert Path(rover).is_file(), rover
    installed = tmp_path / UNIT.name
    installed.write_text(UNIT.read_text().replace(SHIPPED_ROVER, rover))
    done = subprocess.run(
        [verify, "verify", str(installed)], capture_output=True, text=True, timeout=60, check=False
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "" and done.stderr.strip() == "", done.stderr
    # And it does find fault: a wrong setting is named (the check is not a blank pass).
    broken = tmp_path / "rover-bridge-broken.service"
    broken.write_text(installed.read_text().replace("Restart=on-failure", "Restart=sometimes"))
    bad = subprocess.run(
        [verify, "verify", str(broken)], capture_output=True, text=True, timeout=60, check=False
    )
    assert "Failed to parse service restart specifier" in bad.stderr


ONBOARD_UNIT = ROOT / "bridge" / "ros" / "systemd" / "rover-onboard.service"


def test_the_onboard_unit_runs_beside_the_bridge_with_its_token_from_a_file() -> None:
    """Review D2: nothing started rover onboard on a rover, and rover go runs its plans
    on board by default: a real rover never answered the uplink."""
    parser = configparser.ConfigParser(interpolation=None, strict=False)
    parser.optionxform = str  # type: ignore[assignment,method-assign]
    parser.read_string(ONBOARD_UNIT.read_text())
    service, section = parser["Service"], parser["Unit"]
    assert section["BindsTo"] == section["After"] == UNIT.name  # with the bridge
    assert parser["Install"]["WantedBy"] == UNIT.name
    assert service["ExecStart"] == f"{SHIPPED_ROVER} onboard"  # no token on argv
    assert service["EnvironmentFile"] == "/etc/rover/uplink.env"
    assert service["Restart"] == "on-failure" and service["RestartPreventExitStatus"] == "2"
    # it promotes itself after a start at normal priority (docs/realtime.md)
    assert "CPUSchedulingPolicy" not in service
    assert int(service["LimitRTPRIO"]) > BRIDGE_PRIORITY
    assert service["KillSignal"] == "SIGTERM"
    assert "bridge/ros/systemd/rover-onboard.service" in (ROOT / "docs" / "ros2.md").read_text()


def test_systemd_analyze_verify_accepts_the_onboard_unit(tmp_path: Path) -> None:
    verify = shutil.which("systemd-analyze")
    if verify is None:
        pytest.skip("systemd-analyze is not installed (systemd)")
    rover = str(Path(sys.executable).parent / "rover")
    for unit in (UNIT, ONBOARD_UNIT):  # the bridge's beside it: BindsTo= names it
        (tmp_path / unit.name).write_text(unit.read_text().replace(SHIPPED_ROVER, rover))
    done = subprocess.run(
        [verify, "verify", str(tmp_path / ONBOARD_UNIT.name)],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
        cwd=tmp_path,
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "" and done.stderr.strip() == "", done.stderr
