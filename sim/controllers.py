"""The controllers the simulator plays against, over their twin: the Python model
(:class:`emulator.controller.ControllerModel`) or the C firmware core
(:class:`emulator.firmware.FirmwareController`), behind the same interface.

:class:`SampleLeak` makes either one also send what a protocol v2 controller could:
sensor samples before a session (ENCODERS, at the telemetry rate, until a matching HELLO
opens one). A v3 controller sends none; a host must stay right with both, so the
simulator can add them (``--leak-samples``) to a controller that does not.
"""

from __future__ import annotations

import functools
from pathlib import Path

from emulator.controller import ControllerConfig, ControllerModel
from emulator.firmware import build_library, make_controller
from emulator.mutants import make_mutant
from emulator.twin import Twin
from firmware_proto.model.rover import RoverDescription
from firmware_proto.wire.message import Message
from firmware_proto.wire.messages import ENCODERS_RATE_HZ, Encoders

__all__ = ["SampleLeak", "build_controller"]


def build_controller(
    name: str,
    rover: RoverDescription,
    tick_s: float,
    queue_depth: int,
    seed: int,
    mutant: str = "",
) -> ControllerModel:
    """A controller (``python`` or ``c``) over a fresh twin on an open plane, booted
    (its boot IDENT is not sent: the host connects later). ``mutant``: the Python model
    with one rule broken instead (:mod:`emulator.mutants`; a fix of the controller side
    undone, for the simulator to find).

    Raises:
        ValueError: an unknown controller name.
        FirmwareBuildError: ``c`` and the core cannot be built here.
    """
    twin = Twin(rover, None, dt_s=tick_s)
    if mutant:
        if name != "python":
            raise ValueError(f"a controller mutant is a Python model, not {name!r}")
        model = make_mutant(
            mutant, rover, twin, ControllerConfig(queue_depth=queue_depth), seed=seed
        )
        model.boot()
        return model
    extra = {"library": _library()} if name == "c" else {}
    controller = make_controller(
        name, rover, twin, ControllerConfig(queue_depth=queue_depth), seed=seed, **extra
    )
    controller.boot()
    return controller


@functools.cache
def _library() -> Path:
    """The C core's shared library, built (or found in the cache) once per process."""
    return build_library()


class SampleLeak:
    """ENCODERS before a session, as a protocol v2 controller could send them."""

    def __init__(self, controller: ControllerModel) -> None:
        self.controller = controller
        self._next_s = 0.0
        self.sent = 0
        """Samples this adds (none while the controller sends its own)."""

    def after_tick(self, out: list[Message]) -> None:
        """Add an ENCODERS to a tick's output lacking one: no session open and one due."""
        c = self.controller
        now = c.twin.time_s
        if c.handshake_ok or now + 1e-9 < self._next_s:
            return
        self._next_s = now + 1.0 / ENCODERS_RATE_HZ
        if any(isinstance(m, Encoders) for m in out):
            return
        left, right = c.encoders.counts()
        t_ms = int((now - c.boot_s) * 1000.0 + 1e-6) & 0xFFFF
        out.append(Encoders(t_ms, _wrap24(left), _wrap24(right)))
        self.sent += 1


def _wrap24(value: int) -> int:
    return ((value + (1 << 23)) & 0xFFFFFF) - (1 << 23)
