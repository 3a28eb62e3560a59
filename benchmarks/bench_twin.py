"""Physics twin throughput: steps/s and the factor over real time.

Run: ``python -m benchmarks.bench_twin [--repeat N] [--quick]``. Prints one table:

- *real time*: the reference the factors are relative to (1 s of twin time per s);
- *bare pymunk body*: the same body and chassis shape stepped with no force code, the
  floor that pymunk itself sets (measured in the same run);
- *twin driving*: :meth:`Twin.step` with the motors commanded (force code included) on
  an open plane and on the densest map, at 1 ms and at the gate step;
- *12-step plan*: :func:`play` of a 12-step plan with 10 m of driving and four turns
  on scn01 (through a traction region), wall time p50/p99 over the repeats and the
  factor over real time at p50, at 1 ms, the gate step and 10 ms.

Targets: at least 50x real time at 1 ms (>= 50,000 steps/s) while driving; at least
500x for the 12-step plan at the gate step. Single thread; timings are wall clock
(``time.perf_counter``), best-of for the step rates, percentiles for the plan.
"""

from __future__ import annotations

import argparse
import math
import platform
import statistics
import time
from collections.abc import Callable

import pymunk

from emulator.drive import turn_units_for_yaw
from emulator.playback import play
from emulator.twin import GATE_DT_S, Twin
from firmware_proto.model.rover import RoverDescription, load_rover
from firmware_proto.model.worldmap import load_map
from firmware_proto.wire.messages import Command

STEP_RUN = 20_000


def bare_pymunk_rate(rover: RoverDescription, dt: float) -> float:
    """Steps/s of a space holding the rover's body and chassis box, no forces."""
    space = pymunk.Space()
    size = (rover.geometry.chassis_length_m, rover.geometry.chassis_width_m)
    body = pymunk.Body(rover.mass.mass_kg, pymunk.moment_for_box(rover.mass.mass_kg, size))
    body.velocity = (0.3, 0.0)
    space.add(body, pymunk.Poly.create_box(body, size))
    step = space.step
    t0 = time.perf_counter()
    for _ in range(STEP_RUN):
        step(dt)
    return STEP_RUN / (time.perf_counter() - t0)


def twin_rate(rover: RoverDescription, dt: float, map_name: str | None) -> float:
    """Steps/s of :meth:`Twin.step` with the rover turning gently in place of a plan."""
    world = load_map(map_name) if map_name else None
    twin = Twin(rover, world, dt_s=dt)
    k = rover.drive.wheel_velocity_scale_rad_s
    twin.set_motor_omegas(-20 * k, 24 * k)  # a slow arc: stays clear of obstacles
    step = twin.step
    t0 = time.perf_counter()
    for _ in range(STEP_RUN):
        step()
    return STEP_RUN / (time.perf_counter() - t0)


def best(fn: Callable[[], float], repeat: int) -> float:
    return max(fn() for _ in range(repeat))


def square_plan(rover: RoverDescription) -> list[tuple[int, int, int]]:
    """12 steps: four sides of 2 x 1.25 m (10 m of driving), each then a 90 degree LEFT turn."""
    quarter = turn_units_for_yaw(rover, math.pi / 2)
    side: list[tuple[int, int, int]] = [
        (Command.FWD, 60, 28750),
        (Command.FWD, 60, 28750),
        (Command.LEFT, 30, quarter),
    ]
    return side * 4


def plan_times(rover: RoverDescription, dt: float, repeat: int) -> tuple[float, float, float, int]:
    """(sim time s, wall p50 s, wall p99 s, physics steps) of the square plan on scn01."""
    world = load_map("scn01")
    plan = square_plan(rover)
    walls: list[float] = []
    sim = 0.0
    steps = 0
    for _ in range(repeat):
        t0 = time.perf_counter()
        twin = Twin(rover, world, dt_s=dt)
        result = play(twin, plan)
        walls.append(time.perf_counter() - t0)
        sim, steps = result.sim_time_s, twin.steps
        assert result.completed, "the benchmark plan must run to the end"
    walls.sort()
    p99 = walls[min(len(walls) - 1, math.ceil(0.99 * len(walls)) - 1)]
    return sim, statistics.median(walls), p99, steps


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--repeat", type=int, default=20, help="plan repetitions (default 20)")
    parser.add_argument(
        "--quick", action="store_true", help="one run of each case (smoke test; noisy figures)"
    )
    args = parser.parse_args(argv)
    repeat = 1 if args.quick else max(1, args.repeat)
    tries = 1 if args.quick else 5  # best of: the rates
    rover = load_rover()

    print(
        f"twin benchmark: Python {platform.python_version()}, pymunk {pymunk.version}, "
        f"{platform.machine()}, one thread"
    )
    print()
    header = f"{'case':<44} {'dt ms':>6} {'steps/s':>10} {'x real time':>12}"
    print(header)
    print("-" * len(header))

    def row(name: str, dt: float, rate: float) -> None:
        print(f"{name:<44} {dt * 1e3:>6.1f} {rate:>10,.0f} {rate * dt:>12,.1f}")

    row("real time (reference)", 0.001, 1000.0)
    row(
        "bare pymunk body, no force code (peer)",
        0.001,
        best(lambda: bare_pymunk_rate(rover, 0.001), tries),
    )
    row("twin driving, open plane", 0.001, best(lambda: twin_rate(rover, 0.001, None), tries))
    row(
        "twin driving, scn03 (densest map)",
        0.001,
        best(lambda: twin_rate(rover, 0.001, "scn03"), tries),
    )
    row(
        "twin driving, open plane",
        GATE_DT_S,
        best(lambda: twin_rate(rover, GATE_DT_S, None), tries),
    )
    row(
        "twin driving, scn03 (densest map)",
        GATE_DT_S,
        best(lambda: twin_rate(rover, GATE_DT_S, "scn03"), tries),
    )

    print()
    header = (
        f"{'12-step plan, 10 m + 4 turns, scn01':<36} {'dt ms':>6} {'sim s':>7} "
        f"{'steps':>7} {'wall p50 ms':>12} {'wall p99 ms':>12} {'x real time':>12}"
    )
    print(header)
    print("-" * len(header))
    for dt in (0.001, 0.005, GATE_DT_S):
        sim, p50, p99, steps = plan_times(
            rover, dt, repeat if dt > 0.001 or args.quick else max(3, repeat // 4)
        )
        label = "playback (gate step)" if dt == GATE_DT_S else "playback"
        print(
            f"{label:<36} {dt * 1e3:>6.1f} {sim:>7.2f} {steps:>7} {p50 * 1e3:>12.1f} "
            f"{p99 * 1e3:>12.1f} {sim / p50:>12,.0f}"
        )
    print()
    print("targets: >= 50x real time at 1 ms while driving; >= 500x for the plan at the gate step")


if __name__ == "__main__":
    main()
