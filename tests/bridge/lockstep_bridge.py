"""The bridge node in virtual time, for tests: the product's
:class:`~bridge.ros.node.BridgeNode`, its :class:`~bridge.link.controllerlink.ControllerLink`
and :class:`~bridge.ros.rosport.inprocess.InProcessPort` nodes on one
:class:`~firmware_proto.linkio.clock.LockstepClock`, against the Python controller model
served by a :class:`~emulator.lockstep.LockstepController` over an in-memory serial line
(bytes through the real codec). No thread, no wall clock: a test's wait advances the
clock tick by tick, so what it checks happens the same way on every run, however busy
the machine (docs/testing.md).

:class:`Line` is the medium, with the two outages a served emulator makes in real time:
**cut** (every frame lost both ways while the controller runs on, as the emulator's
``link-drop=1.0``) and **unplug** (the host's device gone: its reads and writes fail,
and it cannot be opened again until :meth:`Line.replug`, as
:meth:`~emulator.serial_frontend.SerialFrontEnd.unplug`). The same path over a real pty
in real time is tests/bridge/test_link.py's (the link) and tests/bridge/test_node.py's
(the node).
"""

from __future__ import annotations

import errno
import itertools
from collections.abc import Callable
from types import TracebackType
from typing import Any

import pytest

from bridge.link.transport import Transport
from bridge.ros.node import BridgeNode
from bridge.ros.params import load_params
from bridge.ros.rosport import RosPort, open_port
from bridge.ros.rosport.msgs import DiagnosticArray
from emulator.controller import ControllerConfig, ControllerModel
from emulator.lockstep import LockstepController
from emulator.twin import GATE_DT_S, Twin
from firmware_proto.linkio.clock import LockstepClock
from firmware_proto.linkio.endpoint import CONTROLLER, HOST
from firmware_proto.linkio.inbox import Inbox
from firmware_proto.linkio.memory import MemoryPort, memory_line
from firmware_proto.linkio.serial_endpoint import BytePort, SerialEndpoint
from firmware_proto.model.rover import RoverDescription

from .test_node import Client

__all__ = ["TICK_S", "Diagnostics", "Line", "LockstepBridge"]

TICK_S = GATE_DT_S
"""The clock's tick and the controller's control period, s (as a whole mission's in
virtual time, sim/world.py)."""

_names = itertools.count()


class Line:
    """An in-memory serial line from the bridge's transport to a lockstep controller that
    a test can cut or unplug (module docstring). One thread: the clock's."""

    def __init__(self, name: str) -> None:
        self.name = name
        self._host, self._controller = memory_line(name)
        self.cut = False
        """Every frame is lost, both ways (the controller runs on)."""
        self.plugged = True
        self._plugs = 0
        """Unplugs so far: a host end opened before the last one is gone for good."""
        self.opens = 0
        """Times the host's device was opened."""

    def controller_endpoint(self) -> SerialEndpoint:
        """The controller's end (for :class:`~emulator.lockstep.LockstepController`)."""
        port = self._controller
        return SerialEndpoint(CONTROLLER, lambda: port, name=port.name)

    def transport(self, url: str) -> Transport:
        """The bridge's transport factory: a transport on the host's end, which opens the
        device afresh each time (``ControllerLink`` calls it on every reconnect)."""
        return Transport(url, SerialEndpoint(HOST, self._open_host, name=url))

    def unplug(self) -> None:
        """The host's device disappears: the open one fails at its next read or write,
        and opening it fails until :meth:`replug`."""
        self.plugged = False
        self._plugs += 1

    def replug(self) -> None:
        """The device is back (a new one: nothing of the old survives)."""
        self.plugged = True

    def _open_host(self) -> BytePort:
        if not self.plugged:
            raise OSError(errno.ENOENT, "No such file or directory", self.name)
        self._host.read(0)  # a device opened afresh holds nothing from before
        self.opens += 1
        return _HostEnd(self, self._host, self._plugs)

    def gone(self, plugs: int) -> bool:
        """Whether a host end opened after ``plugs`` unplugs has lost its device."""
        return not self.plugged or plugs != self._plugs


class _HostEnd:
    """The host's open device on a :class:`Line` (a
    :class:`~firmware_proto.linkio.serial_endpoint.BytePort`)."""

    def __init__(self, line: Line, port: MemoryPort, plugs: int) -> None:
        self._line = line
        self._port = port
        self._plugs = plugs
        self._closed = False

    @property
    def name(self) -> str:
        return self._line.name

    def _check(self) -> None:
        if self._closed or self._line.gone(self._plugs):
            raise OSError(errno.EIO, "Input/output error (device gone)", self._line.name)

    def read(self, timeout_s: float) -> bytes:
        """What arrived (never waits: lockstep); nothing while the line is cut."""
        self._check()
        data = self._port.read(0)
        return b"" if self._line.cut else data

    def write(self, data: bytes) -> bool:
        """Hand ``data`` to the controller; lost on the way while the line is cut."""
        self._check()
        if self._line.cut:
            return True  # written: the line loses it
        return self._port.write(data)

    def close(self) -> None:
        self._closed = True


class Diagnostics:
    """``/diagnostics`` as it arrives on a port; waits advance the clock."""

    def __init__(self, port: RosPort, clock: LockstepClock) -> None:
        self.log: Inbox[DiagnosticArray] = Inbox(clock=clock)
        port.subscribe("/diagnostics", DiagnosticArray, self.log.append)

    def mark(self) -> int:
        return self.log.mark()

    def wait(
        self, pred: Callable[[DiagnosticArray], bool], *, since: int = 0, timeout: float = 15.0
    ) -> DiagnosticArray:
        """The first array at or after ``since`` for which ``pred`` holds, within
        ``timeout`` virtual seconds."""
        found = self.log.wait(pred, since=since, timeout_s=timeout)
        if found is None:
            pytest.fail(f"no matching /diagnostics in {timeout} virtual s ({self.log.mark()} seen)")
        return found[1]


class LockstepBridge:
    """A bridge node on a :class:`Line` to the controller model, a client (the executor,
    subscribed before the bridge starts) and a ``/diagnostics`` monitor, every part on
    one lockstep clock; the link is ready when it returns. Close it (or ``with``)."""

    def __init__(self, rover: RoverDescription, *, seed: int = 1, **params: Any) -> None:
        """Args:
        rover: the rover description.
        seed: the controller's sensor noise and boot nonce.
        params: bridge parameters (``load_params`` names) over the defaults.

        Raises:
            TimeoutError: the link was not ready within 5 virtual s.
        """
        self.clock = clock = LockstepClock(TICK_S)
        n = next(_names)
        self.line = Line(f"memory:lockstep-bridge-{n}")
        self.model = ControllerModel(rover, Twin(rover, dt_s=TICK_S), ControllerConfig(), seed=seed)
        self.controller = LockstepController(self.model, self.line.controller_endpoint(), clock)
        self._parts: list[Any] = [self.controller.open()]
        bus = f"lockstep-bridge-{n}"

        def port(name: str) -> RosPort:
            opened = open_port("inprocess", node_name=name, bus=bus, clock=clock)
            self._parts.append(opened)
            return opened

        try:
            self.client = Client(port("executor"), clock=clock)
            self.diagnostics = Diagnostics(port("monitor"), clock)
            values = {"device": self.line.name, "ros_backend": "inprocess", **params}
            self.node = BridgeNode(
                load_params(values, env={}),
                port("rover_bridge"),
                rover=rover,
                clock=clock,
                transport_factory=self.line.transport,
            )
            self._parts.append(self.node)
            self.node.start()
            self.client.status.wait_count("ready", 1, timeout=5.0)
        except BaseException:
            self.close()
            raise

    def run_until(self, ready: Callable[[], bool], timeout_s: float = 10.0) -> None:
        """Advance the clock until ``ready()``; fail the test after ``timeout_s`` virtual
        seconds."""
        deadline = self.clock.ticks + round(timeout_s / self.clock.dt_s)
        while not ready():
            if self.clock.ticks >= deadline:
                pytest.fail(f"condition not met in {timeout_s} virtual s")
            self.clock.advance()

    def close(self) -> None:
        """Close every part, last made first (idempotent)."""
        while self._parts:
            self._parts.pop().close()

    def __enter__(self) -> LockstepBridge:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
