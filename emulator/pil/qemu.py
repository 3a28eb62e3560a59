"""The nRF51 image under qemu-system-arm ``-M microbit``: the controller's UART on a pty,
its plant inside the image (``-DFW_PIL``: ``port_pil/pil_plant.c``).

qemu runs with ``-serial pty`` (unpaced, lossless), a QMP socket for
``system_reset`` (``reboot`` is a real reset from the reset vector), and a GDB stub
through which the runner reads ``pil_view``/``pil_stats`` and writes ``pil_hooks``
(each access stops the machine briefly). No ``-icount``: the emulated timers follow the
host clock, which at real-time priority keeps the watchdog in wall time.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import re
import socket
import subprocess
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

from emulator.injection import FaultSpec
from emulator.pil.errors import PilError
from emulator.pil.gdbstub import GdbStub
from emulator.pil.images import Image, require_tool
from emulator.pil.target import PilTarget
from emulator.pil.view import STATS, VIEW, WORLD, WORLD_MAGIC, PilStats, PortView, hooks_bytes
from firmware_proto.model.worldmap import load_map

__all__ = ["MicrobitTarget", "qemu_command"]

logger = logging.getLogger(__name__)

_PTY = re.compile(r"char device redirected to (/dev/pts/\d+) \(label serial0\)")
_START_TIMEOUT_S = 20.0
_SIDES = {"left": (0,), "right": (1,), "both": (0, 1), None: (0, 1)}


def qemu_command(elf: Path, qmp: Path, gdb: Path, icount: int | None = None) -> list[str]:
    """qemu-system-arm's command line for ``elf``, halted until the GDB stub continues it;
    ``icount``: ``-icount shift=N`` (benchmarks only: conformance's watchdog would fail)."""
    extra = ["-icount", f"shift={icount}"] if icount is not None else []
    return [
        require_tool("qemu-system-arm", "qemu-system-arm"),
        "-M",
        "microbit",
        "-nographic",
        "-monitor",
        "none",
        "-serial",
        "pty",
        "-qmp",
        f"unix:{qmp},server=on,wait=off",
        "-chardev",
        f"socket,id=gdb0,path={gdb},server=on,wait=off",
        "-gdb",
        "chardev:gdb0",
        "-S",
        *extra,
        "-kernel",
        str(elf),
    ]


def _set_scheduling(priority: int) -> None:
    """In the child before exec: real-time round robin where permitted, else nothing."""
    if priority > 0:
        with contextlib.suppress(OSError):
            os.sched_setscheduler(0, os.SCHED_RR, os.sched_param(priority))


class MicrobitTarget(PilTarget):
    """The nRF51 image in qemu; its in-image plant starts at ``map_name``'s start pose."""

    name = "microbit"
    plant_name = "the in-image kinematic wheel and encoder model (FW_PIL)"

    def __init__(
        self, image: Image, *, map_name: str = "lab", icount: int | None = None, **kwargs: Any
    ) -> None:
        super().__init__(image, **kwargs)
        self.map_name = map_name
        self.icount = icount

    def _start_emulator(self) -> None:
        if not self.image.pil or "pil_hooks" not in self.image.symbols:
            raise PilError("the microbit target needs the image built with the PIL flag")
        self._tmp = tempfile.TemporaryDirectory(prefix="rover-pil-")
        tmp = Path(self._tmp.name)
        self._qmp_path, gdb_path = tmp / "qmp.sock", tmp / "gdb.sock"
        self._stall = [False, False]
        self._dropout = [False, False]
        self._slip = [1.0, 1.0]
        self._proc = subprocess.Popen(
            qemu_command(self.image.elf, self._qmp_path, gdb_path, self.icount),
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,  # the pty's name (qemu_printf), and its errors
            stderr=subprocess.STDOUT,
            text=True,
            preexec_fn=lambda: _set_scheduling(self.realtime_priority),  # noqa: PLW1509
        )
        self._stderr: list[str] = []
        got = threading.Event()

        def read_stderr() -> None:
            assert self._proc.stdout is not None
            for line in self._proc.stdout:
                self._stderr.append(line.rstrip())
                match = _PTY.search(line)
                if match:
                    self.device = match.group(1)
                    got.set()
            got.set()

        self._reader = threading.Thread(target=read_stderr, name="pil-qemu-stderr", daemon=True)
        self._reader.start()
        if not got.wait(_START_TIMEOUT_S) or not self.device:
            raise PilError("qemu did not start: " + " | ".join(self._stderr[-5:]))
        self.realtime_note = self._scheduling_note()
        self._gdb = GdbStub(str(gdb_path), timeout_s=5.0)
        # Halted before its first instruction (-S): the world starts at the map's pose.
        start = load_map(self.map_name).start
        self._gdb.write(
            self.image.symbols["pil_world"],
            WORLD.pack(
                WORLD_MAGIC,
                round(start.x * 1000),
                round(start.y * 1000),
                round(start.yaw_deg * 10),
                0,
            ),
        )
        self._gdb.cont()

    def _scheduling_note(self) -> str:
        if self.realtime_priority <= 0:
            return "normal scheduling (asked for none)"
        try:
            policy = os.sched_getscheduler(self._proc.pid)
        except OSError as exc:
            return f"unknown ({exc.strerror})"
        if policy == os.SCHED_RR:
            return f"SCHED_RR priority {self.realtime_priority}"
        return "normal scheduling: real-time priority not permitted"

    def alive(self) -> bool:
        return hasattr(self, "_proc") and self._proc.poll() is None

    def _close_emulator(self) -> None:
        gdb = getattr(self, "_gdb", None)
        if gdb is not None:
            gdb.close()
        proc = getattr(self, "_proc", None)
        if proc is not None:
            if proc.poll() is None:
                proc.terminate()
                try:
                    proc.wait(10)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait(5)
            self._reader.join(5)
            if proc.stdout is not None:
                proc.stdout.close()
        tmp = getattr(self, "_tmp", None)
        if tmp is not None:
            tmp.cleanup()

    # -- the machine -------------------------------------------------------------------------
    def _qmp(self, command: str) -> dict[str, object]:
        with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
            sock.settimeout(5.0)
            sock.connect(str(self._qmp_path))
            stream = sock.makefile("rw", encoding="utf-8")
            json.loads(stream.readline())  # the greeting
            for cmd in ("qmp_capabilities", command):
                stream.write(json.dumps({"execute": cmd}) + "\n")
                stream.flush()
                while True:
                    answer: dict[str, object] = json.loads(stream.readline())
                    if "return" in answer or "error" in answer:
                        break
            if "error" in answer:
                raise PilError(f"qemu refused {command}: {answer['error']}")
            return answer

    def reset(self) -> None:
        """A hardware reset of the MCU (qemu's ``system_reset``); the hooks in force are
        written again once the restarted image ticks (its start-up zeroes them)."""
        before = self._ticks()
        self._qmp("system_reset")
        deadline = time.monotonic() + 5.0
        while time.monotonic() < deadline:
            time.sleep(0.005)
            ticks = self._ticks()
            if 0 < ticks < before:
                break
        else:
            raise PilError("the image did not start again after system_reset")
        self._write_hooks()

    def _ticks(self) -> int:
        return PilStats.decode(self._gdb.read(self.image.symbols["pil_stats"], STATS.size)).ticks

    def _write_hooks(self) -> None:
        data = hooks_bytes(
            (self._stall[0], self._stall[1]),
            (self._dropout[0], self._dropout[1]),
            (self._slip[0], self._slip[1]),
        )
        self._gdb.write(self.image.symbols["pil_hooks"], data)

    def _apply(self, spec: FaultSpec) -> None:
        if spec.kind == "reboot":
            self.reset()
            return
        kind = spec.target if spec.kind == "clear" else spec.kind
        for i in _SIDES[spec.side]:
            if kind == "stall":
                self._stall[i] = spec.kind != "clear"
            elif kind == "encoder-dropout":
                self._dropout[i] = spec.kind != "clear"
            elif kind == "slip":
                self._slip[i] = 1.0 if spec.kind == "clear" else float(spec.value or 1.0)
        self._write_hooks()

    def _read_port(self) -> tuple[PortView, PilStats]:
        view = PortView.decode(self._gdb.read(self.image.symbols["pil_view"], VIEW.size))
        stats = PilStats.decode(self._gdb.read(self.image.symbols["pil_stats"], STATS.size))
        return view, stats
