"""What is plugged in: serial ports, CAN interfaces, and what our udev rules do to them.

:func:`inventory` gathers, for ``rover devices``: serial ports from pyserial (built-in
UARTs without hardware, which kernels from 6.5 report and pyserial no longer filters,
are hidden and counted), CAN interfaces from ``/sys/class/net`` with ``ip -details
-json`` where it can tell, which of our rules files would name each device
(:func:`udev.rules.evaluate`) or would once a pinned placeholder holds its serial or
port, ``/dev/rover-motor``, SocketCAN support, and whether our files are installed.
Every source is a parameter with the real one as default (tests feed synthetic ports
and a fake sysfs tree).
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import re
import shutil
import socket
import subprocess
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Protocol

from serial.tools import list_ports

from udev.install import (
    DEFAULT_NETWORK_DIR,
    DEFAULT_RULES_DIR,
    PLACEHOLDER_SERIAL,
    PLACEHOLDER_USB_PORT,
    SourceFile,
    fill_placeholders,
    source_files,
)
from udev.rules import DeviceNode, RulesFile, UdevEvent, evaluate, parse_rules

__all__ = [
    "ARPHRD_CAN",
    "MOTOR_LINK",
    "CanInterface",
    "Inventory",
    "MotorLink",
    "PortInfo",
    "RulesVerdict",
    "SerialPort",
    "SocketCan",
    "UdevFileStatus",
    "inventory",
    "list_can_interfaces",
    "list_serial_ports",
    "motor_link_status",
    "socketcan_support",
]

logger = logging.getLogger(__name__)

ARPHRD_CAN = 280
MOTOR_LINK = Path("/dev/rover-motor")
BY_ID_DIR = Path("/dev/serial/by-id")
SYS_CLASS_TTY = Path("/sys/class/tty")
SYS_CLASS_NET = Path("/sys/class/net")
IP_TIMEOUT_S = 5.0

# sysfs attributes read along a device's parent chain (the ones our rules can match).
_CHAIN_ATTRS = (
    "idVendor",
    "idProduct",
    "serial",
    "manufacturer",
    "product",
    "bInterfaceNumber",
    "type",
    "dev_id",
    "dev_port",
)


class PortInfo(Protocol):
    """What we read from a pyserial ``ListPortInfo`` (or anything shaped like it)."""

    device: str
    name: str
    description: str
    hwid: str
    vid: int | None
    pid: int | None
    serial_number: str | None
    location: str | None
    manufacturer: str | None
    product: str | None
    interface: str | None


def _split_location(location: str | None) -> tuple[str | None, str]:
    """pyserial's location (``1-1.2`` or ``1-1.2:1.0``) -> (USB port path, interface)."""
    if not location:
        return None, "00"
    port, _, iface = location.partition(":")
    number = iface.rpartition(".")[2] if iface else "0"
    try:
        return port, f"{int(number):02x}"
    except ValueError:
        return port, "00"


@dataclass(frozen=True)
class SerialPort:
    """One serial port, as pyserial describes it, plus its ``/dev/serial/by-id`` links."""

    device: str
    name: str
    description: str | None = None
    vid: int | None = None
    pid: int | None = None
    serial_number: str | None = None
    manufacturer: str | None = None
    product: str | None = None
    location: str | None = None
    interface: str | None = None
    by_id: tuple[str, ...] = ()

    @classmethod
    def from_info(cls, info: PortInfo, by_id: Iterable[str] = ()) -> SerialPort:
        def text(value: str | None) -> str | None:
            return None if value in (None, "", "n/a") else value

        return cls(
            device=info.device,
            name=info.name,
            description=text(info.description),
            vid=info.vid,
            pid=info.pid,
            serial_number=text(info.serial_number),
            manufacturer=text(info.manufacturer),
            product=text(info.product),
            location=text(info.location),
            interface=text(info.interface),
            by_id=tuple(by_id),
        )

    @property
    def is_usb(self) -> bool:
        return self.vid is not None and self.pid is not None

    @property
    def vid_pid(self) -> str | None:
        """``"0403:6001"``, or None for a port without USB ids."""
        return f"{self.vid:04x}:{self.pid:04x}" if self.is_usb else None

    @property
    def usb_port(self) -> str | None:
        """The USB port path (``1-1.2``), what ``KERNELS==`` matches on the USB device."""
        return _split_location(self.location)[0] if self.is_usb else None

    @property
    def interface_number(self) -> str | None:
        """``"00"``-style USB interface number, as udev's ID_USB_INTERFACE_NUM."""
        return _split_location(self.location)[1] if self.is_usb else None

    def udev_event(self) -> UdevEvent:
        """The ``add`` event udev would see for this tty, as far as pyserial tells."""
        chain = [DeviceNode(self.name, "tty")]
        env = {"DEVNAME": self.device}
        if self.vid is not None and self.pid is not None:
            port, iface = _split_location(self.location)
            if self.name.startswith("ttyUSB"):
                chain.append(DeviceNode(self.name, "usb-serial"))
            chain.append(
                DeviceNode(
                    f"{port}:1.{int(iface, 16)}" if port else "",
                    "usb",
                    attrs={"bInterfaceNumber": iface},
                )
            )
            attrs = {"idVendor": f"{self.vid:04x}", "idProduct": f"{self.pid:04x}"}
            for key, value in (
                ("serial", self.serial_number),
                ("manufacturer", self.manufacturer),
                ("product", self.product),
            ):
                if value is not None:
                    attrs[key] = value
            chain.append(DeviceNode(port or "", "usb", "usb", attrs))
            env.update(
                ID_BUS="usb",
                ID_VENDOR_ID=f"{self.vid:04x}",
                ID_MODEL_ID=f"{self.pid:04x}",
                ID_USB_INTERFACE_NUM=iface,
            )
            if self.serial_number is not None:
                env["ID_SERIAL_SHORT"] = self.serial_number
        return UdevEvent(tuple(chain), env)


@dataclass(frozen=True)
class CanInterface:
    """One network interface of type CAN (ARPHRD 280), from sysfs and ``ip -details``."""

    name: str
    kind: str | None = None  # "can", "vcan", "vxcan", ... (ip's info_kind)
    driver: str | None = None
    operstate: str | None = None
    state: str | None = None  # controller state: ERROR-ACTIVE, BUS-OFF, ...
    bitrate: int | None = None
    restart_ms: int | None = None
    vid: int | None = None
    pid: int | None = None
    serial_number: str | None = None
    usb_port: str | None = None
    chain: tuple[DeviceNode, ...] = field(default=(), repr=False, compare=False)

    @property
    def vid_pid(self) -> str | None:
        return (
            f"{self.vid:04x}:{self.pid:04x}"
            if self.vid is not None and self.pid is not None
            else None
        )

    def udev_event(self) -> UdevEvent:
        chain = self.chain or (DeviceNode(self.name, "net", attrs={"type": str(ARPHRD_CAN)}),)
        return UdevEvent(chain, {"INTERFACE": self.name})


@dataclass(frozen=True)
class SocketCan:
    """Whether this kernel can open a CAN_RAW socket, and why not if not."""

    available: bool
    detail: str


@dataclass(frozen=True)
class MotorLink:
    """``/dev/rover-motor``: whether it exists and where it points."""

    path: str
    exists: bool
    is_symlink: bool
    target: str | None = None  # the link as written
    resolved: str | None = None  # the device it leads to

    def describe(self) -> str:
        if self.exists and self.is_symlink:
            return f"{self.path} -> {self.target} ({self.resolved})"
        if self.exists:
            return f"{self.path} exists but is not a symlink (not made by our rules?)"
        if self.is_symlink:
            return f"{self.path} -> {self.target}: dangling, the device is gone"
        return f"{self.path}: absent"


@dataclass(frozen=True)
class RulesVerdict:
    """What one of our rules files would do to one device."""

    file: str
    hits: tuple[str, ...] = ()  # "file:line"
    symlinks: tuple[str, ...] = ()
    name: str | None = None
    group: str | None = None
    mode: str | None = None
    assumed: tuple[str, ...] = ()
    pending: str | None = None  # a pinned rule that would match once filled in

    @property
    def matched(self) -> bool:
        return bool(self.hits)

    def describe(self) -> str:
        if not self.matched:
            return f"{self.file}: {self.pending}" if self.pending else f"{self.file}: no match"
        effects = [f"/dev/{link}" for link in self.symlinks]
        if self.name:
            effects.append(f"named {self.name}")
        if self.group:
            effects.append(f"group {self.group}")
        if self.mode:
            effects.append(f"mode {self.mode}")
        text = f"{', '.join(self.hits)} -> {', '.join(effects) or 'no visible effect'}"
        if self.assumed:
            text += f" (assuming {len(self.assumed)} key(s) we cannot evaluate)"
        return text


@dataclass(frozen=True)
class UdevFileStatus:
    """One of our files and its installed copy (``status``: ``not installed``,
    ``installed``, ``installed (placeholders filled)``, ``installed, differs from source``)."""

    name: str
    source: str
    target: str
    status: str


@dataclass(frozen=True)
class _Source:
    file: SourceFile
    text: str
    parsed: RulesFile


def list_serial_ports(
    comports: Callable[[], Iterable[PortInfo]] | None = None,
    *,
    by_id_dir: Path = BY_ID_DIR,
    sys_class_tty: Path = SYS_CLASS_TTY,
) -> tuple[list[SerialPort], list[str]]:
    """Serial ports, sorted by device; and the devices hidden as absent built-in UARTs."""
    if comports is None:
        comports = list_ports.comports
    links: dict[str, list[str]] = {}
    if by_id_dir.is_dir():
        for entry in sorted(by_id_dir.iterdir()):
            with contextlib.suppress(OSError):
                links.setdefault(os.path.realpath(entry), []).append(str(entry))
    ports: list[SerialPort] = []
    hidden: list[str] = []
    for info in comports():
        if info.vid is None and _read(sys_class_tty / info.name / "type") == "0":
            hidden.append(info.device)
            continue
        ports.append(SerialPort.from_info(info, links.get(os.path.realpath(info.device), [])))
    ports.sort(key=lambda p: p.device)
    return ports, sorted(hidden)


def _read(path: Path) -> str | None:
    try:
        return path.read_text(encoding="utf-8", errors="replace").strip()
    except OSError:
        return None


def _sysfs_chain(device_dir: Path) -> list[DeviceNode]:
    """The parents of a sysfs device directory, nearest first, with :data:`_CHAIN_ATTRS`."""
    nodes: list[DeviceNode] = []
    path = device_dir.parent
    while path != path.parent and path.name not in ("devices", "sys"):
        subsystem = path / "subsystem"
        if subsystem.exists():
            driver = path / "driver"
            attrs = {
                name: value for name in _CHAIN_ATTRS if (value := _read(path / name)) is not None
            }
            nodes.append(
                DeviceNode(
                    path.name,
                    Path(os.path.realpath(subsystem)).name,
                    Path(os.path.realpath(driver)).name if driver.exists() else None,
                    attrs,
                )
            )
        path = path.parent
    return nodes


def _ip_details(name: str) -> dict[str, Any] | None:
    """``ip -details -json link show dev NAME`` parsed, or None where ip cannot tell."""
    ip = shutil.which("ip")
    if ip is None:
        return None
    try:
        result = subprocess.run(
            [ip, "-details", "-json", "link", "show", "dev", name],
            capture_output=True,
            text=True,
            timeout=IP_TIMEOUT_S,
            check=False,
        )
        data = json.loads(result.stdout) if result.returncode == 0 else None
    except (OSError, subprocess.SubprocessError, ValueError) as exc:
        logger.debug("ip -details for %s failed: %s", name, exc)
        return None
    if isinstance(data, list) and data and isinstance(data[0], dict):
        return data[0]
    return None


def list_can_interfaces(
    sys_class_net: Path = SYS_CLASS_NET,
    ip_details: Callable[[str], dict[str, Any] | None] = _ip_details,
) -> list[CanInterface]:
    """CAN interfaces (type 280) under ``sys_class_net``, sorted by name."""
    found: list[CanInterface] = []
    if not sys_class_net.is_dir():
        return found
    for entry in sorted(sys_class_net.iterdir()):
        if _read(entry / "type") != str(ARPHRD_CAN):
            continue
        own = {name: v for name in ("type", "dev_id", "dev_port") if (v := _read(entry / name))}
        chain = [DeviceNode(entry.name, "net", attrs=own), *_sysfs_chain(entry.resolve())]
        usb = next((n for n in chain if "idVendor" in n.attrs), None)
        details = ip_details(entry.name) or {}
        linkinfo = details.get("linkinfo") or {}
        data = linkinfo.get("info_data") or {}
        bittiming = data.get("bittiming") or {}
        driver = next((n.driver for n in chain[1:] if n.driver and n.driver != "usb"), None)

        found.append(
            CanInterface(
                name=entry.name,
                kind=linkinfo.get("info_kind"),
                driver=driver,
                operstate=_read(entry / "operstate"),
                state=data.get("state"),
                bitrate=_int_or_none(bittiming.get("bitrate")),
                restart_ms=_int_or_none(data.get("restart_ms")),
                vid=int(usb.attrs["idVendor"], 16) if usb else None,
                pid=int(usb.attrs["idProduct"], 16) if usb and "idProduct" in usb.attrs else None,
                serial_number=usb.attrs.get("serial") if usb else None,
                usb_port=usb.kernel if usb else None,
                chain=tuple(chain),
            )
        )
    return found


def _int_or_none(value: object) -> int | None:
    return value if isinstance(value, int) and not isinstance(value, bool) else None


def socketcan_support() -> SocketCan:
    """Try to open a CAN_RAW socket; this kernel's answer."""
    family = getattr(socket, "AF_CAN", None)
    if family is None:
        return SocketCan(False, "this Python has no socket.AF_CAN")
    try:
        sock = socket.socket(family, socket.SOCK_RAW, socket.CAN_RAW)
    except OSError as exc:
        return SocketCan(False, f"the kernel has no SocketCAN (AF_CAN): {exc.strerror or exc}")
    sock.close()
    return SocketCan(True, "SocketCAN (AF_CAN) is available")


def motor_link_status(path: Path = MOTOR_LINK) -> MotorLink:
    """Where ``path`` (``/dev/rover-motor``) points, if anywhere."""
    is_link = path.is_symlink()
    return MotorLink(
        path=str(path),
        exists=path.exists(),
        is_symlink=is_link,
        target=os.readlink(path) if is_link else None,
        resolved=os.path.realpath(path) if path.exists() else None,
    )


def _load_sources(directory: Path | None) -> list[_Source]:
    if directory is None:
        return []
    sources: list[_Source] = []
    for file in source_files(directory):
        if file.kind != "rules":
            continue
        text = file.path.read_text(encoding="utf-8")
        sources.append(_Source(file, text, parse_rules(text, str(file.path))))
    return sources


def _verdicts(
    sources: Sequence[_Source], event: UdevEvent, serial: str | None, usb_port: str | None
) -> list[RulesVerdict]:
    verdicts: list[RulesVerdict] = []
    for src in sources:
        outcome = evaluate([src.parsed], event)
        pending = None
        if not outcome.hits and (
            PLACEHOLDER_SERIAL in src.text or PLACEHOLDER_USB_PORT in src.text
        ):
            fills = [
                (PLACEHOLDER_SERIAL, "--serial", serial),
                (PLACEHOLDER_USB_PORT, "--usb-port", usb_port),
            ]
            for placeholder, flag, value in fills:
                if value is None or placeholder not in src.text:
                    continue
                try:
                    filled = fill_placeholders(
                        src.text,
                        serial=value if flag == "--serial" else None,
                        usb_port=value if flag == "--usb-port" else None,
                    )
                except ValueError:
                    continue
                if evaluate([parse_rules(filled, str(src.file.path))], event).hits:
                    pending = (
                        f"would match once {placeholder} is {value} "
                        f"('rover udev install {flag} {value}')"
                    )
                    break
        verdicts.append(
            RulesVerdict(
                file=src.file.name,
                hits=tuple(hit.where for hit in outcome.hits),
                symlinks=outcome.symlinks,
                name=outcome.name,
                group=outcome.group,
                mode=outcome.mode,
                assumed=outcome.assumed,
                pending=pending,
            )
        )
    return verdicts


def _installed_status(
    directory: Path | None, rules_dir: Path, network_dir: Path
) -> list[UdevFileStatus]:
    if directory is None:
        return []
    statuses: list[UdevFileStatus] = []
    for file in source_files(directory):
        target = (rules_dir if file.kind == "rules" else network_dir) / file.name
        installed = _read_bytes(target)
        source = file.path.read_bytes()
        if installed is None:
            status = "not installed"
        elif installed == source:
            status = "installed"
        else:
            pattern = re.escape(source.decode("utf-8", "replace"))
            for placeholder in (PLACEHOLDER_SERIAL, PLACEHOLDER_USB_PORT):
                pattern = pattern.replace(re.escape(placeholder), r'[^"\n]+')
            filled = re.fullmatch(pattern, installed.decode("utf-8", "replace"))
            status = (
                "installed (placeholders filled)" if filled else "installed, differs from source"
            )
        statuses.append(UdevFileStatus(file.name, str(file.path), str(target), status))
    return statuses


def _read_bytes(path: Path) -> bytes | None:
    try:
        return path.read_bytes()
    except OSError:
        return None


@dataclass(frozen=True)
class PortReport:
    port: SerialPort
    rules: tuple[RulesVerdict, ...]


@dataclass(frozen=True)
class CanReport:
    interface: CanInterface
    rules: tuple[RulesVerdict, ...]


@dataclass(frozen=True)
class Inventory:
    """Everything ``rover devices`` reports; :meth:`render` and :meth:`to_json`."""

    ports: tuple[PortReport, ...]
    hidden_ports: tuple[str, ...]
    can: tuple[CanReport, ...]
    socketcan: SocketCan
    motor_link: MotorLink
    udev_files: tuple[UdevFileStatus, ...]
    source_dir: str | None
    source_problems: tuple[str, ...] = ()

    @property
    def usb_ports(self) -> tuple[PortReport, ...]:
        return tuple(r for r in self.ports if r.port.is_usb)

    def conflicts(self) -> list[str]:
        """Links that more than one device would claim under one rules file."""
        claims: dict[tuple[str, str], list[str]] = {}
        for report in self.ports:
            for verdict in report.rules:
                for link in verdict.symlinks:
                    claims.setdefault((verdict.file, link), []).append(report.port.device)
        return [
            f"{len(devices)} devices would claim /dev/{link} under {file} "
            f"({', '.join(devices)}): which one gets it is not defined; "
            "use the pinned rules or unplug the others"
            for (file, link), devices in sorted(claims.items())
            if len(devices) > 1
        ]

    def summary(self) -> str:
        usb = len(self.usb_ports)
        parts = [
            f"{usb} USB serial adapter{'s' if usb != 1 else ''}"
            if usb
            else "no USB serial adapters",
            f"{len(self.can)} CAN interface{'s' if len(self.can) != 1 else ''}"
            if self.can
            else "no CAN interfaces",
            f"{self.motor_link.path} {'present' if self.motor_link.exists else 'absent'}",
        ]
        return ", ".join(parts)

    def to_json(self) -> dict[str, Any]:
        def port_json(report: PortReport) -> dict[str, Any]:
            data = asdict(report.port)
            data.update(
                vid_pid=report.port.vid_pid,
                usb_port=report.port.usb_port,
                interface_number=report.port.interface_number,
                rules=[asdict(v) | {"matched": v.matched} for v in report.rules],
            )
            return data

        def can_json(report: CanReport) -> dict[str, Any]:
            data = asdict(report.interface)
            data.pop("chain")
            data.update(
                vid_pid=report.interface.vid_pid,
                rules=[asdict(v) | {"matched": v.matched} for v in report.rules],
            )
            return data

        return {
            "summary": self.summary(),
            "serial_ports": [port_json(r) for r in self.ports],
            "hidden_serial_ports": list(self.hidden_ports),
            "can_interfaces": [can_json(r) for r in self.can],
            "socketcan": asdict(self.socketcan),
            "motor_link": asdict(self.motor_link),
            "udev_source_dir": self.source_dir,
            "udev_source_problems": list(self.source_problems),
            "udev_files": [asdict(s) for s in self.udev_files],
            "conflicts": self.conflicts(),
        }

    def render(self) -> str:
        out: list[str] = ["Serial ports (pyserial list_ports)"]
        for report in self.ports:
            port = report.port
            if not port.is_usb:
                out.append(
                    f"  {port.device}  built-in serial port, no USB ids: no rule of ours applies"
                )
                continue
            names = " ".join(x for x in (port.manufacturer, port.product) if x) or port.description
            head = f"  {port.device}  {port.vid_pid}  {names or '?'}"
            out.append(head)
            out.append(
                f"      serial {port.serial_number or '(none)'}  usb port {port.usb_port or '?'}"
                f"  interface {port.interface_number}"
            )
            for link in port.by_id:
                out.append(f"      by-id {link}")
            out.extend(_rule_lines(report.rules))
        if not self.usb_ports:
            out.append("  no USB serial adapters found")
        if self.hidden_ports:
            out.append(
                f"  ({len(self.hidden_ports)} built-in port(s) without a UART hidden: "
                f"{', '.join(self.hidden_ports)})"
            )
        out.append("CAN interfaces (/sys/class/net, type 280)")
        for can in self.can:
            iface = can.interface
            facts = [
                iface.kind or "?",
                f"driver {iface.driver}" if iface.driver else None,
                iface.vid_pid,
                f"serial {iface.serial_number}" if iface.serial_number else None,
                f"usb port {iface.usb_port}" if iface.usb_port else None,
                f"operstate {iface.operstate}" if iface.operstate else None,
                f"state {iface.state}" if iface.state else None,
                f"bitrate {iface.bitrate}" if iface.bitrate else None,
            ]
            out.append(f"  {iface.name}  " + "  ".join(f for f in facts if f))
            out.extend(_rule_lines(can.rules))
        if not self.can:
            out.append("  no CAN interfaces found")
        out.append(f"  SocketCAN: {self.socketcan.detail}")
        out.append("Motor controller link")
        out.append(f"  {self.motor_link.describe()}")
        out.append(f"Our udev files ({self.source_dir or 'source directory not found'})")
        for status in self.udev_files:
            out.append(f"  {status.name:<30} {status.status}  ({status.target})")
        for problem in self.source_problems:
            out.append(f"  problem: {problem}")
        out.extend(f"warning: {conflict}" for conflict in self.conflicts())
        out.append(f"Summary: {self.summary()}.")
        return "\n".join(out)


def _rule_lines(verdicts: Sequence[RulesVerdict]) -> list[str]:
    relevant = [v for v in verdicts if v.matched or v.pending]
    if not relevant:
        return ["      rule  none of our rules matches this device"]
    return [f"      rule  {v.describe()}" for v in relevant]


def inventory(
    *,
    source: Path | None,
    comports: Callable[[], Iterable[PortInfo]] | None = None,
    by_id_dir: Path = BY_ID_DIR,
    sys_class_tty: Path = SYS_CLASS_TTY,
    sys_class_net: Path = SYS_CLASS_NET,
    ip_details: Callable[[str], dict[str, Any] | None] = _ip_details,
    motor_link: Path = MOTOR_LINK,
    rules_dir: Path = DEFAULT_RULES_DIR,
    network_dir: Path = DEFAULT_NETWORK_DIR,
    socketcan: Callable[[], SocketCan] = socketcan_support,
) -> Inventory:
    """Gather what ``rover devices`` shows; ``source``: our ``udev/`` (None: no verdicts)."""
    sources = _load_sources(source)
    problems = tuple(str(i) for s in sources for i in s.parsed.issues)
    ports, hidden = list_serial_ports(comports, by_id_dir=by_id_dir, sys_class_tty=sys_class_tty)
    port_reports = tuple(
        PortReport(
            port,
            tuple(_verdicts(sources, port.udev_event(), port.serial_number, port.usb_port))
            if port.is_usb
            else (),
        )
        for port in ports
    )
    can_reports = tuple(
        CanReport(
            iface,
            tuple(_verdicts(sources, iface.udev_event(), iface.serial_number, iface.usb_port)),
        )
        for iface in list_can_interfaces(sys_class_net, ip_details)
    )
    return Inventory(
        ports=port_reports,
        hidden_ports=tuple(hidden),
        can=can_reports,
        socketcan=socketcan(),
        motor_link=motor_link_status(motor_link),
        udev_files=tuple(_installed_status(source, rules_dir, network_dir)),
        source_dir=str(source) if source else None,
        source_problems=problems,
    )
