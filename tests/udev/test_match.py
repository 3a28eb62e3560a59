"""Which of our rules names which device: synthetic pyserial ports and CAN interfaces
replayed through the real rules files in udev/."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from serial.tools.list_ports_common import ListPortInfo

from udev.devices import CanInterface, SerialPort, inventory
from udev.install import fill_placeholders
from udev.rules import DeviceNode, RulesFile, evaluate, parse_rules

UDEV_DIR = Path(__file__).resolve().parents[2] / "udev"
PINNED = UDEV_DIR / "99-rover-motor.rules"
BENCH = UDEV_DIR / "99-rover-motor-bench.rules"
CAN = UDEV_DIR / "70-rover-can.rules"

# Every chip the rules and udev/README.md promise: (vid, pid, has a serial number).
SERIAL_CHIPS = {
    "FTDI FT232R": (0x0403, 0x6001, True),
    "FTDI FT231X": (0x0403, 0x6015, True),
    "FTDI FT2232 channel A": (0x0403, 0x6010, True),
    "Silicon Labs CP210x": (0x10C4, 0xEA60, True),
    "WCH CH9102": (0x1A86, 0x55D4, True),
    "WCH CH340": (0x1A86, 0x7523, False),
    "WCH CH341": (0x1A86, 0x5523, False),
    "STM32 VCP": (0x0483, 0x5740, True),
    "ST-LINK/V2-1 VCP": (0x0483, 0x374B, True),
    "RP2040 Pico SDK": (0x2E8A, 0x000A, True),
    "RP2040 MicroPython": (0x2E8A, 0x0005, True),
}


def port(
    device: str = "/dev/ttyUSB0",
    *,
    vid: int | None = 0x0403,
    pid: int | None = 0x6001,
    serial: str | None = "A10KZ4PB",
    location: str | None = "1-1.2",
    manufacturer: str | None = "FTDI",
    product: str | None = "FT232R USB UART",
) -> ListPortInfo:
    """A real pyserial ListPortInfo, filled as list_ports_linux fills it."""
    info = ListPortInfo(device, skip_link_detection=True)
    info.vid, info.pid, info.serial_number = vid, pid, serial
    info.location, info.manufacturer, info.product = location, manufacturer, product
    if vid is not None:
        info.apply_usb_info()
    return info


def rules(path: Path, **fill: str) -> RulesFile:
    parsed = parse_rules(fill_placeholders(path.read_text(), **fill), str(path))
    assert parsed.issues == ()
    return parsed


def line_of(path: Path, needle: str) -> int:
    """The line where the rule containing ``needle`` starts (continuations included)."""
    lines = path.read_text().splitlines()
    index = next(i for i, line in enumerate(lines) if needle in line)
    while index > 0 and lines[index - 1].rstrip().endswith("\\"):
        index -= 1
    return index + 1


def location_for(name: str) -> str:
    # Multi-interface devices (CDC-ACM, FT2232) report the interface in the location.
    return "1-1.2:1.0" if ("2232" in name or "VCP" in name or "RP2040" in name) else "1-1.2"


@pytest.mark.parametrize("chip", SERIAL_CHIPS)
def test_bench_rules_name_every_chip_rover_motor(chip: str):
    vid, pid, has_serial = SERIAL_CHIPS[chip]
    info = port(
        vid=vid, pid=pid, serial="S123" if has_serial else None, location=location_for(chip)
    )
    out = evaluate([rules(BENCH)], SerialPort.from_info(info).udev_event())
    assert out.symlinks == ("rover-motor",)
    assert (out.group, out.mode) == ("dialout", "0660")
    assert out.env["ID_MM_DEVICE_IGNORE"] == "1"
    assert out.assumed == ()
    hit, service = out.hits
    assert re.search(f"{pid:04x}", (BENCH.read_text().splitlines()[hit.line - 1]))
    # Then the device is handed to systemd, which starts the bridge's unit (bound to it).
    assert service.line == line_of(BENCH, "ENV{SYSTEMD_WANTS}+=")
    assert out.env["SYSTEMD_WANTS"] == "rover-bridge.service"


@pytest.mark.parametrize("chip", SERIAL_CHIPS)
def test_pinned_rules_match_only_the_pinned_unit(chip: str):
    vid, pid, has_serial = SERIAL_CHIPS[chip]
    loc = location_for(chip)
    info = port(vid=vid, pid=pid, serial="S123" if has_serial else None, location=loc)
    event = SerialPort.from_info(info).udev_event()
    # As shipped (placeholders), the pinned rules name nothing.
    assert evaluate([rules(PINNED)], event).symlinks == ()
    if has_serial:
        right, wrong = rules(PINNED, serial="S123"), rules(PINNED, serial="OTHER")
        needle = f'ATTRS{{idProduct}}=="{pid:04x}", ATTRS{{serial}}'
    else:
        right, wrong = rules(PINNED, usb_port="1-1.2"), rules(PINNED, usb_port="1-1.3")
        needle = f'ATTRS{{idProduct}}=="{pid:04x}", KERNELS'
    out = evaluate([right], event)
    assert out.symlinks == ("rover-motor",)
    assert [h.line for h in out.hits] == [
        line_of(PINNED, needle),
        line_of(PINNED, "ENV{SYSTEMD_WANTS}+="),
    ]
    assert out.env["SYSTEMD_WANTS"] == "rover-bridge.service"
    assert evaluate([wrong], event).symlinks == ()


def test_ft2232_channel_b_and_unknown_chips_and_builtin_ports_get_nothing():
    both = [rules(BENCH), rules(PINNED, serial="S123")]
    channel_b = port(pid=0x6010, serial="S123", location="1-1.2:1.1")
    prolific = port(vid=0x067B, pid=0x2303, serial=None, product="PL2303")
    builtin = port(device="/dev/ttyS0", vid=None, pid=None, serial=None, location=None)
    for info in (channel_b, prolific, builtin):
        for parsed in both:
            assert evaluate([parsed], SerialPort.from_info(info).udev_event()).hits == ()


def test_pinned_rule_says_which_serial_to_fill_in(tmp_path: Path):
    ports = [
        port(serial="A10KZ4PB"),
        port(device="/dev/ttyUSB1", vid=0x1A86, pid=0x7523, serial=None, location="1-1.3"),
    ]
    found = inventory(
        source=UDEV_DIR,
        comports=lambda: ports,
        by_id_dir=tmp_path,
        sys_class_net=tmp_path,
        motor_link=tmp_path / "rover-motor",
        rules_dir=tmp_path,
        network_dir=tmp_path,
    )
    pinned = [next(v for v in r.rules if v.file == PINNED.name) for r in found.ports]
    assert not pinned[0].matched
    assert pinned[0].pending is not None
    assert "--serial A10KZ4PB" in pinned[0].pending
    assert pinned[1].pending is not None
    assert "--usb-port 1-1.3" in pinned[1].pending
    text = found.render()
    assert "would match once REPLACE_ME_WITH_SERIAL is A10KZ4PB" in text
    # Two adapters under the bench rules: both claim the link, and we say so.
    (conflict,) = found.conflicts()
    assert "2 devices would claim /dev/rover-motor under 99-rover-motor-bench.rules" in conflict
    assert f"warning: {conflict}" in text


def can_event(vid: str, pid: str, *, type_: str = "280", action: str = "add") -> CanInterface:
    chain = (
        DeviceNode("can0", "net", attrs={"type": type_}),
        DeviceNode("1-1.4:1.0", "usb", "gs_usb", {"bInterfaceNumber": "00"}),
        DeviceNode("1-1.4", "usb", "usb", {"idVendor": vid, "idProduct": pid}),
    )
    return CanInterface(name="can0", chain=chain)


@pytest.mark.parametrize(
    ("vid", "pid"),
    [("1d50", "606f"), ("1209", "2323"), ("0c72", "000c"), ("0c72", "0012")],
    ids=["gs_usb", "candleLight", "PCAN-USB", "PCAN-USB FD"],
)
def test_can_rules_name_usb_can_adapters_rovercan0(vid: str, pid: str):
    out = evaluate([rules(CAN)], can_event(vid, pid).udev_event())
    assert out.name == "rovercan0"
    assert len(out.hits) == 1


def test_can_rules_leave_other_interfaces_and_events_alone():
    parsed = rules(CAN)
    not_can = can_event("1d50", "606f", type_="1").udev_event()
    assert evaluate([parsed], not_can).name is None
    other_vendor = can_event("0403", "6001").udev_event()
    assert evaluate([parsed], other_vendor).name is None
    vcan = CanInterface(name="vcan0").udev_event()
    assert evaluate([parsed], vcan).name is None
    change = can_event("1d50", "606f").udev_event()
    change = type(change)(change.chain, change.env, action="change")
    assert evaluate([parsed], change).name is None
