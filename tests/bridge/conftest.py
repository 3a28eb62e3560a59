"""Fixtures of the bridge tests: ROS port backends, loopback DDS, collecting callbacks,
real emulators (pty or python-can bus) with a ``/command_status`` recorder, and
:class:`~bridge.link.controllerlink.ControllerLink` instances on them.

The same end-to-end test runs on every medium through :data:`MEDIA` and :func:`serve`:
a pty, python-can's ``virtual`` bus, and ``socketcan`` on ``vcan0`` where the kernel has
it (skipped elsewhere, saying why).

ROS port tests run on both backends through :data:`BACKEND_PARAMS`: ``inprocess`` and
real ROS 2 (``rclpy``, marker ``rclpy``: only inside the private network namespace that
``.ci/test`` sets up, where DDS discovery cannot leave the machine; tests/conftest.py).
"""

from __future__ import annotations

import dataclasses
import itertools
import os
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from bridge.link.controllerlink import ControllerLink, LinkConfig
from bridge.link.transport import Transport, open_transport
from bridge.ros.rosport import RosPort, open_port
from emulator.can_frontend import CanFrontEnd
from emulator.controller import ControllerConfig
from emulator.engine import Emulator, EmulatorStatus
from emulator.firmware import make_controller
from emulator.frontend import FrontEnd
from emulator.mutants import mutant as find_mutant
from emulator.serial_frontend import SerialFrontEnd
from emulator.twin import GATE_DT_S, Twin, served_dt_s
from firmware_proto.linkio.clock import WALL, Clock
from firmware_proto.linkio.inbox import Inbox as WaitableLog
from firmware_proto.model.rover import RoverDescription, load_rover
from firmware_proto.runtime.realtime import BRIDGE_PRIORITY, EMULATOR_PRIORITY
from firmware_proto.wire.messages import SCHEMA_HASH
from tests.conftest import IN_VCAN_VM
from tests.scheduling import threads_at

#: Every backend, with the marks it needs.
BACKEND_PARAMS = [
    pytest.param("inprocess", id="inprocess"),
    pytest.param("rclpy", id="rclpy", marks=pytest.mark.rclpy),
    pytest.param("rclpy-process", id="rclpy-process", marks=pytest.mark.rclpy),
]


PortFactory = Callable[..., RosPort]


@pytest.fixture
def make_port(request: pytest.FixtureRequest) -> Iterator[PortFactory]:
    """``make_port(backend, namespace=..., node_name=...)``; every port closes at teardown.

    In-process ports of one test share a bus private to that test.
    """
    ports: list[RosPort] = []
    bus = f"test-{request.node.nodeid}"

    def make(backend: str, **kwargs: Any) -> RosPort:
        if backend == "inprocess":
            kwargs.setdefault("bus", bus)
        port = open_port(backend, **kwargs)
        ports.append(port)
        return port

    yield make
    for port in reversed(ports):
        port.close()


class Inbox:
    """A callback that keeps what it receives (in the link layer's waitable
    :class:`~firmware_proto.linkio.inbox.Inbox`), and lets a test wait for it."""

    def __init__(self) -> None:
        self.log: WaitableLog[Any] = WaitableLog()
        self.threads: set[str] = set()

    @property
    def items(self) -> list[Any]:
        """Everything received, in order."""
        return self.log.items()

    def __call__(self, msg: Any) -> None:
        self.threads.add(threading.current_thread().name)
        self.log.append(msg)

    def wait_for(self, count: int, timeout_s: float = 10.0) -> list[Any]:
        """Wait until ``count`` items arrived; fail the test on timeout."""
        if not self.log.until(lambda xs: len(xs) >= count, since=0, timeout_s=timeout_s):
            pytest.fail(f"received {len(self.items)} of {count} messages in {timeout_s} s")
        return self.items

    def wait_until(
        self, pred: Callable[[Any], bool], *, since: int = 0, timeout_s: float = 10.0
    ) -> Any:
        """The first item from index ``since`` on that satisfies ``pred``, waiting for it;
        fail the test on timeout."""
        found = self.log.wait(pred, since=since, timeout_s=timeout_s)
        if found is None:
            pytest.fail(f"none of {len(self.items) - since} items matched in {timeout_s} s")
        return found[1]

    def mark(self) -> int:
        """Index to wait from: items received after this call."""
        return self.log.mark()


# -- emulators and status recording (link and node tests) -------------------------------

SPEED = 1.0 if IN_VCAN_VM else 4.0
"""Twin seconds per wall second for served emulators (timeouts scaled to match). Real
time inside .ci/vcan-vm, whose CPU may be emulated (TCG): two emulators at four times
real time there fall behind their own heartbeats."""
TWIN_DT_S = GATE_DT_S if IN_VCAN_VM else served_dt_s(SPEED)
"""The twin's physics step, s: as ``rover emulate`` takes it at :data:`SPEED`; inside
.ci/vcan-vm the gate's (and the wire simulator's) 10 ms, for the same reason: a Python
loop runs 6 to 20 times slower there than on its host (docs/vcan-vm.md)."""
VM_ACK_TIMEOUT_S = 0.25
"""The links' ACK timeout inside .ci/vcan-vm unless a test sets its own: there a frame's
round trip through two Python processes on the emulated CPU may take longer than the
protocol's 50 ms, and a retry is then no lost frame."""

VM_LINK_LOST_BEATS = 10
"""The links' (and bridges') controller heartbeats missed before ``fault:link_lost``
inside .ci/vcan-vm unless a test sets its own, instead of the protocol's 3 (the bridge's
``link_lost_beats``): there a test process sharing the emulated CPU with its emulator
may be kept off it for longer than three of them, and a link lost in a test of
something else is a false failure."""

WIDE_LINK_LOST_BEATS = 10
"""The bridge's ``link_lost_beats`` where an in-process real-time test is about something
else (its emulator, bridge and test share one process): about 1 s of silence, not the
protocol's 0.3 s. Beside four busy processes a CI run saw that process stall 409 ms and
the bridge call the link lost in a test of odometry across a reboot (2026-11-30); a link
that a test drops for good is still called lost, a second later."""

WIDE_WATCHDOG_MS = 1000
"""The controller's watchdog, ms, where a real-time test is about something else: in
.ci/vcan-vm's software CPU, beside a load of many times the cores, and on this host for
the frozen-node and reboot tests. A stall of about 200 ms is enough for the protocol's
250 ms to fire (an idle CI run saw both of the bridge's children stall 165-177 ms within
4 ms and the test's emulator fall 214 ms behind: docs/testing.md), while a fault that
such a test looks for, a link held up for a second or more, still trips 1 s."""


def vm_slack(config: dict[str, Any]) -> dict[str, Any]:
    """``config`` (a link's or bridge's settings) with the VM's defaults added inside
    .ci/vcan-vm (:data:`VM_ACK_TIMEOUT_S`, :data:`VM_LINK_LOST_BEATS`); as given
    elsewhere."""
    if IN_VCAN_VM:
        config.setdefault("ack_timeout_s", VM_ACK_TIMEOUT_S)
        config.setdefault("link_lost_beats", VM_LINK_LOST_BEATS)
    return config


_channels = itertools.count()


class Recorder:
    """Collects ``/command_status`` strings (in a waitable
    :class:`~firmware_proto.linkio.inbox.Inbox`); waits on them with timeouts, in
    ``clock`` seconds (a lockstep clock's waits advance it)."""

    def __init__(self, clock: Clock = WALL) -> None:
        self.log: WaitableLog[str] = WaitableLog(clock=clock)

    @property
    def items(self) -> list[str]:
        """Every status received, in order."""
        return self.log.items()

    def __call__(self, text: str) -> None:
        self.log.append(text)

    def mark(self) -> int:
        return self.log.mark()

    def since(self, mark: int) -> list[str]:
        return self.log.items(mark)

    def wait(
        self, pred: Callable[[list[str]], bool], *, since: int = 0, timeout: float = 15.0
    ) -> list[str]:
        """Wait until ``pred(items since mark)`` holds; returns those items."""
        if not self.log.until(pred, since=since, timeout_s=timeout):
            raise TimeoutError(
                f"status condition not met in {timeout} s; got {self.log.items(since)}"
            )
        return self.log.items(since)

    def wait_count(self, text: str, n: int, *, since: int = 0, timeout: float = 15.0) -> list[str]:
        return self.wait(lambda xs: xs.count(text) >= n, since=since, timeout=timeout)


@pytest.fixture(scope="session")
def rover() -> RoverDescription:
    return load_rover()


@pytest.fixture
def emulators(rover: RoverDescription) -> Iterator[Callable[..., Emulator]]:
    """Factory of running emulators; ``kind`` "pty" or "can", ``firmware`` "python" (the
    model) or "c" (the C core, emulator/firmware.py), ``watchdog_ms`` and
    ``telemetry_hz`` the controller's (its defaults unless given), ``mutant`` a Python
    model with one rule broken (emulator.mutants); all closed after the test."""
    started: list[Emulator] = []

    def make(
        kind: str = "pty",
        *,
        link: Path | None = None,
        seed: int = 1,
        node: int = 1,
        channel: str | None = None,
        interface: str = "virtual",
        schema_hash: int = SCHEMA_HASH,
        firmware: str = "python",
        watchdog_ms: int | None = None,
        telemetry_hz: int | None = None,
        mutant: str = "",
    ) -> Emulator:
        config = ControllerConfig(timeout_scale=SPEED)
        if watchdog_ms is not None:
            config = dataclasses.replace(config, watchdog_ms=watchdog_ms)
        if telemetry_hz is not None:
            config = dataclasses.replace(config, telemetry_hz=telemetry_hz)
        twin = Twin(rover, dt_s=TWIN_DT_S)
        if mutant:  # the Python model with one rule broken (emulator.mutants)
            model = find_mutant(mutant).model(
                rover, twin, config, seed=seed, schema_hash=schema_hash
            )
        else:
            model = make_controller(
                firmware, rover, twin, config, seed=seed, schema_hash=schema_hash
            )
        frontend: FrontEnd
        if kind == "pty":
            frontend = SerialFrontEnd(link=link, seed=seed)
        else:
            frontend = CanFrontEnd(
                interface=interface, channel=channel or "bridge", node=node, seed=seed
            )
        emu = Emulator(model, frontend, speed_factor=SPEED)
        with threads_at(EMULATOR_PRIORITY):  # as `rover emulate` runs it
            emu.start()
        started.append(emu)
        return emu

    yield make
    for emu in started:
        emu.close()


@pytest.fixture
def can_channel() -> str:
    return f"bridge-test-{next(_channels)}"


# -- media: the same test on a pty, a virtual CAN bus and SocketCAN -----------------------

HAVE_VCAN0 = os.path.exists("/sys/class/net/vcan0")
NO_VCAN0 = "no vcan0 here: this kernel has no SocketCAN (udev/vcan-up.sh says why)"

#: Every medium a link test can run on.
MEDIA = [
    pytest.param("pty", id="pty"),
    pytest.param("virtual", id="virtual"),
    pytest.param(
        "socketcan",
        id="socketcan",
        marks=[pytest.mark.socketcan, pytest.mark.skipif(not HAVE_VCAN0, reason=NO_VCAN0)],
    ),
]
#: The CAN media only.
CAN_MEDIA = MEDIA[1:]


def can_channel_for(kind: str, channel: str) -> str:
    """The channel a CAN test uses: ``vcan0`` on socketcan, else the test's own."""
    return "vcan0" if kind == "socketcan" else channel


def wait_emulator(
    emu: Emulator, pred: Callable[[EmulatorStatus], bool], what: str, timeout_s: float = 10.0
) -> EmulatorStatus:
    """Poll the emulator's status (every 10 ms, bounded) until ``pred`` holds; fail the
    test, saying ``what`` was awaited, on timeout."""
    deadline = time.monotonic() + timeout_s
    while True:
        status = emu.status()
        if pred(status):
            return status
        if time.monotonic() > deadline:
            pytest.fail(f"the emulator never reached: {what} in {timeout_s} s; last {status}")
        time.sleep(0.01)


def serve(emulators: Callable[..., Emulator], kind: str, channel: str, **kw: Any) -> Emulator:
    """A running emulator on medium ``kind`` (see :data:`MEDIA`); ``channel`` names the
    virtual bus; ``kw`` go to the ``emulators`` factory."""
    if kind == "pty":
        return emulators("pty", **kw)
    return emulators("can", interface=kind, channel=can_channel_for(kind, channel), **kw)


def link_url(emu: Emulator) -> str:
    """The transport URL a host uses to reach ``emu``."""
    front = emu.frontend
    if isinstance(front, SerialFrontEnd):
        return front.device
    assert isinstance(front, CanFrontEnd)
    return f"can://{front.interface}/{front.channel}?node={front.node}"


Links = Callable[..., tuple[ControllerLink, Recorder]]


def start_link(
    url: str,
    *,
    transport_factory: Callable[[str], Transport] = open_transport,
    **config: float,
) -> tuple[ControllerLink, Recorder]:
    """A started link to ``url`` (``config``: LinkConfig fields) and its status
    recorder; ``transport_factory`` builds its transports (a test's subclass of a real
    one). The caller closes the link."""
    rec = Recorder()
    link = ControllerLink(
        LinkConfig(url, **config),  # type: ignore[arg-type]
        on_status=rec,
        transport_factory=transport_factory,
    )
    with threads_at(BRIDGE_PRIORITY):  # as `rover bridge` runs it
        link.start()
    return link, rec


@pytest.fixture
def links() -> Iterator[Links]:
    """``links(url, **LinkConfig fields)`` -> a started link and its status recorder; all
    closed after the test."""
    started: list[ControllerLink] = []

    def make(url: str, **config: float) -> tuple[ControllerLink, Recorder]:
        link, rec = start_link(url, transport_factory=open_transport, **vm_slack(config))
        started.append(link)
        return link, rec

    yield make
    for link in started:
        link.close()
