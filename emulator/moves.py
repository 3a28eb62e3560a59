"""Many steps replayed from rest on many grounds at once: what a calibration fits and
designs with.

:func:`play_moves` replays every ``(start, steps, ground)`` job in one loop over the
physics steps: in C (:mod:`emulator.batch_kernel`) where it builds, else with
``emulator.batch``'s numpy forces for all jobs at once. No physics
engine (a calibration step that met an obstacle is an outlier): each body is a free
rigid body integrated as pymunk integrates one, with the twin's wheel commands
(:func:`emulator.batch.schedule`), traction regions, and ``settle_s`` wheels stopped
after the steps. A job agrees with :class:`~emulator.twin.Twin` to about 1e-9 m;
deterministic.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pymunk

from emulator import batch_kernel
from emulator.batch import _WHEEL_PROBE_RADIUS_M, BatchDraw, Schedule, _Forces, schedule
from emulator.errors import TwinConfigError
from emulator.twin import MAX_DT_S, Pose2D
from firmware_proto.model.rover import RoverDescription
from firmware_proto.model.worldmap import WorldMap

__all__ = ["MoveJob", "play_moves"]


@dataclass(frozen=True)
class MoveJob:
    """One replay: ``steps`` from rest at ``start`` on ``draw``'s ground.

    Attributes:
        start: the start pose, map frame.
        steps: ``(command, speed, distance)`` triples, played back to back.
        draw: the ground, each side's friction factor, the start's offset.
    """

    start: Pose2D
    steps: tuple[tuple[int, int, int], ...]
    draw: BatchDraw


def play_moves(
    rover: RoverDescription,
    world: WorldMap | None,
    jobs: Sequence[MoveJob],
    *,
    dt_s: float,
    settle_s: float,
    kernel: str = "auto",
) -> np.ndarray:
    """Replay every job (see the module docstring).

    Args:
        rover: the rover description; each job's ground replaces its traction.
        world: the map, for its traction regions (``None``: an open plane).
        jobs: the replays.
        dt_s: physics step, s, in ``(0, MAX_DT_S]``.
        settle_s: wheels stopped after each job's steps, s (rounded to whole steps).
        kernel: one of :data:`emulator.batch_kernel.KERNELS`: ``auto`` replays in C
            where the kernel builds, else with numpy (said once in the log).

    Returns:
        ``(len(jobs), 3)``: each job's pose at its end, ``(x_m, y_m, yaw_rad)`` in the
        map frame, the yaw unwrapped (the start's yaw plus every turn since).

    Raises:
        CommandError: a step is invalid.
        TwinConfigError: ``dt_s``, ``settle_s`` or ``kernel`` out of range.
        NativeBuildError: ``kernel="c"`` and the C kernel cannot be built here.
    """
    if not (math.isfinite(dt_s) and 0.0 < dt_s <= MAX_DT_S):
        raise TwinConfigError(f"dt_s must be in (0, {MAX_DT_S}], got {dt_s}")
    if not (math.isfinite(settle_s) and settle_s >= 0.0):
        raise TwinConfigError(f"settle_s must be >= 0, got {settle_s}")
    lib = batch_kernel.choose(kernel)
    n = len(jobs)
    if n == 0:
        return np.empty((0, 3))
    plans: dict[tuple[tuple[int, int, int], ...], Schedule] = {}
    for job in jobs:
        if job.steps not in plans:
            plans[job.steps] = _schedule(rover, job.steps, dt_s)
    settle = round(settle_s / dt_s)
    forces = _Forces(rover, world, [job.draw for job in jobs])
    g = rover.geometry
    mass = rover.mass.mass_kg
    inv_mass = 1.0 / mass
    inv_inertia = 1.0 / pymunk.moment_for_box(mass, (g.chassis_length_m, g.chassis_width_m))
    start = np.array(
        [
            (
                job.start.x_m + job.draw.start_dx_m,
                job.start.y_m + job.draw.start_dy_m,
                job.start.yaw_rad + job.draw.start_dyaw_rad,
            )
            for job in jobs
        ]
    ).reshape(n, 3)
    job_plans = [plans[job.steps] for job in jobs]
    if lib is not None:
        prepared = batch_kernel.Prepared(
            forces,
            inv_mass=inv_mass,
            inv_inertia=inv_inertia,
            dt_s=dt_s,
            probe_m=_WHEEL_PROBE_RADIUS_M,
        )
        surfaces = [plan.surface_mps for plan in job_plans]  # (ticks, 2), shared by jobs
        return batch_kernel.play(lib, prepared, start=start, surfaces=surfaces, settle_ticks=settle)
    return _play_numpy(forces, inv_mass, inv_inertia, dt_s, start, job_plans, settle)


@functools.lru_cache(maxsize=512)
def _schedule(
    rover: RoverDescription, steps: tuple[tuple[int, int, int], ...], dt_s: float
) -> Schedule:
    """:func:`emulator.batch.schedule`, kept: a fit replays the same steps on every
    ground it tries (its wheel speeds read-only, shared by every caller)."""
    plan = schedule(rover, steps, dt_s)
    plan.surface_mps.setflags(write=False)
    return plan


def _play_numpy(
    forces: _Forces,
    inv_mass: float,
    inv_inertia: float,
    dt_s: float,
    start: np.ndarray,
    plans: Sequence[Schedule],
    settle: int,
) -> np.ndarray:
    """:func:`play_moves` for every job at once, numpy's operations per physics step."""
    n = len(plans)
    out = np.empty((n, 3))
    ends = np.array([plan.ticks + settle for plan in plans], dtype=np.int64)
    last = int(ends.max())
    surface = np.zeros((max(1, last), n, 2))
    for i, plan in enumerate(plans):
        surface[: plan.ticks, i, :] = plan.surface_mps
    finishing: dict[int, list[int]] = {}
    for i, end in enumerate(ends):
        finishing.setdefault(int(end), []).append(i)
    x, y, a = start[:, 0].copy(), start[:, 1].copy(), start[:, 2].copy()
    vx = np.zeros(n)
    vy = np.zeros(n)
    w = np.zeros(n)
    for at in finishing.get(0, ()):
        out[at] = (x[at], y[at], a[at])
    for tick in range(1, last + 1):
        c, s = np.cos(a), np.sin(a)
        forces.place(x, y, c, s)
        ul = surface[tick - 1, :, 0]
        ur = surface[tick - 1, :, 1]
        fx, fy, tz = forces.step(c * vx + s * vy, c * vy - s * vx, w, ul, ur, dt_s)
        # Chipmunk: positions with the old velocities, then the velocities.
        x = x + vx * dt_s
        y = y + vy * dt_s
        a = a + w * dt_s
        vx = vx + (c * fx - s * fy) * inv_mass * dt_s
        vy = vy + (s * fx + c * fy) * inv_mass * dt_s
        w = w + tz * inv_inertia * dt_s
        done = finishing.get(tick)
        if done is not None:
            out[done, 0] = x[done]
            out[done, 1] = y[done]
            out[done, 2] = a[done]
    return out
