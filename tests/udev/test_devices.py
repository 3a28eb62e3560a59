"""``rover devices`` on this machine, and device discovery against synthetic sources
(pyserial ports, a fake sysfs tree, a fake ``ip -details``)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from serial.tools.list_ports_common import ListPortInfo

from firmware_proto.cli import main
from udev.devices import (
    inventory,
    list_can_interfaces,
    list_serial_ports,
    motor_link_status,
)

UDEV_DIR = Path(__file__).resolve().parents[2] / "udev"


def test_rover_devices_runs_here_and_says_plainly_what_it_found(
    capsys: pytest.CaptureFixture[str],
):
    assert main(["devices"]) == 0
    out = capsys.readouterr().out
    ports, _hidden = list_serial_ports()
    cans = list_can_interfaces()
    assert "Serial ports (pyserial list_ports)" in out
    if not any(p.is_usb for p in ports):
        assert "no USB serial adapters found" in out
    for p in ports:
        assert p.device in out
    if not cans:
        assert "no CAN interfaces found" in out
    assert "SocketCAN: " in out
    assert "/dev/rover-motor" in out
    assert "99-rover-motor.rules" in out
    assert out.rstrip().splitlines()[-1].startswith("Summary: ")


def test_rover_devices_json_is_valid_and_complete(capsys: pytest.CaptureFixture[str]):
    assert main(["devices", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert set(data) >= {
        "summary",
        "serial_ports",
        "hidden_serial_ports",
        "can_interfaces",
        "socketcan",
        "motor_link",
        "udev_files",
        "conflicts",
    }
    assert isinstance(data["socketcan"]["available"], bool)
    assert data["motor_link"]["path"] == "/dev/rover-motor"
    assert {f["name"] for f in data["udev_files"]} >= {"99-rover-motor.rules"}


def test_the_rover_entry_point_has_devices_and_udev(udev_check: str):
    rover = Path(sys.executable).with_name("rover")
    result = subprocess.run(
        [str(rover), "devices"], capture_output=True, text=True, timeout=60, check=False
    )
    assert result.returncode == 0, result.stderr
    assert "Summary: " in result.stdout
    check = subprocess.run(
        [str(rover), "udev", "check"], capture_output=True, text=True, timeout=60, check=False
    )
    assert check.returncode == 0, check.stdout
    assert check.stdout.strip().endswith(f"with {udev_check}: OK")


def test_udev_check_reports_broken_files(
    udev_check: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
):
    bad = tmp_path / "50-bad.rules"
    bad.write_text('# fine\nSUBSYSTEM="tty", SYMLINK+="x"\nKERNEL=="x", SYMLNK+="y"\n')
    assert main(["udev", "check", str(bad)]) == 1
    out = capsys.readouterr().out.splitlines()
    assert f"{bad}:2: Invalid operator for SUBSYSTEM." in out
    assert f"{bad}:3: Invalid key 'SYMLNK'" in out
    assert out[-1] == f"checked 1 file(s) with {udev_check}: 2 problem(s)"


def test_nothing_plugged_in_is_said_plainly(tmp_path: Path):
    found = inventory(
        source=UDEV_DIR,
        comports=list,
        by_id_dir=tmp_path,
        sys_class_net=tmp_path,
        motor_link=tmp_path / "rover-motor",
        rules_dir=tmp_path,
        network_dir=tmp_path,
    )
    text = found.render()
    assert "no USB serial adapters found" in text
    assert "no CAN interfaces found" in text
    assert f"{tmp_path / 'rover-motor'}: absent" in text
    assert found.summary() == (
        f"no USB serial adapters, no CAN interfaces, {tmp_path / 'rover-motor'} absent"
    )
    assert json.loads(json.dumps(found.to_json()))["serial_ports"] == []


def test_absent_builtin_uarts_are_hidden_and_by_id_links_found(tmp_path: Path):
    sys_tty = tmp_path / "class-tty"
    for name, uart_type in (("ttyS0", "4"), ("ttyS1", "0")):
        (sys_tty / name).mkdir(parents=True)
        (sys_tty / name / "type").write_text(uart_type + "\n")
    dev = tmp_path / "dev"
    dev.mkdir()
    usb = dev / "ttyUSB0"
    usb.touch()
    by_id = dev / "serial" / "by-id"
    by_id.mkdir(parents=True)
    link = by_id / "usb-FTDI_FT232R_USB_UART_A10KZ4PB-if00-port0"
    link.symlink_to("../../ttyUSB0")
    infos = []
    for name in ("ttyS0", "ttyS1"):
        infos.append(ListPortInfo(f"/dev/{name}", skip_link_detection=True))
    ftdi = ListPortInfo(str(usb), skip_link_detection=True)
    ftdi.vid, ftdi.pid, ftdi.serial_number, ftdi.location = 0x0403, 0x6001, "A10KZ4PB", "1-1.2"
    infos.append(ftdi)
    ports, hidden = list_serial_ports(lambda: infos, by_id_dir=by_id, sys_class_tty=sys_tty)
    assert hidden == ["/dev/ttyS1"]
    assert [p.device for p in ports] == ["/dev/ttyS0", str(usb)]
    assert ports[1].by_id == (str(link),)
    assert ports[1].vid_pid == "0403:6001"
    assert (ports[1].usb_port, ports[1].interface_number) == ("1-1.2", "00")
    assert not ports[0].is_usb


def _node(path: Path, subsystem: Path, **attrs: str) -> Path:
    path.mkdir(parents=True, exist_ok=True)
    (path / "subsystem").symlink_to(subsystem)
    for name, value in attrs.items():
        (path / name).write_text(value + "\n")
    return path


@pytest.fixture
def fake_sysfs(tmp_path: Path) -> Path:
    """/sys with a candleLight on 1-1.4 (can0), a vcan0 and an ethernet eth0."""
    sys = tmp_path / "sys"
    bus_usb = sys / "bus" / "usb"
    gs_usb = bus_usb / "drivers" / "gs_usb"
    gs_usb.mkdir(parents=True)
    class_net = sys / "class" / "net"
    class_net.mkdir(parents=True)
    net_class = sys / "class" / "net-subsystem"
    net_class.mkdir()
    usb_dev = _node(
        sys / "devices" / "pci0000:00" / "usb1" / "1-1" / "1-1.4",
        bus_usb,
        idVendor="1d50",
        idProduct="606f",
        serial="003A00425741500220383733",
        product="candleLight USB to CAN adapter",
    )
    iface = _node(usb_dev / "1-1.4:1.0", bus_usb, bInterfaceNumber="00")
    (iface / "driver").symlink_to(gs_usb)
    can0 = _node(iface / "net" / "can0", net_class, type="280", operstate="up", dev_id="0x0")
    virtual = sys / "devices" / "virtual" / "net"
    vcan0 = _node(virtual / "vcan0", net_class, type="280", operstate="unknown")
    eth0 = _node(virtual / "eth0", net_class, type="1", operstate="up")
    for dev in (can0, vcan0, eth0):
        (class_net / dev.name).symlink_to(dev)
    return class_net


def fake_ip(name: str) -> dict[str, Any] | None:
    if name == "can0":
        return {
            "ifname": "can0",
            "linkinfo": {
                "info_kind": "can",
                "info_data": {
                    "state": "ERROR-ACTIVE",
                    "restart_ms": 100,
                    "bittiming": {"bitrate": 500000, "sample_point": "0.875"},
                },
            },
        }
    if name == "vcan0":
        return {"ifname": "vcan0", "linkinfo": {"info_kind": "vcan"}}
    return None


def test_can_interfaces_come_from_sysfs_and_ip(fake_sysfs: Path):
    can0, vcan0 = list_can_interfaces(fake_sysfs, fake_ip)
    assert can0.name == "can0"
    assert (can0.kind, can0.driver, can0.vid_pid) == ("can", "gs_usb", "1d50:606f")
    assert (can0.state, can0.bitrate, can0.restart_ms) == ("ERROR-ACTIVE", 500000, 100)
    assert (can0.usb_port, can0.serial_number) == ("1-1.4", "003A00425741500220383733")
    assert can0.operstate == "up"
    assert (vcan0.name, vcan0.kind, vcan0.driver, vcan0.vid_pid) == ("vcan0", "vcan", None, None)


def test_inventory_says_which_rule_renames_the_can_adapter(fake_sysfs: Path, tmp_path: Path):
    found = inventory(
        source=UDEV_DIR,
        comports=list,
        by_id_dir=tmp_path,
        sys_class_net=fake_sysfs,
        ip_details=fake_ip,
        motor_link=tmp_path / "rover-motor",
        rules_dir=tmp_path,
        network_dir=tmp_path,
    )
    can0, vcan0 = found.can
    (verdict,) = [v for v in can0.rules if v.matched]
    assert verdict.file == "70-rover-can.rules"
    assert verdict.name == "rovercan0"
    assert not any(v.matched for v in vcan0.rules)
    text = found.render()
    assert "can0  can  driver gs_usb  1d50:606f" in text
    assert "bitrate 500000" in text
    assert "-> named rovercan0" in text
    assert found.summary().startswith("no USB serial adapters, 2 CAN interfaces")
    data = found.to_json()["can_interfaces"][0]
    assert data["vid_pid"] == "1d50:606f"
    assert "chain" not in data


def test_motor_link_status(tmp_path: Path):
    device = tmp_path / "ttyACM0"
    device.touch()
    link = tmp_path / "rover-motor"
    assert not motor_link_status(link).exists
    link.symlink_to("ttyACM0")
    status = motor_link_status(link)
    assert (status.exists, status.is_symlink, status.target) == (True, True, "ttyACM0")
    assert status.resolved == str(device)
    assert status.describe() == f"{link} -> ttyACM0 ({device})"
    device.unlink()
    assert "dangling" in motor_link_status(link).describe()


def test_installed_files_are_compared_with_the_source(tmp_path: Path):
    rules_dir = tmp_path / "rules.d"
    rules_dir.mkdir()
    pinned = (UDEV_DIR / "99-rover-motor.rules").read_text()
    (rules_dir / "99-rover-motor.rules").write_text(
        pinned.replace("REPLACE_ME_WITH_SERIAL", "A10KZ4PB")
    )
    (rules_dir / "70-rover-can.rules").write_text("# edited by hand\n")
    (rules_dir / "99-rover-motor-bench.rules").write_bytes(
        (UDEV_DIR / "99-rover-motor-bench.rules").read_bytes()
    )
    found = inventory(
        source=UDEV_DIR,
        comports=list,
        by_id_dir=tmp_path,
        sys_class_net=tmp_path,
        motor_link=tmp_path / "rover-motor",
        rules_dir=rules_dir,
        network_dir=tmp_path,
    )
    status = {s.name: s.status for s in found.udev_files}
    assert status == {
        "70-rover-can.rules": "installed, differs from source",
        "80-rovercan0.network": "not installed",
        "99-rover-motor-bench.rules": "installed",
        "99-rover-motor.rules": "installed (placeholders filled)",
    }


def test_devices_with_a_missing_source_fails_clearly(capsys: pytest.CaptureFixture[str]):
    assert main(["devices", "--source", "/nonexistent/udev"]) == 1
    err = capsys.readouterr().err
    assert "udev source directory /nonexistent/udev (from --source) does not exist" in err
