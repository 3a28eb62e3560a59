"""Batch twins in C beside numpy, in the same run: the replays a calibration fits and
designs with (:func:`emulator.moves.play_moves`) and the gate's batches of twins
(:func:`emulator.batch.play_batch`).

Run: ``python -m benchmarks.bench_batch [--repeat N] [--quick]``. Prints two tables. The
first, a row per replay batch: seeded one-step jobs (22 steps of any command, speed 10-60, 500-20,000 units,
each on several grounds) and 1 s of rest on the lab map (through its traction region) at the fit's 10 ms step, each batch as large as the fits
ask for (a Jacobian's 66 replays; the posterior's 2,816); CPU time (``time.process_time``)
p50 and worst over the repeats for each, their ratio, the C kernel's job-steps per
second, and the largest difference between the two replays' end poses (their units: m,
and rad for the yaw). The wheel commands are computed once before timing (a fit keeps
them: ``emulator.moves._schedule``). The second, a row per batch of 1, 50 and 100 twins
(the gate's chunks hold up to 100) on varied grounds playing the gate benchmark's 12-step
plan on scn01 through its traction region: the same columns, the twin-steps those
played (each twin until it collided or came to rest), the difference between their end
poses.
"""

from __future__ import annotations

import argparse
import platform
import statistics
import time
from collections.abc import Callable
from typing import TypeVar

import numpy as np
import pymunk

from emulator import batch_kernel
from emulator.batch import BatchDraw, BatchResult, play_batch
from emulator.ground import load_ground
from emulator.moves import MoveJob, _schedule, play_moves
from emulator.twin import Pose2D
from firmware_proto.model.rover import RoverDescription, load_rover
from firmware_proto.model.worldmap import load_map

DT_S = 0.01
SETTLE_S = 1.0
STEPS = 22
"""Distinct steps in a replay batch (a fit's are its recordings' steps)."""
SQUARE = [(1, 60, 28750), (1, 60, 28750), (3, 30, 15484)] * 4
"""bench_gate's 12-step plan: four sides of 2 x 1.25 m on scn01, through its region."""


def jobs(rover: RoverDescription, n: int, seed: int) -> list[MoveJob]:
    """``n`` one-step jobs, seeded: :data:`STEPS` steps, each on several grounds (as a
    fit replays its steps), varied sides and starts on the lab map."""
    rng = np.random.default_rng(seed)
    ground = load_ground("loose", rover)
    steps = [
        (int(rng.integers(1, 5)), int(rng.integers(10, 61)), int(rng.integers(500, 20000)))
        for _ in range(STEPS)
    ]
    out = []
    for i in range(n):
        step = steps[i % STEPS]
        draw = BatchDraw(ground, float(rng.uniform(0.7, 1.1)), float(rng.uniform(0.7, 1.1)))
        start = Pose2D(
            float(rng.uniform(1.0, 7.0)), float(rng.uniform(1.0, 7.0)), float(rng.uniform(-3, 3))
        )
        out.append(MoveJob(start, (step,), draw))
    return out


_R = TypeVar("_R")


def cpu_s(fn: Callable[[], _R], repeat: int) -> tuple[list[float], _R]:
    """CPU seconds of each of ``repeat`` (at least one) calls, and the last call's result."""
    times = []
    for _ in range(repeat - 1):
        t0 = time.process_time()
        fn()
        times.append(time.process_time() - t0)
    t0 = time.process_time()
    result = fn()
    times.append(time.process_time() - t0)
    return times, result


def _row(n: int, steps: int, plain_t: list[float], c_t: list[float], difference: float) -> None:
    p50_plain, p50_c = statistics.median(plain_t), statistics.median(c_t)
    print(
        f"| {n:,} | {steps:,} | {p50_plain * 1e3:,.1f} | {max(plain_t) * 1e3:,.1f} "
        f"| {p50_c * 1e3:,.2f} | {max(c_t) * 1e3:,.2f} | {p50_plain / max(p50_c, 1e-9):,.1f}x "
        f"| {steps / max(p50_c, 1e-9):,.0f} | {difference:.1e} |"
    )


def _header(first: str) -> None:
    print(
        f"| {first} | twin-steps | numpy p50 ms | numpy worst ms | C p50 ms | C worst ms "
        "| numpy / C | C twin-steps/s | largest difference |"
    )
    print("|---:|---:|---:|---:|---:|---:|---:|---:|---:|")


def replays(rover: RoverDescription, sizes: tuple[int, ...], repeat: int) -> None:
    """The first table: :func:`play_moves` batches."""
    lab = load_map("lab")
    print("play_moves: one-step replays from rest on the lab map, 10 ms steps, 1 s of rest")
    print()
    _header("jobs")
    for n in sizes:
        batch = jobs(rover, n, seed=n)
        play_moves(rover, lab, batch, dt_s=DT_S, settle_s=SETTLE_S, kernel="c")  # schedules

        def run(kernel: str, batch: list[MoveJob] = batch) -> np.ndarray:
            return play_moves(rover, lab, batch, dt_s=DT_S, settle_s=SETTLE_S, kernel=kernel)

        plain_t, plain = cpu_s(lambda: run("numpy"), repeat)
        c_t, c = cpu_s(lambda: run("c"), repeat)
        settle = round(SETTLE_S / DT_S)
        steps = sum(_schedule(rover, job.steps, DT_S).ticks + settle for job in batch)
        _row(n, steps, plain_t, c_t, float(np.abs(c - plain).max()))


def twins(rover: RoverDescription, sizes: tuple[int, ...], repeat: int) -> None:
    """The second table: :func:`play_batch` of the 12-step plan."""
    world = load_map("scn01")
    start = Pose2D(1.0, 4.0, 0.0)
    print(
        "play_batch: the gate's 12-step plan (four sides of 2 x 1.25 m) on scn01, "
        "twins on varied grounds, one pymunk space, 10 ms steps"
    )
    print()
    _header("twins")
    for n in sizes:
        rng = np.random.default_rng(n)
        ground = load_ground("loose", rover)
        draws = [
            BatchDraw(
                ground.with_values(mu_lateral=float(rng.uniform(0.4, 0.6))),
                float(rng.uniform(0.9, 1.1)),
                float(rng.uniform(0.9, 1.1)),
            )
            for _ in range(n)
        ]

        def run(kernel: str, draws: list[BatchDraw] = draws) -> BatchResult:
            return play_batch(
                rover, world, draws, SQUARE, dt_s=DT_S, safety_margin_m=0.1, start=start,
                record_every_s=1.0, kernel=kernel,
            )  # fmt: skip

        plain_t, plain = cpu_s(lambda: run("numpy"), repeat)
        c_t, c = cpu_s(lambda: run("c"), repeat)
        steps = int(c.final_tick.sum())
        _row(n, steps, plain_t, c_t, float(np.abs(c.final - plain.final).max()))


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--repeat", type=int, default=5, help="calls of each (default 5)")
    parser.add_argument(
        "--quick", action="store_true", help="small batches, one call each (smoke test)"
    )
    args = parser.parse_args(argv)
    repeat = 1 if args.quick else max(1, args.repeat)
    rover = load_rover()
    print(
        f"batch twins benchmark: Python {platform.python_version()}, numpy "
        f"{np.__version__}, pymunk {pymunk.version}, {platform.machine()}, one thread; "
        f"the C kernel: {batch_kernel.build().name}"
    )
    print()
    replays(rover, (8,) if args.quick else (66, 2816), repeat)
    print()
    twins(rover, (4,) if args.quick else (1, 50, 100), repeat)


if __name__ == "__main__":
    main()
