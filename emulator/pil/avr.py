"""The ATmega2560 image under simavr with the pymunk twin as its plant.

The harness (``simavr_harness.c``, loaded with ctypes) owns the simulated MCU; this
module owns its time. One step is one plant step (1 ms by default): host bytes into
USART0 (paced at the baud rate in simulated time), the MCU run to the end of the step,
its transmitted bytes out, its motor outputs (Timer4 PWM duty, direction pins) drive the
twin one step, and the sensors are posted into the image's ``pil_sensors``. The same
:class:`AvrSystem` runs in real time (:class:`AvrTarget`) or lockstep
(:class:`AvrLockstep`).
"""

from __future__ import annotations

import ctypes
import errno
import hashlib
import itertools
import logging
import os
import random
import subprocess
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

from emulator.injection import FaultSpec, parse_fault
from emulator.pil.errors import PilError, PilToolMissingError
from emulator.pil.images import Image, cache_dir, require_tool
from emulator.pil.plant import MotorOutputs, TwinPlant
from emulator.pil.target import PilTarget
from emulator.pil.view import STATS, VIEW, PilStats, PortView
from emulator.twin import Pose2D, Twin
from firmware_proto.linkio.clock import LockstepClock
from firmware_proto.linkio.endpoint import HOST, Endpoint
from firmware_proto.linkio.memory import MemoryPort, memory_line
from firmware_proto.linkio.ptypair import PtyPair
from firmware_proto.linkio.serial_endpoint import SerialEndpoint
from firmware_proto.model.rover import RoverDescription, load_rover
from firmware_proto.model.worldmap import load_map
from firmware_proto.wire.messages import FaultCode

__all__ = [
    "F_CPU_HZ",
    "AvrLockstep",
    "AvrMcu",
    "AvrSystem",
    "AvrTarget",
    "avr_lockstep_pair",
    "build_harness",
    "make_system",
]

logger = logging.getLogger(__name__)

F_CPU_HZ = 16_000_000
"""The simulated clock (the image is built for it: F_CPU)."""
HARNESS_SOURCE = Path(__file__).with_name("simavr_harness.c")
PWM_FULL_SCALE_UM_S = 400_000
"""Wheel surface speed at 100 % duty (the port's FW_AVR_PWM_FULL_SCALE_UM_S)."""
# ATmega2560 data-space addresses (datasheet, "Register Summary").
_ICR4, _OCR4A, _OCR4B, _PORTH = 0xA6, 0xA8, 0xAA, 0x102
_GPIOR1 = 0x4A
_PH5, _PH6 = 5, 6
_OUT_CAP = 65536
_STATES = {7: "done", 8: "crashed"}
_lines = itertools.count()


def build_harness(timeout_s: float = 120.0) -> Path:
    """The harness as a shared library, compiled if its source or compiler changed.

    Raises:
        PilToolMissingError: no compiler, or no libsimavr-dev / libelf-dev.
        PilError: the build failed (its output in the message).
    """
    cc = require_tool(os.environ.get("CC", "gcc"), "gcc libc6-dev")
    if not Path("/usr/include/simavr/sim_avr.h").exists():
        raise PilToolMissingError(
            "libsimavr's headers not found: apt-get install libsimavr-dev libelf-dev "
            "(or bash .ci/bootstrap --test)"
        )
    flags = ["-std=c99", "-O2", "-fPIC", "-shared", "-Wall", "-Wextra", "-Werror"]
    libs = ["-lsimavr", "-lelf"]
    digest = hashlib.sha256(HARNESS_SOURCE.read_bytes())
    for part in [cc, *flags, *libs]:
        digest.update(part.encode() + b"\0")
    out_dir = cache_dir()
    out_dir.mkdir(parents=True, exist_ok=True)
    lib = out_dir / f"pil-simavr-harness-{digest.hexdigest()[:16]}.so"
    if not lib.exists():
        with tempfile.TemporaryDirectory(dir=out_dir) as tmp:
            tmp_lib = Path(tmp) / lib.name
            done = subprocess.run(
                [cc, *flags, str(HARNESS_SOURCE), "-o", str(tmp_lib), *libs],
                capture_output=True,
                text=True,
                timeout=timeout_s,
                check=False,
            )
            if done.returncode != 0:
                if "-lsimavr" in done.stderr or "-lelf" in done.stderr:
                    raise PilToolMissingError(
                        "libsimavr or libelf not found: apt-get install libsimavr-dev libelf-dev"
                    )
                raise PilError(f"building the simavr harness failed:\n{done.stderr}")
            os.replace(tmp_lib, lib)
    return lib


_LIBS: dict[Path, ctypes.CDLL] = {}
_LIB_LOCK = threading.Lock()


def _load(path: Path) -> ctypes.CDLL:
    with _LIB_LOCK:
        lib = _LIBS.get(path)
        if lib is None:
            lib = ctypes.CDLL(str(path))
            vp, u8p = ctypes.c_void_p, ctypes.POINTER(ctypes.c_uint8)
            lib.pil_avr_new.restype = vp
            lib.pil_avr_new.argtypes = [
                ctypes.c_char_p,
                ctypes.c_uint32,
                ctypes.POINTER(ctypes.c_int),
            ]
            lib.pil_avr_free.argtypes = [vp]
            lib.pil_avr_cycles.restype = ctypes.c_uint64
            lib.pil_avr_cycles.argtypes = [vp]
            lib.pil_avr_uart_send.restype = ctypes.c_uint32
            lib.pil_avr_uart_send.argtypes = [vp, ctypes.c_char_p, ctypes.c_uint32]
            lib.pil_avr_uart_take.restype = ctypes.c_uint32
            lib.pil_avr_uart_take.argtypes = [vp, u8p, ctypes.c_uint32]
            lib.pil_avr_uart_pending.restype = ctypes.c_uint32
            lib.pil_avr_uart_pending.argtypes = [vp]
            lib.pil_avr_run.restype = ctypes.c_int
            lib.pil_avr_run.argtypes = [vp, ctypes.c_uint64]
            lib.pil_avr_read.argtypes = [vp, ctypes.c_uint16, u8p, ctypes.c_uint16]
            lib.pil_avr_write.argtypes = [vp, ctypes.c_uint16, ctypes.c_char_p, ctypes.c_uint16]
            lib.pil_avr_reset.argtypes = [vp]
            _LIBS[path] = lib
        return lib


class AvrMcu:
    """One simulated ATmega2560 running ``image``. Not thread-safe (one caller at a time).

    Raises:
        PilError: the image cannot be loaded; PilToolMissingError: no libsimavr.
    """

    def __init__(self, image: Image, library: Path | None = None) -> None:
        self.image = image
        self._lib = _load(library or build_harness())
        err = ctypes.c_int(0)
        handle = self._lib.pil_avr_new(str(image.elf).encode(), F_CPU_HZ, ctypes.byref(err))
        if not handle:
            raise PilError(f"simavr cannot load {image.elf} (error {err.value})")
        self._h: int | None = handle
        self._out = (ctypes.c_uint8 * _OUT_CAP)()
        self._buf = (ctypes.c_uint8 * 64)()

    @property
    def cycles(self) -> int:
        """Cycles since power-on (not reset by :meth:`reset`)."""
        return int(self._lib.pil_avr_cycles(self._h))

    def send(self, data: bytes) -> int:
        """Queue host bytes for USART0; how many were taken (8 KiB wait at most)."""
        return int(self._lib.pil_avr_uart_send(self._h, data, len(data))) if data else 0

    def take(self) -> bytes:
        """The bytes USART0 transmitted since the last call."""
        n = self._lib.pil_avr_uart_take(self._h, self._out, _OUT_CAP)
        return bytes(self._out[:n])

    def run(self, until_cycle: int) -> None:
        """Run to ``until_cycle``.

        Raises:
            PilError: the program crashed or ended.
        """
        state = self._lib.pil_avr_run(self._h, until_cycle)
        if state in _STATES:
            raise PilError(f"the ATmega2560 program {_STATES[state]} at cycle {self.cycles}")

    def read(self, address: int, length: int) -> bytes:
        """Bytes of the data space (registers, I/O, SRAM)."""
        buf = (ctypes.c_uint8 * length)()
        self._lib.pil_avr_read(self._h, address, buf, length)
        return bytes(buf)

    def write(self, address: int, data: bytes) -> None:
        """Bytes into SRAM (the image's globals)."""
        self._lib.pil_avr_write(self._h, address, data, len(data))

    def reset(self) -> None:
        """The reset pin: the program starts again (its RAM is cleared by its start-up)."""
        self._lib.pil_avr_reset(self._h)

    def motor_outputs(self) -> MotorOutputs:
        """Timer4's duty and top, and PORTH's direction bits."""
        raw = self.read(_ICR4, 6)
        top = raw[0] | raw[1] << 8
        porth = self.read(_PORTH, 1)[0]
        return MotorOutputs(
            duty=(raw[2] | raw[3] << 8, raw[4] | raw[5] << 8),
            reverse=(bool(porth >> _PH5 & 1), bool(porth >> _PH6 & 1)),
            top=top,
            full_scale_um_s=PWM_FULL_SCALE_UM_S,
        )

    def close(self) -> None:
        """Free the simulator (idempotent)."""
        if self._h is not None:
            self._lib.pil_avr_free(self._h)
            self._h = None


class AvrSystem:
    """The MCU and its plant, advanced one plant step at a time (:meth:`step`).

    Args:
        image: the ATmega2560 image (PIL build).
        plant: the twin and its sensors; its time step is the step.
        seed: seeds the boot nonces (through GPIOR1/GPIOR2 at each reset).
    """

    def __init__(self, image: Image, plant: TwinPlant, seed: int = 1) -> None:
        for name in ("pil_sensors", "pil_view", "pil_stats"):
            if name not in image.symbols:
                raise PilError(f"the ATmega2560 image has no {name}: not a PIL build of port_avr")
        self.image = image
        self.plant = plant
        self.mcu = AvrMcu(image)
        self.cycles_per_step = round(F_CPU_HZ * plant.twin.dt_s)
        self._rng = random.Random(seed)
        self._until = 0
        self._seed_nonce()
        self.bytes_in = 0
        self.bytes_out = 0

    def _seed_nonce(self) -> None:
        self.mcu.write(_GPIOR1, self._rng.randrange(1 << 16).to_bytes(2, "little"))

    def step(self, received: bytes = b"") -> bytes:
        """One plant step: ``received`` into USART0, the MCU to the end of the step, the
        twin one step on the motor outputs, the sensors posted; what USART0 sent."""
        if received:
            self.bytes_in += self.mcu.send(received)
        self._until += self.cycles_per_step
        self.mcu.run(self._until)
        out = self.mcu.take()
        self.bytes_out += len(out)
        self.plant.step(self.mcu.motor_outputs())
        self.mcu.write(self.image.symbols["pil_sensors"], self.plant.sensors())
        return out

    def reset(self) -> None:
        """A reset of the MCU; the plant's decoder counters restart with it."""
        self.mcu.reset()
        self._seed_nonce()
        self.plant.reboot()

    def view(self) -> tuple[PortView, PilStats]:
        """The image's ``pil_view`` and ``pil_stats``."""
        s = self.image.symbols
        return (
            PortView.decode(self.mcu.read(s["pil_view"], VIEW.size)),
            PilStats.decode(self.mcu.read(s["pil_stats"], STATS.size)),
        )

    def close(self) -> None:
        """Free the simulator (idempotent)."""
        self.mcu.close()


def make_system(
    image: Image,
    *,
    map_name: str | None = "lab",
    rover: RoverDescription | None = None,
    seed: int = 1,
    dt_s: float = 0.001,
    start: Pose2D | None = None,
) -> AvrSystem:
    """An :class:`AvrSystem` on ``rover emulate``'s twin for ``map_name`` (``None``: open)."""
    rover = rover or load_rover()
    world = load_map(map_name) if map_name is not None else None
    twin = Twin(rover, world, dt_s=dt_s, start=start)
    return AvrSystem(image, TwinPlant(rover, twin, seed=seed), seed=seed)


def apply_fault(system: AvrSystem, spec: FaultSpec) -> None:
    """Put one fault into the plant (or reset the MCU)."""
    if spec.kind == "reboot":
        system.reset()
        return
    kind = spec.target if spec.kind == "clear" else spec.kind
    sides = {"left": (0,), "right": (1,), "both": (0, 1), None: (0, 1)}[spec.side]
    on = spec.kind != "clear"
    for side in sides:
        if kind == "slip":
            system.plant.set_slip(side, float(spec.value or 1.0) if on else 1.0)
        elif kind == "stall":
            system.plant.set_stall(side, on)
        elif kind == "encoder-dropout":
            system.plant.set_dropout(side, on)


class AvrTarget(PilTarget):
    """The ATmega2560 in real time: one plant step per millisecond of wall time, on a
    thread of its own, with USART0 on a pty.

    Args as :class:`~emulator.pil.target.PilTarget`, and ``map_name``: the twin's map.
    """

    name = "atmega2560"
    plant_name = "the pymunk twin (rover emulate's), through the simavr harness"

    def __init__(self, image: Image, *, map_name: str = "lab", **kwargs: Any) -> None:
        super().__init__(image, **kwargs)
        self.map_name = map_name
        self.late_steps = 0
        self.pty_drops = 0

    def _start_emulator(self) -> None:
        self.system = make_system(self.image, map_name=self.map_name, seed=self.seed)
        self._pty = PtyPair()
        os.set_blocking(self._pty.master_fd, False)
        self.device = self._pty.device
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="pil-avr", daemon=True)
        self._error: BaseException | None = None
        self._thread.start()
        self.realtime_note = "the runner's own thread (rover pil's scheduling)"

    def alive(self) -> bool:
        return self._thread.is_alive()

    def _serve(self) -> None:
        dt = self.system.plant.twin.dt_s
        fd = self._pty.master_fd
        next_wall = time.monotonic()
        try:
            while not self._stop.is_set():
                try:
                    received = os.read(fd, 4096)
                except BlockingIOError:
                    received = b""
                except OSError as exc:  # EIO: no host has the device open
                    if exc.errno != errno.EIO:
                        raise
                    received = b""
                with self._lock:
                    out = self.system.step(received)
                if out:
                    try:
                        os.write(fd, out)
                    except (BlockingIOError, OSError):
                        self.pty_drops += len(out)
                next_wall += dt
                delay = next_wall - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
                elif delay < -0.1:  # far behind (a stall): catch up no further
                    self.late_steps += 1
                    next_wall = time.monotonic()
        except BaseException as exc:  # ends the target; alive() tells the runner
            self._error = exc
            logger.exception("the ATmega2560 step loop failed")

    def _close_emulator(self) -> None:
        stop = getattr(self, "_stop", None)
        if stop is not None:
            stop.set()
            self._thread.join(10)
        pty_pair = getattr(self, "_pty", None)
        if pty_pair is not None:
            pty_pair.close()
        system = getattr(self, "system", None)
        if system is not None:
            system.close()

    def time_s(self) -> float:
        return self.system.plant.twin.time_s

    def ground_travel_m(self) -> float:
        with self._lock:
            return self.system.plant.travel_m

    def pose(self, view: PortView) -> tuple[float, float, float]:
        p = self.system.plant.twin.pose
        return p.x_m, p.y_m, p.yaw_deg

    def _apply(self, spec: FaultSpec) -> None:
        apply_fault(self.system, spec)

    def _read_port(self) -> tuple[PortView, PilStats]:
        return self.system.view()


class AvrLockstep:
    """The ATmega2560 and its twin on a lockstep clock: one plant step per tick, USART0 on
    an in-memory line (the controller's raw end of :func:`memory_line`).

    Every byte both ways is hashed (:attr:`digest`, in the order and the tick it crossed),
    so that two runs from one seed can be compared.
    """

    def __init__(self, system: AvrSystem, port: MemoryPort, clock: LockstepClock) -> None:
        if abs(clock.dt_s - system.plant.twin.dt_s) > 1e-12:
            raise ValueError("the clock's tick must be the twin's time step")
        self.system = system
        self.port = port
        self.clock = clock
        self._hash = hashlib.sha256()
        self._opened = False
        self.ticks = 0

    def open(self, boot_s: float = 0.05) -> AvrLockstep:
        """Tick from now on, and run ``boot_s`` of it, so the MCU has booted (USART
        receiving, IDENT out) before the host starts."""
        self._opened = True
        self.clock.add(self.tick)
        self.clock.advance(max(0, round(boot_s / self.clock.dt_s)))
        return self

    def close(self) -> None:
        """Later ticks do nothing; the simulator is freed (idempotent)."""
        self._opened = False
        self.system.close()

    def tick(self) -> None:
        """One plant step with what the host wrote."""
        if not self._opened:
            return
        received = self.port.read(0)
        out = self.system.step(received)
        if received:
            self._hash.update(b"H%d:" % self.ticks + received)
        if out:
            self._hash.update(b"C%d:" % self.ticks + out)
            self.port.write(out)
        self.ticks += 1

    def inject(self, fault: str) -> dict[str, Any]:
        """The control port's ``inject`` (reboot, stall, slip, encoder-dropout, clear:)."""
        spec = parse_fault(fault)
        apply_fault(self.system, spec)
        kind = spec.target if spec.kind == "clear" else spec.kind
        if kind == "encoder-dropout":
            # Answer once the firmware has taken it, as PilTarget._settle does.
            want = any(self.system.plant.encoders.dropout)
            bit = 1 << (FaultCode.ENCODER.value - 1)
            for _ in range(1000):
                if bool(self.system.view()[0].faults & bit) == want:
                    break
                self.clock.advance(1)
            else:
                raise PilError(f"the firmware did not follow {fault} within 1 s")
        return {"ok": True, "fault": fault, "t": round(self.system.plant.twin.time_s, 6)}

    @property
    def digest(self) -> str:
        """SHA-256 of the wire traffic so far, both directions, with their ticks."""
        return self._hash.hexdigest()


def avr_lockstep_pair(
    system: AvrSystem,
) -> tuple[AvrLockstep, Endpoint, LockstepClock]:
    """``system`` in lockstep on an in-memory serial line: ``(MCU side, host endpoint,
    clock)``; open the first, then a ``ProtocolHost`` on the endpoint and the clock."""
    clock = LockstepClock(system.plant.twin.dt_s)
    host_port, mcu_port = memory_line(f"pil-avr-{next(_lines)}")
    host_end = SerialEndpoint(HOST, lambda: host_port, name=host_port.name)
    return AvrLockstep(system, mcu_port, clock), host_end, clock
