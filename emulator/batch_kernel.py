"""The batch twins' traction forces in C (``batch_kernel.c``): :func:`play`, the whole
replay loop of :func:`emulator.moves.play_moves`, and :class:`Forces`, one physics
step's forces for :func:`emulator.batch.play_batch`'s twins.

numpy pays its call overhead about 150 times a physics step whatever the number of twins;
a calibration replays a few dozen at once and the gate's uncertainty a few hundred, so
that overhead was most of their time. The kernel computes each twin alone, with the same
operations in the same order as ``emulator.batch._Forces``, so the two agree to the
last bits of ``tanh``, ``sin`` and ``cos`` (numpy's ``tanh`` is its own, not libm's), to
1e-12 m and 1e-9 m with the same collision and rest ticks (``tests/emulator/test_moves.py``,
``tests/emulator/test_batch_kernel.py``; figures in docs/twin.md, "Batch replays"). Built
on first use with the host's C compiler and cached (:mod:`emulator.sharedlib`);
:func:`choose` falls back to numpy, said once in the log, where it cannot be (no
compiler, no writable cache, a failed build: kept, not tried again).
"""

from __future__ import annotations

import ctypes
import logging
import threading
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from emulator.errors import NativeBuildError, TwinConfigError
from emulator.sharedlib import WARNINGS, build_shared_library, compiler

__all__ = ["KERNELS", "ForceParameters", "Forces", "Prepared", "build", "choose", "load", "play"]

_Edges = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]


class ForceParameters(Protocol):
    """What :class:`Prepared` reads of a batch's numpy forces (``emulator.batch._Forces``,
    which imports this module): the model's constants, each twin's ground (arrays of one
    value per twin; ``side``: ``(4, n)``, a factor per wheel FL, RL, FR, RR;
    ``region_scales``: ``(n, regions)``) and the regions' convex parts as edges."""

    hx: float
    hy: float
    mass: float
    inertia: float
    inv_vrr: float
    wheel_x: np.ndarray
    wheel_y: np.ndarray
    s0: np.ndarray
    kappa: np.ndarray
    rr: np.ndarray
    mu_long_n: np.ndarray
    mu_lat_n: np.ndarray
    side: np.ndarray
    region_scales: np.ndarray
    parts: list[list[_Edges]]


logger = logging.getLogger(__name__)

KERNELS = ("auto", "c", "numpy")
"""What the batch twins' forces are computed with: ``auto`` (the C kernel where it
builds, else numpy), ``c`` (the kernel, or :class:`NativeBuildError`), ``numpy``."""

_C_DIR = Path(__file__).resolve().parent
_SOURCES = ("batch_kernel.c",)
_FLAGS = (
    *WARNINGS,
    "-O2",
    "-ffp-contract=off",  # no fused multiply-adds: numpy's roundings, step by step
)
_LOCK = threading.Lock()
_LIB: list[ctypes.CDLL] = []
_FAILED: list[NativeBuildError] = []
_said_numpy: list[str] = []

_D = ctypes.POINTER(ctypes.c_double)
_I32 = ctypes.POINTER(ctypes.c_int32)
_I64 = ctypes.POINTER(ctypes.c_int64)


class _Model(ctypes.Structure):
    """``batch_model_t``, field for field."""

    _fields_ = [
        ("hx", ctypes.c_double),
        ("hy", ctypes.c_double),
        ("mass", ctypes.c_double),
        ("inertia", ctypes.c_double),
        ("inv_mass", ctypes.c_double),
        ("inv_inertia", ctypes.c_double),
        ("inv_vrr", ctypes.c_double),
        ("dt", ctypes.c_double),
        ("probe", ctypes.c_double),
        ("wheel_x", ctypes.c_double * 4),
        ("wheel_y", ctypes.c_double * 4),
    ]


class _Grounds(ctypes.Structure):
    """``batch_grounds_t``."""

    _fields_ = [
        (name, _D)
        for name in ("s0", "kappa", "rr", "mu_long_n", "mu_lat_n", "side", "region_scales")
    ]


class _Regions(ctypes.Structure):
    """``batch_regions_t``."""

    _fields_ = [
        ("regions", ctypes.c_int32),
        ("parts", ctypes.c_int32),
        ("part_region", _I32),
        ("part_edge", _I32),
        ("edges", _D),
    ]


def build(timeout_s: float = 120.0) -> Path:
    """The kernel as a shared library, built if it is not cached yet.

    Raises:
        NativeBuildError: no C compiler, or the build failed (its output is in the message).
    """
    return build_shared_library(
        "rover_batch",
        _C_DIR,
        _SOURCES,
        (),
        _FLAGS,
        cc=compiler(
            error=NativeBuildError,
            hint="the batch twins' C kernel needs one (apt-get install gcc libc6-dev); "
            "kernel='numpy' needs none",
        ),
        error=NativeBuildError,
        libs=("-lm",),
        timeout_s=timeout_s,
    )


def load() -> ctypes.CDLL:
    """The kernel, built and loaded once per process; a failure is kept and raised again
    (no second build).

    Raises:
        NativeBuildError: it cannot be built or loaded here.
    """
    with _LOCK:
        if _FAILED:
            raise _FAILED[0]
        if not _LIB:
            try:
                path = build()
                try:
                    lib = ctypes.CDLL(str(path))
                except OSError as exc:
                    raise NativeBuildError(f"cannot load {path}: {exc}") from exc
            except NativeBuildError as exc:
                _FAILED.append(exc)
                raise
            fn = lib.rover_play_moves
            fn.restype = ctypes.c_int
            fn.argtypes = [
                ctypes.POINTER(_Model),
                ctypes.POINTER(_Grounds),
                ctypes.POINTER(_Regions),
                ctypes.c_int64,
                _D,
                _D,
                _I64,
                _I64,
                _I64,
                _D,
            ]
            fn = lib.rover_batch_forces
            fn.restype = None
            fn.argtypes = [
                ctypes.POINTER(_Model),
                ctypes.POINTER(_Grounds),
                ctypes.POINTER(_Regions),
                ctypes.c_int64,
                ctypes.c_void_p,
                _D,
                ctypes.c_double,
                ctypes.c_double,
                _D,
            ]
            _LIB.append(lib)
        return _LIB[0]


def choose(kernel: str) -> ctypes.CDLL | None:
    """The library for ``kernel`` (one of :data:`KERNELS`), or ``None`` for numpy: for
    ``auto``, where it cannot be built or loaded (said once per process in the log).

    Raises:
        TwinConfigError: ``kernel`` is not one of :data:`KERNELS`.
        NativeBuildError: ``kernel == "c"`` and it cannot be built or loaded here.
    """
    if kernel not in KERNELS:
        raise TwinConfigError(f"kernel must be one of {KERNELS}, got {kernel!r}")
    if kernel == "numpy":
        return None
    try:
        return load()
    except NativeBuildError as exc:
        if kernel == "c":
            raise
        if not _said_numpy:
            _said_numpy.append(str(exc))
            first, _, rest = str(exc).partition("\n")
            logger.warning("batch twins in numpy, not the C kernel: %s", first)
            if rest:
                logger.debug("the kernel's build said:\n%s", rest)
        return None


def _f64(values: Any) -> np.ndarray:
    return np.ascontiguousarray(values, dtype=np.float64)


class Prepared:
    """The C structures of one batch: the rover, the step, each twin's ground and the
    map's traction regions (kept alive with the arrays they point into).

    Args:
        forces: the batch's numpy forces (one twin per draw, in order): its parameters.
        dt_s: physics step, s.
        probe_m: a wheel is on a region when its contact is within this of it, m.
        inv_mass, inv_inertia: of the rigid body, 1/kg and 1/(kg m^2), for :func:`play`
            (pymunk integrates :class:`Forces`'s twins).
    """

    def __init__(
        self,
        forces: ForceParameters,
        *,
        dt_s: float,
        probe_m: float,
        inv_mass: float = 0.0,
        inv_inertia: float = 0.0,
    ) -> None:
        self._keep: list[np.ndarray] = []
        self.model = _Model(
            hx=forces.hx,
            hy=forces.hy,
            mass=forces.mass,
            inertia=forces.inertia,
            inv_mass=inv_mass,
            inv_inertia=inv_inertia,
            inv_vrr=forces.inv_vrr,
            dt=dt_s,
            probe=probe_m,
            wheel_x=(ctypes.c_double * 4)(*forces.wheel_x[:, 0]),
            wheel_y=(ctypes.c_double * 4)(*forces.wheel_y[:, 0]),
        )
        self.grounds = _Grounds(
            self.pointer(_f64(forces.s0)),
            self.pointer(_f64(forces.kappa)),
            self.pointer(_f64(forces.rr)),
            self.pointer(_f64(forces.mu_long_n)),
            self.pointer(_f64(forces.mu_lat_n)),
            self.pointer(_f64(forces.side[[0, 2], :].T)),
            self.pointer(_f64(forces.region_scales)),
        )
        part_region: list[int] = []
        part_edge = [0]
        edges: list[np.ndarray] = []
        for r_index, parts in enumerate(forces.parts):
            for px, py, dx, dy in parts:
                part_region.append(r_index)
                edges.append(np.hstack([px, py, dx, dy]))
                part_edge.append(part_edge[-1] + len(px))
        self.regions = _Regions(
            len(forces.parts),
            len(part_region),
            self.pointer(np.array(part_region or [0], dtype=np.int32), _I32),
            self.pointer(np.array(part_edge, dtype=np.int32), _I32),
            self.pointer(_f64(np.vstack(edges) if edges else np.zeros((1, 4)))),
        )

    def pointer(self, array: np.ndarray, kind: Any = _D) -> Any:
        """``array``'s data as a C pointer, the array kept alive as long as this is."""
        self._keep.append(array)
        return array.ctypes.data_as(kind)


def play(
    lib: ctypes.CDLL,
    prepared: Prepared,
    *,
    start: np.ndarray,
    surfaces: Sequence[np.ndarray],
    settle_ticks: int,
) -> np.ndarray:
    """Each job's pose at its end (:func:`emulator.moves.play_moves`'s result).

    Args:
        lib: :func:`load`'s library.
        prepared: the jobs' structures (one twin per job, in job order).
        start: ``(n, 3)`` start poses (x_m, y_m, yaw_rad), map frame.
        surfaces: each job's wheel surface speeds per tick, ``(ticks, 2)`` (left, right),
            m/s; jobs may share one array (it is passed once).
        settle_ticks: ticks with the wheels stopped after each job's steps.
    """
    n = len(surfaces)
    offsets: dict[int, int] = {}
    distinct: list[np.ndarray] = []
    total = 0
    for surface in surfaces:
        if id(surface) not in offsets:
            offsets[id(surface)] = total
            distinct.append(surface)
            total += len(surface)
    offset = np.array([offsets[id(surface)] for surface in surfaces], dtype=np.int64)
    ticks = np.array([len(surface) for surface in surfaces], dtype=np.int64)
    end = ticks + settle_ticks
    speeds = _f64(np.concatenate(distinct) if total else np.zeros((1, 2)))
    start = _f64(start)
    out = np.empty((n, 3))
    lib.rover_play_moves(
        ctypes.byref(prepared.model),
        ctypes.byref(prepared.grounds),
        ctypes.byref(prepared.regions),
        n,
        start.ctypes.data_as(_D),
        speeds.ctypes.data_as(_D),
        offset.ctypes.data_as(_I64),
        ticks.ctypes.data_as(_I64),
        end.ctypes.data_as(_I64),
        out.ctypes.data_as(_D),
    )
    return out


class Forces:
    """One physics step's world-frame forces and torques for :func:`emulator.batch.
    play_batch`'s twins, written where pymunk.batch sets them from.

    Args:
        lib: :func:`load`'s library.
        prepared: the twins' structures.
        offsets: ``(n, 2)`` where each twin's copy of the map is, m.
        force: ``3 * n`` floats or more (contiguous): twin ``i``'s ``(fx, fy, tz)`` go to
            ``force[3i:3i + 3]``.
    """

    def __init__(
        self, lib: ctypes.CDLL, prepared: Prepared, offsets: np.ndarray, force: np.ndarray
    ) -> None:
        n = len(offsets)
        if len(force) < 3 * n or not force.flags.c_contiguous or force.dtype != np.float64:
            raise ValueError("force must be 3 * n contiguous float64 or more")
        self._call = lib.rover_batch_forces
        self._prepared = prepared
        self._args = (
            ctypes.byref(prepared.model),
            ctypes.byref(prepared.grounds),
            ctypes.byref(prepared.regions),
            n,
        )
        self._offsets = prepared.pointer(_f64(offsets))
        self._force = prepared.pointer(force)
        self._n = n

    def __call__(self, state: np.ndarray, ul: float, ur: float) -> None:
        """Compute them from ``state``: ``(n, 6)`` contiguous float64, pymunk.batch's
        position, angle, velocity (world frame) and angular velocity of each twin; ``ul``,
        ``ur`` the wheel surface speeds every twin is commanded, m/s."""
        if state.shape != (self._n, 6) or not state.flags.c_contiguous:
            raise ValueError(f"state must be ({self._n}, 6) and contiguous")
        self._call(*self._args, state.ctypes.data, self._offsets, ul, ur, self._force)
