"""The replay loop of :func:`emulator.moves.play_moves` in C (``moves_kernel.c``).

The numpy loop pays numpy's call overhead about 150 times a physics step whatever the
number of jobs; a calibration replays a few dozen at once, so that overhead was most of a
fit. The kernel plays each job alone, with the same operations in the same order as
:class:`emulator.batch._Forces` and the numpy loop, so the two agree to the last bits of
libm's ``tanh``, ``sin`` and ``cos`` (``tests/emulator/test_moves.py``; figures in
docs/twin.md, "Batch replays"). Built on first use with the host's C compiler and cached
(:mod:`emulator.sharedlib`); :func:`load` says why when it cannot be.
"""

from __future__ import annotations

import ctypes
import threading
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from emulator.batch import _WHEEL_PROBE_RADIUS_M, Schedule, _Forces
from emulator.errors import NativeBuildError
from emulator.sharedlib import build_shared_library, compiler

__all__ = ["KERNELS", "build", "load", "play"]

KERNELS = ("auto", "c", "numpy")
"""What :func:`emulator.moves.play_moves` replays with: ``auto`` (the C kernel where it
builds, else numpy), ``c`` (the kernel, or :class:`NativeBuildError`), ``numpy``."""

_C_DIR = Path(__file__).resolve().parent
_SOURCES = ("moves_kernel.c",)
_FLAGS = (
    "-std=c99",
    "-Wall",
    "-Wextra",
    "-Werror",
    "-pedantic",
    "-Wconversion",
    "-Wshadow",
    "-O2",
    "-ffp-contract=off",  # no fused multiply-adds: numpy's roundings, step by step
)
_LOCK = threading.Lock()
_LIB: list[ctypes.CDLL] = []

_D = ctypes.POINTER(ctypes.c_double)
_I32 = ctypes.POINTER(ctypes.c_int32)
_I64 = ctypes.POINTER(ctypes.c_int64)


class _Model(ctypes.Structure):
    """``moves_model_t``, field for field."""

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
    """``moves_grounds_t``."""

    _fields_ = [
        (name, _D)
        for name in ("s0", "kappa", "rr", "mu_long_n", "mu_lat_n", "side", "region_scales")
    ]


class _Regions(ctypes.Structure):
    """``moves_regions_t``."""

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
        "rover_moves",
        _C_DIR,
        _SOURCES,
        (),
        _FLAGS,
        cc=compiler(
            error=NativeBuildError,
            hint="the C replay kernel needs one (apt-get install gcc libc6-dev); "
            "play_moves(kernel='numpy') needs none",
        ),
        error=NativeBuildError,
        libs=("-lm",),
        timeout_s=timeout_s,
    )


def load() -> ctypes.CDLL:
    """The kernel, built and loaded once per process.

    Raises:
        NativeBuildError: it cannot be built or loaded here.
    """
    with _LOCK:
        if not _LIB:
            path = build()
            try:
                lib = ctypes.CDLL(str(path))
            except OSError as exc:
                raise NativeBuildError(f"cannot load {path}: {exc}") from exc
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
            _LIB.append(lib)
        return _LIB[0]


def _f64(values: Any) -> np.ndarray:
    return np.ascontiguousarray(values, dtype=np.float64)


def play(
    lib: ctypes.CDLL,
    forces: _Forces,
    *,
    inv_mass: float,
    inv_inertia: float,
    dt_s: float,
    start: np.ndarray,
    plans: Sequence[Schedule],
    settle_ticks: int,
) -> np.ndarray:
    """Each job's pose at its end (:func:`emulator.moves.play_moves`'s result).

    Args:
        lib: :func:`load`'s library.
        forces: the jobs' traction (one twin per job, in job order).
        inv_mass, inv_inertia: of the rigid body, 1/kg and 1/(kg m^2).
        dt_s: physics step, s.
        start: ``(n, 3)`` start poses (x_m, y_m, yaw_rad), map frame.
        plans: each job's wheel commands.
        settle_ticks: ticks with the wheels stopped after each job's steps.
    """
    n = len(plans)
    model = _Model(
        hx=forces.hx,
        hy=forces.hy,
        mass=forces.mass,
        inertia=forces.inertia,
        inv_mass=inv_mass,
        inv_inertia=inv_inertia,
        inv_vrr=forces.inv_vrr,
        dt=dt_s,
        probe=_WHEEL_PROBE_RADIUS_M,
        wheel_x=(ctypes.c_double * 4)(*forces.wheel_x[:, 0]),
        wheel_y=(ctypes.c_double * 4)(*forces.wheel_y[:, 0]),
    )
    keep: list[np.ndarray] = []  # alive until the call returns

    def ptr(array: np.ndarray, kind: Any = _D) -> Any:
        keep.append(array)
        return array.ctypes.data_as(kind)

    grounds = _Grounds(
        ptr(_f64(forces.s0)),
        ptr(_f64(forces.kappa)),
        ptr(_f64(forces.rr)),
        ptr(_f64(forces.mu_long_n)),
        ptr(_f64(forces.mu_lat_n)),
        ptr(_f64(forces.side[[0, 2], :].T)),
        ptr(_f64(forces.region_scales)),
    )
    part_region: list[int] = []
    part_edge = [0]
    edges: list[np.ndarray] = []
    for r_index, parts in enumerate(forces._parts):
        for px, py, dx, dy in parts:
            part_region.append(r_index)
            edges.append(np.hstack([px, py, dx, dy]))
            part_edge.append(part_edge[-1] + len(px))
    regions = _Regions(
        len(forces._parts),
        len(part_region),
        ptr(np.array(part_region or [0], dtype=np.int32), _I32),
        ptr(np.array(part_edge, dtype=np.int32), _I32),
        ptr(_f64(np.vstack(edges) if edges else np.zeros((1, 4)))),
    )
    offsets: dict[int, int] = {}
    surfaces: list[np.ndarray] = []
    total = 0
    for plan in plans:
        if id(plan) not in offsets:
            offsets[id(plan)] = total
            surfaces.append(plan.surface_mps)
            total += plan.ticks
    offset = np.array([offsets[id(plan)] for plan in plans], dtype=np.int64)
    ticks = np.array([plan.ticks for plan in plans], dtype=np.int64)
    end = ticks + settle_ticks
    surface = _f64(np.concatenate(surfaces) if total else np.zeros((1, 2)))
    out = np.empty((n, 3))
    lib.rover_play_moves(
        ctypes.byref(model),
        ctypes.byref(grounds),
        ctypes.byref(regions),
        n,
        ptr(_f64(start)),
        ptr(surface),
        ptr(offset, _I64),
        ptr(ticks, _I64),
        ptr(end, _I64),
        ptr(out),
    )
    return out
