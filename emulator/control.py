"""The emulator's local control interface: one command per line over TCP, JSON answers.

Listens on 127.0.0.1 only. Commands: ``status``, ``stats`` (a PIL target's
counters), ``inject FAULT`` (refused at once if it cannot apply), ``injections``,
``unplug [SECONDS]``, ``replug``, ``help`` (docs/emulator.md, "Control interface").

Each answer is one JSON line: ``{"ok": true, ...}`` or ``{"ok": false, "error": "..."}``;
bad commands get an error answer and the connection carries on. ``inject`` answers
``applied_s`` (twin time) when applied at once, else ``scheduled_s`` and ``fires``.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import socketserver
import threading
from typing import Any, Protocol

from emulator.engine import EmulatorStatus
from emulator.errors import EmulatorError
from emulator.injection import InjectionRecord, ScheduledFault
from emulator.serial_frontend import SerialFrontEnd

__all__ = ["ControlServer", "ControlTarget"]

logger = logging.getLogger(__name__)

_HELP = "commands: status | stats | inject FAULT | injections | unplug [SECONDS] | replug | help"


class ControlTarget(Protocol):
    """What the control interface serves: an :class:`~emulator.engine.Emulator`, or a
    processor-in-the-loop target (``emulator.pil.target.PilTarget``)."""

    @property
    def frontend(self) -> object:
        """The front end (``unplug``/``replug`` need a :class:`SerialFrontEnd`)."""

    @property
    def injections(self) -> list[InjectionRecord]:
        """Every injection applied so far."""

    def status(self) -> EmulatorStatus:
        """A fresh snapshot."""

    def inject(self, fault: str, source: str = ...) -> InjectionRecord | ScheduledFault:
        """Apply or schedule a fault; raises InjectionError when it cannot apply."""


class _Handler(socketserver.StreamRequestHandler):
    server: _Server

    def handle(self) -> None:
        for raw in self.rfile:
            line = raw.decode("utf-8", "replace").strip()
            if not line:
                continue
            answer = self.server.control.execute(line)
            self.wfile.write((json.dumps(answer) + "\n").encode())
            self.wfile.flush()


class _Server(socketserver.ThreadingTCPServer):
    daemon_threads = True
    allow_reuse_address = True
    block_on_close = True
    control: ControlServer


class ControlServer:
    """Serves the control interface of one :class:`ControlTarget` on 127.0.0.1."""

    def __init__(self, emulator: ControlTarget, port: int = 0) -> None:
        """Serve ``emulator`` on ``port`` of 127.0.0.1 (0: a free one, see :attr:`port`)."""
        self.emulator = emulator
        self._server = _Server(("127.0.0.1", port), _Handler)
        self._server.control = self
        self.port: int = self._server.server_address[1]
        self._thread = threading.Thread(
            target=self._server.serve_forever, name="emulator-ctl", daemon=True
        )
        self._timers: list[threading.Timer] = []
        self._lock = threading.Lock()
        self._closed = False

    def start(self) -> ControlServer:
        """Start serving in a background thread."""
        self._thread.start()
        logger.info("control interface on 127.0.0.1:%d", self.port)
        return self

    def close(self) -> None:
        """Stop serving, cancel pending replugs, join threads (idempotent)."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            timers, self._timers = self._timers, []
        for timer in timers:
            timer.cancel()
            timer.join(timeout=5.0)
        if self._thread.is_alive():
            self._server.shutdown()
            self._thread.join(timeout=5.0)
        self._server.server_close()

    def execute(self, line: str) -> dict[str, Any]:
        """Run one command line; never raises."""
        verb, _, arg = line.partition(" ")
        arg = arg.strip()
        try:
            if verb == "status":
                return {"ok": True, "status": dataclasses.asdict(self.emulator.status())}
            if verb == "inject":
                if not arg:
                    raise ValueError("inject needs a fault, e.g. inject slip:left=0.3")
                done = self.emulator.inject(arg, source="control")
                if isinstance(done, InjectionRecord):
                    return {"ok": True, "fault": done.fault, "applied_s": round(done.time_s, 6)}
                return {
                    "ok": True,
                    "fault": done.fault,
                    "scheduled_s": round(done.scheduled_s, 6),
                    "fires": done.fires,
                }
            if verb == "stats":
                port_stats = getattr(self.emulator, "port_stats", None)
                if port_stats is None:
                    raise ValueError("stats applies to a PIL target (rover pil) only")
                return {"ok": True, "stats": dataclasses.asdict(port_stats())}
            if verb == "injections":
                return {
                    "ok": True,
                    "injections": [dataclasses.asdict(r) for r in self.emulator.injections],
                }
            if verb in ("unplug", "replug"):
                return self._plug(verb, arg)
            if verb == "help":
                return {"ok": True, "help": _HELP}
            raise ValueError(f"unknown command {verb!r}; {_HELP}")
        except (EmulatorError, ValueError, RuntimeError, TimeoutError) as exc:
            return {"ok": False, "error": str(exc)}

    def _plug(self, verb: str, arg: str) -> dict[str, Any]:
        frontend = self.emulator.frontend
        if not isinstance(frontend, SerialFrontEnd):
            raise ValueError(f"{verb} applies to the serial front end only")
        if verb == "replug":
            frontend.replug()
            return {"ok": True, "device": frontend.device}
        frontend.unplug()
        if arg:
            seconds = float(arg)
            if not 0 < seconds <= 3600:
                raise ValueError("unplug SECONDS must be in (0, 3600]")
            timer = threading.Timer(seconds, frontend.replug)
            timer.daemon = True
            with self._lock:
                if self._closed:
                    raise RuntimeError("control interface closed")
                self._timers = [t for t in self._timers if t.is_alive()] + [timer]
            timer.start()
        return {"ok": True}
