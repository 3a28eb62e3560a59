"""Batch replays (:func:`emulator.moves.play_moves`, what a calibration fits and designs
with): the C kernel beside the numpy loop it replaced, in the same run.

Run: ``python -m benchmarks.bench_moves [--repeat N] [--quick]``. Prints one table, a
row per batch: seeded one-step jobs (22 steps of any command, speed 10-60, 500-20,000 units,
each on several grounds) and 1 s of rest on the lab map (through its traction region) at the fit's 10 ms step, each batch as large as the fits
ask for (a Jacobian's 66 replays; the posterior's 2,816); CPU time (``time.process_time``)
p50 and worst over the repeats for each, their ratio, the C kernel's job-steps per
second, and the largest difference between the two replays' end poses (their units: m,
and rad for the yaw). The wheel commands are computed once before timing (a fit keeps
them: ``emulator.moves._schedule``).
"""

from __future__ import annotations

import argparse
import platform
import statistics
import time
from collections.abc import Callable

import numpy as np

from emulator import moves_kernel
from emulator.batch import BatchDraw
from emulator.ground import load_ground
from emulator.moves import MoveJob, _schedule, play_moves
from emulator.twin import Pose2D
from firmware_proto.model.rover import RoverDescription, load_rover
from firmware_proto.model.worldmap import load_map

DT_S = 0.01
SETTLE_S = 1.0
STEPS = 22
"""Distinct steps in a batch (a fit's are its recordings' steps)."""


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


def cpu_s(fn: Callable[[], np.ndarray], repeat: int) -> tuple[list[float], np.ndarray]:
    """CPU seconds of each of ``repeat`` calls, and the last call's result."""
    times = []
    result = np.empty(0)
    for _ in range(repeat):
        t0 = time.process_time()
        result = fn()
        times.append(time.process_time() - t0)
    return times, result


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--repeat", type=int, default=5, help="calls of each (default 5)")
    parser.add_argument(
        "--quick", action="store_true", help="small batches, one call each (smoke test)"
    )
    args = parser.parse_args(argv)
    repeat = 1 if args.quick else max(1, args.repeat)
    sizes = (8, 66) if args.quick else (66, 2816)
    rover = load_rover()
    lab = load_map("lab")
    print(
        f"batch replay benchmark: Python {platform.python_version()}, numpy "
        f"{np.__version__}, {platform.machine()}, one thread; the C kernel: "
        f"{moves_kernel.build().name}"
    )
    print()
    print(
        "| jobs | job-steps | numpy p50 ms | numpy worst ms | C p50 ms | C worst ms "
        "| numpy / C | C job-steps/s | largest difference |"
    )
    print("|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for n in sizes:
        batch = jobs(rover, n, seed=n)
        play_moves(rover, lab, batch[:1], dt_s=DT_S, settle_s=SETTLE_S, kernel="c")  # loaded
        play_moves(rover, lab, batch, dt_s=DT_S, settle_s=SETTLE_S, kernel="c")  # schedules

        def run(kernel: str, batch: list[MoveJob] = batch) -> np.ndarray:
            return play_moves(rover, lab, batch, dt_s=DT_S, settle_s=SETTLE_S, kernel=kernel)

        plain_t, plain = cpu_s(lambda: run("numpy"), repeat)
        c_t, c = cpu_s(lambda: run("c"), repeat)
        settle = round(SETTLE_S / DT_S)
        steps = sum(_schedule(rover, job.steps, DT_S).ticks + settle for job in batch)
        p50_plain, p50_c = statistics.median(plain_t), statistics.median(c_t)
        print(
            f"| {n:,} | {steps:,} | {p50_plain * 1e3:,.1f} | {max(plain_t) * 1e3:,.1f} "
            f"| {p50_c * 1e3:,.2f} | {max(c_t) * 1e3:,.2f} | {p50_plain / max(p50_c, 1e-9):,.0f}x "
            f"| {steps / max(p50_c, 1e-9):,.0f} | {float(np.abs(c - plain).max()):.1e} |"
        )


if __name__ == "__main__":
    main()
