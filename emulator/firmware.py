"""The C firmware core in the loop: :class:`FirmwareController` runs the motor
controller of ``firmware_proto/wire/c/fw/`` (a host shared library) behind the
:class:`~emulator.controller.ControllerModel` interface, over the same twin (what is
firmware and what is plant: docs/firmware.md, "Firmware in the loop").

Both directions go through the C codec as serial frames; a tick is ``fw_control`` at
twin time ``t``, one twin step, then ``fw_sense`` at ``t + dt``. :func:`build_library`
caches the library by content hash in ``$ROVER_FIRMWARE_CACHE``, else
``$XDG_CACHE_HOME/rover/firmware``, else ``~/.cache/rover/firmware``;
``ROVER_FIRMWARE_SANITIZE=1`` builds with ASan and UBSan, which needs ``libasan``
preloaded (:func:`sanitizer_env`).
"""

from __future__ import annotations

import contextlib
import ctypes
import logging
import math
import os
import subprocess
import threading
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any, Generic, TypeVar, overload

from emulator.controller import ControllerConfig, ControllerModel, LatchCause
from emulator.drive import motor_omegas
from emulator.errors import FirmwareBuildError
from emulator.sensors import PoseMeasurement, wrap_count
from emulator.sharedlib import WARNINGS, build_shared_library, compiler
from emulator.twin import Twin
from firmware_proto.model.rover import RoverDescription
from firmware_proto.wire.framing import FrameDecoder, FrameEncoder
from firmware_proto.wire.message import Message
from firmware_proto.wire.messages import PROTOCOL_VERSION, SCHEMA_HASH

__all__ = [
    "C_DIR",
    "FIRMWARES",
    "SANITIZE_ENV",
    "FirmwareController",
    "build_library",
    "make_controller",
    "sanitizer_env",
]

logger = logging.getLogger(__name__)

C_DIR = Path(__file__).resolve().parents[1] / "firmware_proto" / "wire" / "c"
"""The C codec; the firmware core is in its ``fw/`` folder."""
SOURCES = ("fw/fw.c", "fw/port_host.c", "rover_msgs.c", "rover_proto.c")
HEADERS = ("fw/fw.h", "fw/fw_hal.h", "rover_msgs.h", "rover_proto.h")
OPTIMISE = ("-O2",)
SANITIZE = (
    "-g",
    "-O1",
    "-fno-omit-frame-pointer",
    "-fsanitize=address,undefined",
    "-fno-sanitize-recover=all",
)
SANITIZE_ENV = "ROVER_FIRMWARE_SANITIZE"
"""``1``: :func:`build_library` builds (and loads) the sanitizer build by default."""
FIRMWARES = ("python", "c")
"""The controller implementations ``--firmware`` chooses between."""
_OUT_CAP = 8192
_LOCK = threading.Lock()
_LIBS: dict[Path, ctypes.CDLL] = {}


# -- build --------------------------------------------------------------------------------
def _compiler() -> str:
    return compiler(
        error=FirmwareBuildError,
        hint="the C firmware needs one to build (apt-get install gcc libc6-dev), "
        "or run with --firmware python",
    )


def build_library(*, sanitize: bool | None = None, timeout_s: float = 120.0) -> Path:
    """The host build of the firmware core as a shared library (cached by content hash:
    :mod:`emulator.sharedlib`).

    Args:
        sanitize: build with ASan and UBSan; ``None``: ``$ROVER_FIRMWARE_SANITIZE == "1"``.
        timeout_s: compiler time limit, s.

    Raises:
        FirmwareBuildError: no compiler, or the build failed (its output is in the message).
    """
    if sanitize is None:
        sanitize = os.environ.get(SANITIZE_ENV) == "1"
    target = build_shared_library(
        "rover_fw",
        C_DIR,
        SOURCES,
        HEADERS,
        [*WARNINGS, *(SANITIZE if sanitize else OPTIMISE)],
        cc=_compiler(),
        error=FirmwareBuildError,
        suffix="-san" if sanitize else "",
        timeout_s=timeout_s,
    )
    logger.debug("the C firmware core: %s", target)
    return target


def sanitizer_env(base: dict[str, str] | None = None) -> dict[str, str]:
    """The environment for a child Python process that loads the sanitizer build: libasan
    preloaded, leak detection off (the interpreter's leaks are not ours), errors fatal."""
    cc = _compiler()
    asan = subprocess.run(
        [cc, "-print-file-name=libasan.so"], capture_output=True, text=True, check=True
    ).stdout.strip()
    env = dict(os.environ if base is None else base)
    env.update(
        {
            SANITIZE_ENV: "1",
            "LD_PRELOAD": asan,
            "ASAN_OPTIONS": "detect_leaks=0:halt_on_error=1:abort_on_error=1",
            "UBSAN_OPTIONS": "halt_on_error=1:print_stacktrace=1",
        }
    )
    return env


# -- ABI ----------------------------------------------------------------------------------
class _Config(ctypes.Structure):
    """``fw_config_t`` (fw.h), field for field."""

    _fields_ = [
        ("fw_major", ctypes.c_uint8),
        ("fw_minor", ctypes.c_uint8),
        ("fw_patch", ctypes.c_uint8),
        ("protocol_version", ctypes.c_uint8),
        ("schema_hash", ctypes.c_uint16),
        ("transport", ctypes.c_uint8),
        ("can_node", ctypes.c_uint8),
        ("queue_depth", ctypes.c_uint8),
        ("left_sign", ctypes.c_int8),
        ("right_sign", ctypes.c_int8),
        ("watchdog_ms", ctypes.c_uint16),
        ("telemetry_hz", ctypes.c_uint8),
        ("pose_hz", ctypes.c_uint8),
        ("heartbeat_hz", ctypes.c_uint8),
        ("stall_timeout_ms", ctypes.c_uint16),
        ("timeout_scale_permille", ctypes.c_uint32),
        ("tick_us", ctypes.c_uint32),
        ("distance_units_per_m", ctypes.c_uint32),
        ("speed_um_s_per_unit", ctypes.c_uint32),
        ("accel_um_s2", ctypes.c_uint32),
        ("max_speed", ctypes.c_uint8),
        ("max_distance", ctypes.c_uint16),
    ]


class _Status(ctypes.Structure):
    """``fw_host_status_t`` (port_host.c)."""

    _fields_ = [
        ("state", ctypes.c_uint8),
        ("handshake_ok", ctypes.c_uint8),
        ("latch", ctypes.c_uint8),
        ("faults", ctypes.c_uint8),
        ("queue_depth", ctypes.c_uint8),
        ("running", ctypes.c_uint8),
        ("boot_nonce", ctypes.c_uint16),
        ("running_seq", ctypes.c_uint16),
        ("watchdog_ms", ctypes.c_uint16),
        ("telemetry_hz", ctypes.c_uint8),
        ("pose_hz", ctypes.c_uint8),
        ("heartbeat_hz", ctypes.c_uint8),
        ("latch_gen", ctypes.c_uint8),
        ("rx_errors", ctypes.c_uint32),
        ("setpoint", ctypes.c_int32 * 2),
        ("commanded", ctypes.c_int32 * 2),
    ]


class _Imu(ctypes.Structure):
    _fields_ = [
        ("yaw_rate_mrad_s", ctypes.c_int16),
        ("accel_x_mm_s2", ctypes.c_int16),
        ("accel_y_mm_s2", ctypes.c_int16),
    ]


class _Pose(ctypes.Structure):
    _fields_ = [
        ("x_mm", ctypes.c_int32),
        ("y_mm", ctypes.c_int32),
        ("yaw_ddeg", ctypes.c_int16),
        ("sigma_cm", ctypes.c_uint8),
        ("taken_us", ctypes.c_uint64),
    ]


_IMU_CB = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.POINTER(_Imu))
_POSE_SAMPLE_CB = ctypes.CFUNCTYPE(None)
_POSE_READ_CB = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.POINTER(_Pose))
_NONCE_CB = ctypes.CFUNCTYPE(ctypes.c_uint16)
_I32x2 = ctypes.c_int32 * 2


def _load(path: Path) -> ctypes.CDLL:
    with _LOCK:
        lib = _LIBS.get(path)
        if lib is not None:
            return lib
        lib = ctypes.CDLL(str(path))
        vp, u64, u32, u8, sz = (
            ctypes.c_void_p,
            ctypes.c_uint64,
            ctypes.c_uint32,
            ctypes.c_uint8,
            ctypes.c_size_t,
        )
        sigs: dict[str, tuple[Any, list[Any]]] = {
            "fw_host_sizeof_config": (sz, []),
            "fw_host_default_config": (None, [ctypes.POINTER(_Config)]),
            "fw_host_new": (
                vp,
                [
                    ctypes.POINTER(_Config),
                    _IMU_CB,
                    _POSE_SAMPLE_CB,
                    _POSE_READ_CB,
                    _NONCE_CB,
                    _I32x2,
                    _I32x2,
                    u64,
                    ctypes.POINTER(ctypes.c_int),
                ],
            ),
            "fw_host_error_name": (ctypes.c_char_p, [ctypes.c_int]),
            "fw_host_free": (None, [vp]),
            "fw_host_set_sensors": (None, [vp, _I32x2, _I32x2]),
            "fw_host_rx": (None, [vp, u64, ctypes.c_char_p, sz]),
            "fw_host_control": (None, [vp, u64]),
            "fw_host_sense": (None, [vp, u64]),
            "fw_host_reboot": (None, [vp, u64]),
            "fw_host_raise_fault": (None, [vp, u64, u8, u32, ctypes.c_int]),
            "fw_host_clear_fault": (None, [vp, u8]),
            "fw_host_add_rx_errors": (None, [vp, u32]),
            "fw_host_wheels": (None, [vp, _I32x2]),
            "fw_host_take": (sz, [vp, ctypes.c_char_p, sz]),
            "fw_host_out_dropped": (u32, [vp]),
            "fw_host_status": (None, [vp, ctypes.POINTER(_Status)]),
        }
        for name, (restype, argtypes) in sigs.items():
            fn = getattr(lib, name)
            fn.restype = restype
            fn.argtypes = argtypes
        if lib.fw_host_sizeof_config() != ctypes.sizeof(_Config):
            raise FirmwareBuildError("fw_config_t and its ctypes mirror differ in size")
        _LIBS[path] = lib
        return lib


def _exact_int(value: float, what: str) -> int:
    n = round(value)
    if n <= 0 or not math.isclose(n, value, rel_tol=1e-9, abs_tol=1e-9):
        raise FirmwareBuildError(f"the C firmware needs {what} as a whole number, got {value}")
    return n


def _clamp16(value: float) -> int:
    return max(-32768, min(32767, round(value)))


_V = TypeVar("_V")

_LATCH_BITS = ((1, LatchCause.STOP), (2, LatchCause.WATCHDOG), (4, LatchCause.FAULT))
"""The ``latch`` bits of ``fw_status_t`` and the causes they stand for."""


class _CoreField(Generic[_V]):
    """A :class:`FirmwareController` attribute read from the C core's status at each read;
    an assignment is ignored (the base class's code assigns what the core holds).

    ``before_init``: the value read before the core exists (``None``: read it anyway).
    """

    def __init__(self, read: Callable[[_Status], _V], before_init: _V | None = None) -> None:
        self._read = read
        self._before_init = before_init

    @overload
    def __get__(self, obj: None, owner: type) -> _CoreField[_V]: ...
    @overload
    def __get__(self, obj: FirmwareController, owner: type) -> _V: ...
    def __get__(self, obj: FirmwareController | None, owner: type) -> _CoreField[_V] | _V:
        if obj is None:
            return self
        if self._before_init is not None and obj._h is None:
            return self._before_init
        return self._read(obj._st())

    def __set__(self, obj: FirmwareController, value: _V) -> None:
        pass


# -- the controller -----------------------------------------------------------------------
class FirmwareController(ControllerModel):
    """The C firmware core behind the :class:`ControllerModel` interface.

    The controller logic and state live in C (the properties read it); the plant, sensor
    models and configuration are the base class's, so fault injection works unchanged.
    Not thread-safe: one thread calls :meth:`handle` and :meth:`tick`.
    """

    def __init__(
        self,
        rover: RoverDescription,
        twin: Twin,
        config: ControllerConfig | None = None,
        *,
        seed: int = 0,
        protocol_version: int = PROTOCOL_VERSION,
        schema_hash: int = SCHEMA_HASH,
        library: Path | None = None,
    ) -> None:
        """Args as :class:`ControllerModel`, and:
        library: the shared library (default: :func:`build_library`).

        Raises:
            FirmwareBuildError: no compiler, a failed build, or a rover or time step the
                integer core cannot represent (whole um/s, um/s^2 and us) or that
                ``fw_init`` refuses (its ``fw_error_t`` named).
        """
        self._lib = _load(library or build_library())
        self._h: int | None = None
        self._tick_us = _exact_int(twin.dt_s * 1e6, "the time step in microseconds")
        self._encoder = FrameEncoder()
        self._decoder = FrameDecoder()
        self._buf = ctypes.create_string_buffer(_OUT_CAP)
        self._wheels = _I32x2()
        """What ``fw_host_wheels`` writes each tick (read at once)."""
        self._enc = _I32x2()
        self._speed = _I32x2()
        """What :meth:`_push_sensors` hands the core (it copies them)."""
        self._pose_due: deque[PoseMeasurement] = deque()
        self._status = _Status()
        self.frame_seqs: list[int] = []
        """The serial frame counter of each frame the core wrote in the last call (its own
        framing, as on hardware; the emulator's front end numbers frames itself)."""
        # The callbacks must outlive the library's use of them.
        self._cb_imu = _IMU_CB(self._read_imu)
        self._cb_pose_sample = _POSE_SAMPLE_CB(self._pose_sample)
        self._cb_pose_read = _POSE_READ_CB(self._pose_read)
        self._cb_nonce = _NONCE_CB(self._nonce)
        super().__init__(
            rover,
            twin,
            config,
            seed=seed,
            protocol_version=protocol_version,
            schema_hash=schema_hash,
        )

    # -- set-up ----------------------------------------------------------------------------
    def _c_config(self) -> _Config:
        cfg = _Config()
        self._lib.fw_host_default_config(ctypes.byref(cfg))
        c, rover, d = self.config, self.rover, self.rover.drive
        cfg.fw_major, cfg.fw_minor, cfg.fw_patch = c.firmware_version
        cfg.protocol_version = self.protocol_version
        cfg.schema_hash = self.schema_hash
        cfg.queue_depth = c.queue_depth
        cfg.left_sign, cfg.right_sign = d.left_wheel_sign, d.right_wheel_sign
        cfg.watchdog_ms = c.watchdog_ms
        cfg.telemetry_hz, cfg.pose_hz, cfg.heartbeat_hz = c.telemetry_hz, c.pose_hz, c.heartbeat_hz
        cfg.stall_timeout_ms = c.stall_timeout_ms
        cfg.timeout_scale_permille = max(1, round(c.timeout_scale * 1000.0))
        cfg.tick_us = self._tick_us
        cfg.distance_units_per_m = d.distance_units_per_m
        cfg.speed_um_s_per_unit = _exact_int(
            rover.speed_to_mps(1) * 1e6, "the speed of one speed unit in um/s"
        )
        cfg.accel_um_s2 = _exact_int(d.wheel_accel_limit_mps2 * 1e6, "the acceleration in um/s^2")
        cfg.max_speed, cfg.max_distance = d.max_speed, d.max_distance
        return cfg

    def _init_params(self) -> None:
        """Parameters live in the core (reset by its boot)."""

    def _init_state(self) -> None:
        if self._h is not None:
            return
        self._pose_due.clear()
        enc, speed = self._sensors()
        error = ctypes.c_int(0)
        handle = self._lib.fw_host_new(
            ctypes.byref(self._c_config()),
            self._cb_imu,
            self._cb_pose_sample,
            self._cb_pose_read,
            self._cb_nonce,
            enc,
            speed,
            self._now_us(),
            ctypes.byref(error),
        )
        if error.value:
            name = self._lib.fw_host_error_name(error.value).decode()
            raise FirmwareBuildError(f"the C core refuses this rover or time step: {name}")
        if not handle:
            raise MemoryError("fw_host_new")
        self._h = handle
        self.boot_s = self.twin.time_s

    def close(self) -> None:
        """Free the core (idempotent); also done when the object is collected."""
        if self._h is not None:
            self._lib.fw_host_free(self._h)
            self._h = None

    def __del__(self) -> None:
        with contextlib.suppress(Exception):  # interpreter shutdown: the library may be gone
            self.close()

    # -- plant -> HAL -----------------------------------------------------------------------
    def _now_us(self) -> int:
        return self.twin.steps * self._tick_us

    def _sensor_values(self) -> tuple[int, int, int, int]:
        """Encoder counts and wheel speeds (um/s, truncated), motor frame: left and right
        counts, left and right speeds."""
        d = self.rover.drive
        left, right = self.encoders.counts()
        vl, vr = self.twin.wheel_surface_speeds_mps
        # The motor frame's counter wraps like the rover frame's (-(-2**31) is -2**31).
        return (
            int(wrap_count(d.left_wheel_sign * left)),
            int(wrap_count(d.right_wheel_sign * right)),
            int(d.left_wheel_sign * vl * 1e6),
            int(d.right_wheel_sign * vr * 1e6),
        )

    def _sensors(self) -> tuple[Any, Any]:
        """:meth:`_sensor_values` as the two arrays the core takes (counts, speeds)."""
        enc_l, enc_r, speed_l, speed_r = self._sensor_values()
        return _I32x2(enc_l, enc_r), _I32x2(speed_l, speed_r)

    def _push_sensors(self) -> None:
        # Twice a tick: into arrays kept for it (fw_host_set_sensors copies the values).
        enc, speed = self._enc, self._speed
        enc[0], enc[1], speed[0], speed[1] = self._sensor_values()
        self._lib.fw_host_set_sensors(self._h, enc, speed)

    def _read_imu(self, out: Any) -> int:
        reading = self.imu.read()
        if reading is None:
            return 0
        out[0].yaw_rate_mrad_s = _clamp16(reading.yaw_rate_rad_s * 1000.0)
        out[0].accel_x_mm_s2 = _clamp16(reading.accel_x_mps2 * 1000.0)
        out[0].accel_y_mm_s2 = _clamp16(reading.accel_y_mps2 * 1000.0)
        return 1

    def _pose_sample(self) -> None:
        self.pose_sensor.sample()

    def _pose_read(self, out: Any) -> int:
        if not self._pose_due:
            self._pose_due.extend(self.pose_sensor.due())
            if not self._pose_due:
                return 0
        m = self._pose_due.popleft()
        msg = self._pose_message(m.pose.x_m, m.pose.y_m, m.pose.yaw_rad, m.sigma_m, 0.0)
        out[0].x_mm, out[0].y_mm = msg.x_mm, msg.y_mm
        out[0].yaw_ddeg, out[0].sigma_cm = msg.yaw_ddeg, msg.sigma_cm
        out[0].taken_us = round(m.taken_s / self.twin.dt_s) * self._tick_us
        return 1

    def _nonce(self) -> int:
        return self._rng.randrange(1 << 16)

    # -- core -> messages --------------------------------------------------------------------
    def _drain(self) -> list[Message]:
        out: list[Message] = []
        seqs: list[int] = []
        while True:
            n = self._lib.fw_host_take(self._h, self._buf, _OUT_CAP)
            if not n:
                break
            # string_at copies the n bytes written (``raw`` would copy the whole buffer).
            for frame in self._decoder.feed(ctypes.string_at(self._buf, n)):
                out.append(frame.message)
                seqs.append(frame.seq)
        self.frame_seqs = seqs
        if self._decoder.counters.rejected:
            raise RuntimeError(f"the C core wrote bad frames: {self._decoder.counters}")
        return out

    def _st(self) -> _Status:
        self._lib.fw_host_status(self._h, ctypes.byref(self._status))
        return self._status

    # -- the ControllerModel interface --------------------------------------------------------
    # The base class's state, read from the C core's status; the base class's own
    # assignments to them (its __init__, a reboot) are ignored: the core holds the state.
    state = _CoreField(lambda s: int(s.state))
    """The :class:`ControllerState` code."""
    handshake_ok = _CoreField(lambda s: bool(s.handshake_ok))
    """A matching HELLO opened the session."""
    boot_nonce = _CoreField(lambda s: int(s.boot_nonce))
    """The nonce of this boot (IDENT, HEARTBEAT)."""
    latch_gen = _CoreField(lambda s: int(s.latch_gen))
    """The latch generation (HEARTBEAT ``latch_gen``)."""
    latch_causes = _CoreField(lambda s: {cause for bit, cause in _LATCH_BITS if s.latch & bit})
    """What set the latch since the last CLEARED (empty: not latched)."""
    faults = _CoreField(lambda s: {code for code in range(1, 9) if s.faults & (1 << (code - 1))})
    """Fault codes whose condition is active now."""
    rx_errors = _CoreField(lambda s: int(s.rx_errors), before_init=0)
    """Bad frames counted (HEARTBEAT ``rx_errors`` before its 16-bit wrap)."""
    watchdog_ms = _CoreField(lambda s: int(s.watchdog_ms))
    """The WATCHDOG_MS parameter in force."""
    telemetry_hz = _CoreField(lambda s: int(s.telemetry_hz))
    """The TELEMETRY_HZ parameter in force."""
    pose_hz = _CoreField(lambda s: int(s.pose_hz))
    """The POSE_HZ parameter in force."""
    heartbeat_hz = _CoreField(lambda s: int(s.heartbeat_hz))
    """The HEARTBEAT_HZ parameter in force."""

    @property
    def queue_depth(self) -> int:
        """Steps queued, the running one included."""
        return int(self._st().queue_depth)

    @property
    def wheel_setpoints_mps(self) -> tuple[float, float]:
        """Wheel speed targets (rover frame): zero from the moment a STOP is handled."""
        s = self._st()
        return s.setpoint[0] / 1e6, s.setpoint[1] / 1e6

    @property
    def wheel_commands_mps(self) -> tuple[float, float]:
        """Speeds commanded to the motors: the setpoints, ramped at the accel limit."""
        s = self._st()
        return s.commanded[0] / 1e6, s.commanded[1] / 1e6

    @property
    def running_seq(self) -> int | None:
        """Sequence number of the step being executed, if any."""
        s = self._st()
        return int(s.running_seq) if s.running else None

    @property
    def at_rest(self) -> bool:
        """Both sides commanded to zero and measured at rest."""
        left, right = self.twin.wheel_surface_speeds_mps
        s = self._st()
        return (
            s.commanded[0] == 0 and s.commanded[1] == 0 and abs(left) < 1e-4 and abs(right) < 1e-4
        )

    def boot(self) -> list[Message]:
        """Power-on: the IDENT the core sent when it was created."""
        self.boots += 1
        logger.info("C firmware boot %d, nonce 0x%04X", self.boots, self.boot_nonce)
        return self._drain()

    def reboot(self) -> list[Message]:
        """A reset of the core: everything but the rx_errors count is lost; IDENT."""
        self.encoders.reset()
        self.pose_sensor.clear()
        self._pose_due.clear()
        self._push_sensors()
        self._lib.fw_host_reboot(self._h, self._now_us())
        self.boot_s = self.twin.time_s
        self.boots += 1
        return self._drain()

    def rx_error(self, count: int = 1) -> None:
        """The front end dropped ``count`` bad frames (reported in HEARTBEAT)."""
        self._lib.fw_host_add_rx_errors(self._h, count)

    def handle(self, msg: Message) -> list[Message]:
        """Deliver one message as its serial frame to ``fw_on_bytes``; the answers."""
        wire = self._encoder.encode(msg, strict=False)
        self._lib.fw_host_rx(self._h, self._now_us(), wire, len(wire))
        return self._drain()

    def raise_fault(self, code: int, detail: int = 0, *, condition: bool = False) -> list[Message]:
        """As :meth:`ControllerModel.raise_fault`, in the core (``fw_raise_fault``)."""
        self._lib.fw_host_raise_fault(
            self._h, self._now_us(), code, max(0, min(detail, 0xFFFFFFFF)), int(condition)
        )
        return self._drain()

    def clear_fault_condition(self, code: int) -> list[Message]:
        """As :meth:`ControllerModel.clear_fault_condition` (``fw_clear_fault``)."""
        self._lib.fw_host_clear_fault(self._h, code)
        return self._drain()

    def tick(self) -> list[Message]:
        """``fw_control``, a twin step on the core's commands, ``fw_sense``: sensors pushed
        before each, so the HAL reads the plant as it is now."""
        lib, h = self._lib, self._h
        self._push_sensors()
        lib.fw_host_control(h, self._now_us())
        wheels = self._wheels
        lib.fw_host_wheels(h, wheels)
        d = self.rover.drive
        # Polarity undone (exactly) so the twin gets the Python model's conversion.
        left_mps = d.left_wheel_sign * wheels[0] / 1e6
        right_mps = d.right_wheel_sign * wheels[1] / 1e6
        self.twin.set_motor_omegas(*motor_omegas(self.rover, left_mps, right_mps))
        self.twin.step()
        self._push_sensors()
        lib.fw_host_sense(h, self._now_us())
        return self._drain()


def make_controller(
    firmware: str,
    rover: RoverDescription,
    twin: Twin,
    config: ControllerConfig | None = None,
    **kwargs: Any,
) -> ControllerModel:
    """The controller ``--firmware`` names: ``python`` (:class:`ControllerModel`) or ``c``
    (:class:`FirmwareController`); ``kwargs`` as their constructors take.

    Raises:
        ValueError: an unknown name (the message lists the known ones).
        FirmwareBuildError: ``c`` and the core cannot be built here.
    """
    if firmware == "python":
        return ControllerModel(rover, twin, config, **kwargs)
    if firmware == "c":
        return FirmwareController(rover, twin, config, **kwargs)
    raise ValueError(f"unknown firmware {firmware!r}; known: {', '.join(FIRMWARES)}")
