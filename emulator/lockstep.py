"""A controller served in lockstep: one model tick per tick of a virtual clock.

:class:`LockstepController` serves a controller (model, C core or mutant) without
threads or a wall clock: on each tick of a :class:`~firmware_proto.linkio.clock.LockstepClock`
it handles what arrived, in order, runs one control period and writes what the model
sent, so a :class:`~firmware_proto.linkio.host.ProtocolHost` on the same clock runs a
script in virtual time, the same every run. Triggered faults wait in a
:class:`~emulator.injection.FaultSchedule`; link faults are refused. docs/emulator.md,
"In lockstep".
"""

from __future__ import annotations

import itertools
import logging
import math
from collections.abc import Sequence
from typing import Any

from emulator.controller import ControllerModel
from emulator.errors import InjectionError
from emulator.injection import FaultSchedule, Injector, parse_fault
from firmware_proto.linkio.clock import LockstepClock
from firmware_proto.linkio.endpoint import CONTROLLER, HOST, Endpoint
from firmware_proto.linkio.media import MEDIA
from firmware_proto.linkio.memory import memory_line
from firmware_proto.linkio.serial_endpoint import SerialEndpoint
from firmware_proto.wire.message import Message

__all__ = ["MEDIA", "LockstepController", "lockstep_pair"]

logger = logging.getLogger(__name__)


_channels = itertools.count()


class LockstepController:
    """A controller model on a controller-side endpoint, ticked by a lockstep clock."""

    name = "lockstep"

    def __init__(self, model: ControllerModel, endpoint: Endpoint, clock: LockstepClock) -> None:
        """Args:
        model: the controller (not yet booted); its twin's time step is the tick.
        endpoint: its end of the link, not yet open (side ``controller``).
        clock: the clock to tick on; its ``dt_s`` must be the twin's.

        Raises:
            ValueError: a host-side endpoint, or a clock of another time step.
        """
        if endpoint.side != CONTROLLER:
            raise ValueError("a lockstep controller needs a controller-side endpoint")
        if not math.isclose(clock.dt_s, model.twin.dt_s, rel_tol=1e-9):
            raise ValueError(f"clock tick {clock.dt_s} s is not the twin's {model.twin.dt_s} s")
        self.model = model
        self.endpoint = endpoint
        self.clock = clock
        self.injector = Injector(model, self)
        self.schedule = FaultSchedule(self.injector, source="control")
        """Faults waiting for their trigger (polled after each control period)."""
        self._rx_errors_seen = 0
        self._opened = False

    def open(self) -> LockstepController:
        """Open the endpoint, boot the model (its IDENT goes out) and tick from now on."""
        self.endpoint.open()
        self._opened = True
        self._send(self.model.boot())
        self.clock.add(self.tick)
        return self

    def close(self) -> None:
        """Close the endpoint (idempotent); later ticks do nothing."""
        if self._opened:
            self._opened = False
            self.endpoint.close()

    def _send(self, messages: Sequence[Message]) -> None:
        for message in messages:
            self.endpoint.write(message)

    def tick(self) -> None:
        """What arrived, in order; one control period; what the model sent."""
        if not self._opened:
            return
        model = self.model
        for message, _seq in self.endpoint.read_ready():
            self._send(model.handle(message))
        out = model.tick()
        out += self.schedule.poll()
        errors = self.endpoint.counters.rejected
        if errors != self._rx_errors_seen:
            model.rx_error(errors - self._rx_errors_seen)
            self._rx_errors_seen = errors
        self._send(out)

    def inject(self, fault: str) -> dict[str, Any]:
        """Apply a fault now, or schedule it when it has a trigger, as the control port's
        ``inject`` does; returns its answer.

        Raises:
            InjectionError: malformed, inapplicable, or a link fault.
        """
        spec = parse_fault(fault)
        self.injector.check(spec)
        if not spec.trigger.immediate:
            scheduled = self.schedule.add(spec, "control")
            return {"ok": True, "fault": fault, "scheduled": scheduled.fires}
        self._send(self.injector.apply(spec, "control"))
        return {"ok": True, "fault": fault, "t": round(self.model.now_s, 6)}

    # -- the injector's link (LinkFaultTarget) ----------------------------------------------
    def restart(self) -> None:
        """A reboot: the frame counter starts again at 0 (docs/protocol.md)."""
        self.endpoint.restart_counter()

    def check_link_faults(
        self,
        *,
        drop: float | None = None,
        corrupt: float | None = None,
        delay_s: float | None = None,
    ) -> None:
        """Link faults are the served front ends' (drawn on the wall clock): refused.

        Raises:
            InjectionError: always.
        """
        raise InjectionError("link faults need a served emulator (rover emulate), not lockstep")

    def set_link_faults(
        self,
        *,
        drop: float | None = None,
        corrupt: float | None = None,
        delay_s: float | None = None,
    ) -> None:
        """Refused, as :meth:`check_link_faults`."""
        self.check_link_faults(drop=drop, corrupt=corrupt, delay_s=delay_s)


def lockstep_pair(
    model: ControllerModel,
    medium: str = "serial",
    *,
    node: int = 1,
    clock: LockstepClock | None = None,
) -> tuple[LockstepController, Endpoint, LockstepClock]:
    """``(controller, host endpoint, clock)`` for ``model`` (not yet booted) in lockstep
    on ``medium``: ``serial`` (an in-memory line) or ``can`` (a fresh python-can
    ``virtual`` channel, the controller at ``node``). ``clock`` defaults to a new one at
    the twin's step. Open the controller (it boots), then a
    :class:`~firmware_proto.linkio.host.ProtocolHost` on the endpoint and the clock.

    Raises:
        ValueError: an unknown medium (the message lists the known ones).
    """
    clock = clock or LockstepClock(model.twin.dt_s)
    if medium == "serial":
        host_port, controller_port = memory_line(f"lockstep-{next(_channels)}")
        host_end: Endpoint = SerialEndpoint(HOST, lambda: host_port, name=host_port.name)
        controller_end: Endpoint = SerialEndpoint(
            CONTROLLER, lambda: controller_port, name=controller_port.name
        )
    elif medium == "can":
        # python-can only for a CAN pair (a serial link never loads it).
        from firmware_proto.linkio.can_endpoint import CanEndpoint  # noqa: PLC0415

        channel = f"lockstep-{next(_channels)}"
        host_end = CanEndpoint(HOST, "virtual", channel, node=node)
        controller_end = CanEndpoint(CONTROLLER, "virtual", channel, node=node)
    else:
        raise ValueError(f"unknown lockstep medium {medium!r}; known: {', '.join(MEDIA)}")
    return LockstepController(model, controller_end, clock), host_end, clock
