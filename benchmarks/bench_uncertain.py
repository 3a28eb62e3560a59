"""Verdicts with their uncertainty: playbacks/s and latency against samples and workers.

Run: ``python -m benchmarks.bench_uncertain [--quick] [--no-cluster] [--repeat R]``.
The plan is bench_gate's 12-step plan (10 m and four turns on scn01, through its
traction region). Two tables, the N-sample verdict beside the single playback:

1. *Playbacks per second, one process*: the single playback (``emulator.playback.play``
   on a :class:`~emulator.twin.Twin`, the peer) against one batch
   (``emulator.batch.play_batch``) of 1, 50, 100 and 200 twins: wall time per call and
   twins played per second.
2. *The verdict over HTTP against N and workers*: ``POST /validate_plan`` with
   ``samples=N`` (1 is the single playback) to a gate with 1 and 2 local worker
   processes, and to a gate whose samples go to a local Dask cluster (a scheduler and
   two single-threaded workers, each its own process, on loopback; ``--no-cluster``
   leaves it out); p50 and max of ``--repeat`` requests, after one that warms the
   workers, and samples per second at p50.

``--quick`` (the smoke test's): N in 1 and 20, one repeat. Timings are wall clock; rows
of one table are measured in the same run.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import statistics
import tempfile
import time
from contextlib import ExitStack
from pathlib import Path

import numpy as np
import pymunk

from benchmarks.bench_gate import as_plan_json, square_plan
from emulator.batch import BatchDraw, play_batch
from emulator.ground import Ground
from emulator.playback import play
from emulator.twin import Pose2D, Twin
from firmware_proto.model.rover import load_rover
from firmware_proto.model.worldmap import load_map
from gate.config import DEFAULT_DT_S, DEFAULT_SAFETY_MARGIN_M, GateConfig
from gate.ensemble import DefaultSpread, draw
from gate.server import GateServer
from tests.gate.client import post_plan

START = (1.0, 4.0, 0.0)


def bench_playbacks(sizes: list[int], repeat: int) -> None:
    rover = load_rover()
    world = load_map("scn01")
    steps = square_plan(rover)
    start = Pose2D.from_deg(*START)
    rows: list[tuple[str, int, float]] = []
    walls = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        twin = Twin(
            rover, world, dt_s=DEFAULT_DT_S, safety_margin_m=DEFAULT_SAFETY_MARGIN_M, start=start
        )
        play(twin, steps)
        walls.append(time.perf_counter() - t0)
    rows.append(("single playback (peer)", 1, statistics.median(walls)))
    spread = DefaultSpread(Ground.of_rover(rover))
    for n in sizes:
        draws: list[BatchDraw] = draw(spread, n, 1, 0.1)
        walls = []
        for _ in range(repeat):
            t0 = time.perf_counter()
            play_batch(
                rover,
                world,
                draws,
                steps,
                dt_s=DEFAULT_DT_S,
                safety_margin_m=DEFAULT_SAFETY_MARGIN_M,
                start=start,
                record_every_s=1.0,
            )
            walls.append(time.perf_counter() - t0)
        rows.append((f"one batch of {n}", n, statistics.median(walls)))
    print("| 12-step plan, scn01, 10 ms, one process | twins | wall p50 s | twins/s |")
    print("|---|---:|---:|---:|")
    for name, n, wall in rows:
        print(f"| {name} | {n} | {wall:.3f} | {n / wall:,.1f} |")


def _latencies(
    address: tuple[str, int], body: dict[str, object], n: int, repeat: int
) -> list[float]:
    query = f"map=scn01&start={START[0]},{START[1]},{START[2]}&samples={n}&seed=1"
    first = post_plan(address, body, query)  # warms the workers
    assert first.status == 200, first.body[:300]
    walls = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        reply = post_plan(address, body, query)
        walls.append(time.perf_counter() - t0)
        assert reply.status == 200, reply.body[:300]
        if n > 1:
            assert json.loads(reply.body)["uncertainty"]["samples"] == n
    return walls


def bench_verdicts(ns: list[int], repeat: int, cluster: bool) -> None:
    rover = load_rover()
    body = as_plan_json(square_plan(rover), START)
    setups: list[tuple[str, GateConfig]] = [
        ("local pool, 1 worker", GateConfig(port=0, workers=1)),
        ("local pool, 2 workers", GateConfig(port=0, workers=2)),
    ]
    with ExitStack() as stack:
        if cluster:
            from gate.cluster import local_cluster

            where = Path(stack.enter_context(tempfile.TemporaryDirectory()))
            address = stack.enter_context(local_cluster(where, workers=2))
            setups.append(
                ("Dask cluster, 2 workers", GateConfig(port=0, workers=1, cluster=address))
            )
        print("| engine | N | p50 s | max s | samples/s at p50 |")
        print("|---|---:|---:|---:|---:|")
        for name, config in setups:
            with GateServer(config) as gate:
                for n in ns:
                    walls = _latencies(gate.address, body, n, repeat)
                    p50 = statistics.median(walls)
                    rate = f"{n / p50:,.0f}" if n > 1 else "(single playback)"
                    print(f"| {name} | {n} | {p50:.3f} | {max(walls):.3f} | {rate} |")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--quick", action="store_true", help="small N, one repeat (smoke test)")
    parser.add_argument("--no-cluster", action="store_true", help="leave the Dask rows out")
    parser.add_argument("--repeat", type=int, default=5, help="requests per row (default 5)")
    args = parser.parse_args(argv)
    repeat = 1 if args.quick else max(1, args.repeat)
    sizes = [1, 20] if args.quick else [1, 50, 100, 200]
    ns = [1, 20] if args.quick else [1, 50, 200, 1000]
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else math.nan
    print(
        f"uncertain-verdict benchmark: Python {platform.python_version()}, pymunk "
        f"{pymunk.version}, numpy {np.__version__}, {os.cpu_count()} CPUs, load {load:.1f}"
    )
    print()
    bench_playbacks(sizes, repeat)
    print()
    bench_verdicts(ns, repeat, cluster=not args.no_cluster)


if __name__ == "__main__":
    main()
