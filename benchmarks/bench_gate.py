"""Simulation gate: validation speed, collision checks, step-size accuracy, HTTP rates.

Run: ``python -m benchmarks.bench_gate [--repeat N] [--seconds S] [--before DIR]``.
``--before DIR`` also measures the gate of another source tree (``git archive COMMIT | tar
-x -C DIR``; rows named after DIR) in the same run, in tables 1, 4 and 5. Prints six
tables (``--table N``, repeatable: only those):

1. *12-step plan, 10 m of driving and four turns* on scn01 (through a traction region):
   wall time p50/p99 and the factor over real time, for the twin alone
   (:func:`emulator.playback.play`), the gate's whole validation in one process
   (playback, verdict, trajectory tagging, JSON) and end to end over HTTP (a ``rover
   gate`` subprocess with worker processes), beside the thesis's Isaac Sim at 60 Hz.
2. *Collision checks per physics step* on each scenario map, beside the thesis's per-frame
   query: the cost pymunk's contact detection adds to a twin step (the map minus an open
   plane, same motion), and an explicit overlap query of the margin-inflated footprint
   against the whole map (pymunk ``shape_query``, the thesis's ``overlap_mesh``).
3. *Step size against the 1 ms reference* over random 12-step plans: the largest final
   position and yaw difference, and the factor over real time.
4. *Requests/s and p50/p99 latency for a trivial plan* (the HTTP path's own cost) with
   1 and 4 keep-alive clients: the gate before and after (processes and threads), the
   HTTP stack alone with a trivial handler (Starlette on uvicorn, as the gate serves;
   aiohttp, when it is installed) and a plain ``http.server`` handler (its Nagle stall),
   all up at once and measured in interleaved rounds.
5. *The 12-step plan from 1 and 4 clients*, worker processes against worker threads
   (and the server before), with the CPU the gate used per wall second.
6. *A call's hand-off to a worker process* from an event loop, the gate's pool beside
   ``concurrent.futures.ProcessPoolExecutor`` (spawn, an initializer), 1 and 4 at a
   time; and stopping a running call (which the executor cannot do).

Timings are wall clock (``time.perf_counter``) on a shared VM; rates vary between runs.
"""

from __future__ import annotations

import argparse
import contextlib
import http.client
import json
import math
import os
import platform
import random
import statistics
import sys
import threading
import time
from collections.abc import Callable
from contextlib import AbstractContextManager, ExitStack
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

import pymunk

from benchmarks.common import Served, gate_process, server_process, tree_cpu_s
from emulator.drive import turn_units_for_yaw
from emulator.playback import play
from emulator.twin import Twin
from firmware_proto.model.geometry import convex_parts
from firmware_proto.model.plan import COMMAND_NAMES, Plan
from firmware_proto.model.rover import RoverDescription, load_rover
from firmware_proto.model.worldmap import CircleObstacle, PolygonObstacle, WorldMap, load_map
from firmware_proto.wire.messages import Command
from gate.config import DEFAULT_DT_S, DEFAULT_SAFETY_MARGIN_M, GateConfig
from gate.options import ValidateOptions
from gate.validator import Validator

THESIS_QUERY_MS = {"scn01": 12.4, "scn02": 18.6, "scn03": 24.1}
TRIVIAL_PLAN = json.dumps(
    {
        "goal": {"x": 1.2, "y": 3.0, "yaw_deg": 0.0},
        "commands": [{"command": "STOP", "speed": 0, "distance": 0}],
    }
).encode()


def percentile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, math.ceil(q * len(ordered)) - 1)]


def square_plan(rover: RoverDescription) -> list[tuple[int, int, int]]:
    """12 steps: four sides of 2 x 1.25 m (10 m of driving), each followed by a 90 degree
    LEFT turn (the plan of benchmarks/bench_twin.py)."""
    quarter = turn_units_for_yaw(rover, math.pi / 2)
    side = [
        (int(Command.FWD), 60, 28750),
        (int(Command.FWD), 60, 28750),
        (int(Command.LEFT), 30, quarter),
    ]
    return side * 4


def as_plan_json(
    steps: list[tuple[int, int, int]], goal: tuple[float, float, float]
) -> dict[str, Any]:
    return {
        "goal": {"x": goal[0], "y": goal[1], "yaw_deg": goal[2]},
        "commands": [{"command": COMMAND_NAMES[c], "speed": s, "distance": d} for c, s, d in steps],
    }


# -- 1. the 12-step plan ----------------------------------------------------------------------


def _http_walls(served: Served, payload: bytes, repeat: int) -> tuple[float, list[float]]:
    """Twin time and wall times of ``repeat`` POSTs of ``payload`` on one connection
    (after two that warm each worker process)."""
    conn = http.client.HTTPConnection(*served.address, timeout=60)
    walls = []
    for i in range(repeat + 2):
        t0 = time.perf_counter()
        conn.request(
            "POST", "/validate_plan?map=scn01", payload, {"Content-Type": "application/json"}
        )
        response = conn.getresponse()
        data = response.read()
        if i >= 2:
            walls.append(time.perf_counter() - t0)
    conn.close()
    assert response.status == 200, data[:200]
    return json.loads(data)["sim_time_s"], walls


def bench_plan(rover: RoverDescription, repeat: int, before: str | None = None) -> None:
    world = load_map("scn01")
    steps = square_plan(rover)
    body = as_plan_json(steps, (1.0, 4.0, 0.0))
    plan = Plan.from_dict(body)
    validator = Validator.from_config(GateConfig(pool="thread"))
    options = ValidateOptions(map="scn01").resolve(validator.settings, "scn01")

    rows: list[tuple[str, float, float, list[float]]] = []
    for dt in (0.001, DEFAULT_DT_S):
        walls = []
        sim = 0.0
        for _ in range(repeat if dt > 0.001 else max(3, repeat // 5)):
            t0 = time.perf_counter()
            result = play(
                Twin(rover, world, dt_s=dt, safety_margin_m=DEFAULT_SAFETY_MARGIN_M), steps
            )
            walls.append(time.perf_counter() - t0)
            sim = result.sim_time_s
            assert result.completed, "the benchmark plan must run to the end"
        rows.append(("twin playback only", dt, sim, walls))
    walls = []
    verdict = None
    for _ in range(repeat):
        t0 = time.perf_counter()
        verdict = validator.validate(plan, options)
        verdict.to_json()
        walls.append(time.perf_counter() - t0)
    assert verdict is not None
    assert verdict.collision is None
    rows.append(("gate validation, in process", DEFAULT_DT_S, verdict.sim_time_s, walls))
    payload = json.dumps(body).encode()
    if before:
        with before_gate(before) as served:
            sim, walls = _http_walls(served, payload, repeat)
        rows.append((f"over HTTP before ({Path(before).name})", DEFAULT_DT_S, sim, walls))
    with gate_process({}) as served:
        sim, walls = _http_walls(served, payload, repeat)
    rows.append(("gate over HTTP, worker processes", DEFAULT_DT_S, sim, walls))

    header = (
        f"{'12-step plan, 10 m + 4 turns, scn01':<36} {'dt ms':>6} {'sim s':>7} "
        f"{'wall p50 ms':>12} {'wall p99 ms':>12} {'x real time':>12}"
    )
    print(header)
    print("-" * len(header))
    peer = "thesis: Isaac Sim at 60 Hz (peer)"
    print(f"{peer:<36} {16.7:>6.1f} {'':>7} {'':>12} {'':>12} {'~1':>12}")
    for name, dt, sim, w in rows:
        p50 = statistics.median(w)
        print(
            f"{name:<36} {dt * 1e3:>6.1f} {sim:>7.2f} {p50 * 1e3:>12.1f} "
            f"{percentile(w, 0.99) * 1e3:>12.1f} {sim / p50:>12,.0f}"
        )
    print("target: >= 500x real time for the gate's validation")


# -- 2. collision checks ------------------------------------------------------------------------


def twin_step_us(
    rover: RoverDescription, world: WorldMap | None, start: tuple[float, float, float]
) -> float:
    """Best-of-5 mean time of one twin step, us, turning slowly in place at ``start``
    (same motion with and without a map, clear of every obstacle)."""
    best = math.inf
    n = 5000
    for _ in range(5):
        from emulator.twin import Pose2D

        twin = Twin(
            rover,
            world,
            dt_s=DEFAULT_DT_S,
            safety_margin_m=DEFAULT_SAFETY_MARGIN_M,
            start=Pose2D.from_deg(*start),
        )
        k = rover.drive.wheel_velocity_scale_rad_s
        twin.set_motor_omegas(10 * k, 10 * k)  # a slow spin on the spot
        step = twin.step
        t0 = time.perf_counter()
        for _ in range(n):
            step()
        best = min(best, (time.perf_counter() - t0) / n)
        assert twin.first_collision is None
    return best * 1e6


def map_space(world: WorldMap) -> pymunk.Space:
    """A pymunk space holding the map's obstacles and walls (for the explicit query)."""
    space = pymunk.Space()
    static = space.static_body
    b, t = world.bounds, 1.0
    shapes: list[pymunk.Shape] = [
        pymunk.Poly(static, [(x0, y0), (x1, y0), (x1, y1), (x0, y1)])
        for x0, y0, x1, y1 in (
            (b.min_x - t, b.min_y - t, b.max_x + t, b.min_y),
            (b.min_x - t, b.max_y, b.max_x + t, b.max_y + t),
            (b.min_x - t, b.min_y, b.min_x, b.max_y),
            (b.max_x, b.min_y, b.max_x + t, b.max_y),
        )
    ]
    for o in world.obstacles:
        if isinstance(o, PolygonObstacle):
            shapes += [pymunk.Poly(static, list(part)) for part in convex_parts(o.points)]
        elif isinstance(o, CircleObstacle):
            shapes.append(pymunk.Circle(static, o.radius_m, offset=o.center))
        else:
            shapes.append(pymunk.Segment(static, o.a, o.b, o.radius_m))
    space.add(*shapes)
    return space


def overlap_query_us(
    rover: RoverDescription, world: WorldMap, seed: int = 1
) -> tuple[float, float]:
    """Mean time of an explicit overlap query of the inflated footprint at random poses
    in the map, us, and the share of poses that overlap something."""
    space = map_space(world)
    body = pymunk.Body(body_type=pymunk.Body.KINEMATIC)
    g = rover.geometry
    half_l, half_w = g.chassis_length_m / 2, g.chassis_width_m / 2
    box = [(-half_l, -half_w), (half_l, -half_w), (half_l, half_w), (-half_l, half_w)]
    footprint = pymunk.Poly(body, box, radius=DEFAULT_SAFETY_MARGIN_M)
    space.add(body, footprint)
    rng = random.Random(seed)
    b = world.bounds
    poses = [
        (
            rng.uniform(b.min_x, b.max_x),
            rng.uniform(b.min_y, b.max_y),
            rng.uniform(-math.pi, math.pi),
        )
        for _ in range(2000)
    ]
    hits = 0
    best = math.inf
    for _ in range(3):
        hits = 0
        t0 = time.perf_counter()
        for x, y, yaw in poses:
            body.position = (x, y)
            body.angle = yaw
            space.reindex_shapes_for_body(body)
            if space.shape_query(footprint):
                hits += 1
        best = min(best, (time.perf_counter() - t0) / len(poses))
    return best * 1e6, hits / len(poses)


def bench_collision(rover: RoverDescription) -> None:
    header = (
        f"{'collision check per step':<18} {'obstacles':>9} {'thesis ms':>10} {'open us':>8} "
        f"{'map us':>7} {'in-step us':>11} {'query us':>9} {'x faster':>9}"
    )
    print(header)
    print("-" * len(header))
    twin_step_us(rover, None, (6.0, 4.0, 0.0))  # warm-up
    for name in ("scn01", "scn02", "scn03"):
        world = load_map(name)
        # A clear spot for the spin: scn03's is west of the barrier.
        spot = {"scn01": (2.0, 4.0, 0.0), "scn02": (1.5, 4.0, 0.0), "scn03": (1.2, 3.2, 0.0)}[name]
        open_us = map_us = math.inf
        for _ in range(3):  # interleaved, best of each: the difference is small
            open_us = min(open_us, twin_step_us(rover, None, spot))
            map_us = min(map_us, twin_step_us(rover, world, spot))
        in_step = max(0.0, map_us - open_us)
        query, _share = overlap_query_us(rover, world)
        worst = max(in_step, query)
        print(
            f"{name:<18} {len(world.obstacles):>9} {THESIS_QUERY_MS[name]:>10.1f} {open_us:>8.2f} "
            f"{map_us:>7.2f} {in_step:>11.2f} {query:>9.2f} "
            f"{THESIS_QUERY_MS[name] * 1e3 / worst:>9,.0f}"
        )
    print("open/map: one twin step (physics, forces, contacts) at the same spot without/with the")
    print("map; in-step: what contact detection adds (the difference of the best runs); query: one")
    print("explicit overlap query of the inflated footprint at a random pose; x faster: the")
    print("thesis's per-frame query time over the larger of ours.")


# -- 3. step size ----------------------------------------------------------------------------------


def random_plans(
    rover: RoverDescription, count: int, seed: int = 7
) -> list[list[tuple[int, int, int]]]:
    rng = random.Random(seed)
    plans = []
    for _ in range(count):
        steps: list[tuple[int, int, int]] = []
        for _ in range(6):
            angle = rng.uniform(-170, 170)
            units = min(30000, turn_units_for_yaw(rover, math.radians(abs(angle))))
            steps.append((3 if angle > 0 else 4, rng.choice([10, 20, 30, 40, 60]), units))
            steps.append(
                (
                    rng.choice([1, 1, 1, 2]),
                    rng.choice([10, 20, 30, 40, 60]),
                    rng.randint(2000, 30000),
                )
            )
        plans.append(steps)
    return plans


def bench_step_size(rover: RoverDescription, count: int) -> None:
    plans = random_plans(rover, count)
    reference = []
    header = (
        f"{'step size vs 1 ms, random 12-step plans':<40} {'dt ms':>6} {'max pos mm':>11} "
        f"{'max yaw deg':>12} {'x real time':>12}"
    )
    print(header)
    print("-" * len(header))
    for dt in (0.001, 0.002, 0.005, 0.01, 0.02):
        wall = sim = 0.0
        pos_err = yaw_err = 0.0
        for i, steps in enumerate(plans):
            t0 = time.perf_counter()
            result = play(Twin(rover, None, dt_s=dt), steps)
            wall += time.perf_counter() - t0
            sim += result.sim_time_s
            p = result.final_pose
            if dt == 0.001:
                reference.append(p)
                continue
            q = reference[i]
            pos_err = max(pos_err, math.hypot(p.x_m - q.x_m, p.y_m - q.y_m))
            yaw_err = max(yaw_err, abs((p.yaw_deg - q.yaw_deg + 180) % 360 - 180))
        label = f"{count} plans, {sim / count:.0f} s each" + (
            " (gate step)" if dt == DEFAULT_DT_S else ""
        )
        print(
            f"{label:<40} {dt * 1e3:>6.0f} {pos_err * 1e3:>11.2f} {yaw_err:>12.3f} "
            f"{sim / wall:>12,.0f}"
        )


# -- 4. HTTP rates -------------------------------------------------------------------------------

BEFORE_COMMIT = "b4a351e"
"""The last commit of the hand-rolled server (``--before`` takes a source tree of it)."""


class _PlainHandler(BaseHTTPRequestHandler):
    """The stdlib way: send_response, headers, end_headers, then the body (two writes)."""

    protocol_version = "HTTP/1.1"
    body = b'{"approved":true}'

    def do_POST(self) -> None:
        self.rfile.read(int(self.headers.get("Content-Length", 0)))
        self.send_response(200)
        self.send_header("Content-Type", "application/json")
        self.send_header("Content-Length", str(len(self.body)))
        self.end_headers()
        self.wfile.write(self.body)

    def log_message(self, format: str, *args: Any) -> None:
        pass


def serve_peer(kind: str) -> None:
    """``--serve-peer KIND``: a trivial JSON handler on a free port, printing ``GATE
    <url>``, until SIGTERM: ``plain`` (http.server), ``stack`` (the gate's stack:
    Starlette on uvicorn through :class:`~firmware_proto.http.HttpService`),
    ``aiohttp`` (the other stack weighed)."""
    import signal

    body = _PlainHandler.body
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    if kind == "plain":
        server = ThreadingHTTPServer(("127.0.0.1", 0), _PlainHandler)
        threading.Thread(target=server.serve_forever, daemon=True).start()
        print(f"GATE http://127.0.0.1:{server.server_address[1]}", flush=True)
        stop.wait()
        server.shutdown()
        server.server_close()
    elif kind == "stack":
        from starlette.requests import Request
        from starlette.responses import Response

        from firmware_proto.http import HttpService, ServeLimits
        from gate.response import render_connection_error

        async def app(scope: Any, receive: Any, send: Any) -> None:
            await Request(scope, receive).body()
            await Response(body, media_type="application/json")(scope, receive, send)

        with HttpService(
            app,
            host="127.0.0.1",
            port=0,
            limits=ServeLimits(),
            render_error=render_connection_error,
            server_name="peer",
            thread_name="peer-http",
        ) as service:
            print(f"GATE {service.url}", flush=True)
            stop.wait()
    elif kind == "aiohttp":
        import asyncio

        from aiohttp import web

        async def handle(request: web.Request) -> web.Response:
            await request.read()
            return web.Response(body=body, content_type="application/json")

        async def run() -> None:
            application = web.Application()
            application.router.add_post("/validate_plan", handle)
            runner = web.AppRunner(application, access_log=None)
            await runner.setup()
            site = web.TCPSite(runner, "127.0.0.1", 0)
            await site.start()
            port = runner.addresses[0][1]
            print(f"GATE http://127.0.0.1:{port}", flush=True)
            while not stop.is_set():
                await asyncio.sleep(0.1)
            await runner.cleanup()

        asyncio.run(run())
    else:
        raise SystemExit(f"unknown peer {kind!r}")


def measure(
    address: tuple[str, int],
    clients: int,
    seconds: float,
    payload: bytes = TRIVIAL_PLAN,
    query: str = "",
) -> tuple[float, list[float]]:
    """``clients`` keep-alive clients posting ``payload`` (default the trivial plan) for
    ``seconds``: the wall time elapsed and every request's latency, s."""
    latencies: list[float] = []
    lock = threading.Lock()
    start = threading.Barrier(clients + 1)
    stop = threading.Event()

    def client() -> None:
        conn = http.client.HTTPConnection(*address, timeout=60)
        mine: list[float] = []
        start.wait()
        while not stop.is_set():
            t0 = time.perf_counter()
            conn.request(
                "POST", "/validate_plan" + query, payload, {"Content-Type": "application/json"}
            )
            response = conn.getresponse()
            response.read()
            mine.append(time.perf_counter() - t0)
            assert response.status == 200
        conn.close()
        with lock:
            latencies.extend(mine)

    threads = [threading.Thread(target=client) for _ in range(clients)]
    for t in threads:
        t.start()
    start.wait()
    t0 = time.perf_counter()
    stop.wait(seconds)
    stop.set()
    for t in threads:
        t.join()
    return time.perf_counter() - t0, latencies


def request_rate(
    address: tuple[str, int],
    clients: int,
    seconds: float,
    payload: bytes = TRIVIAL_PLAN,
    query: str = "",
) -> tuple[float, float, float]:
    """Requests/s, median and 99th-percentile latency (ms) of :func:`measure`."""
    elapsed, latencies = measure(address, clients, seconds, payload, query)
    return (
        len(latencies) / elapsed,
        statistics.median(latencies) * 1e3,
        percentile(latencies, 0.99) * 1e3,
    )


def before_gate(tree: str, pool: str = "process") -> AbstractContextManager[Served]:
    """The gate of the source tree ``tree`` (``--before``), as a subprocess: its packages
    come first on ``sys.path`` (before this checkout and the editable install; worker
    processes inherit the path)."""
    code = (
        f"import sys; sys.path.insert(0, {tree!r}); from gate.cli_gate import main; "
        "import gate; assert gate.__file__.startswith(sys.path[0]), gate.__file__; "
        "sys.exit(main(sys.argv[1:]))"
    )
    argv = [sys.executable, "-c", code, "--port", "0", "--pool", pool, "--workers", "2"]
    return server_process(argv, {})


def _peer(kind: str) -> Callable[[], AbstractContextManager[Served]]:
    return lambda: server_process(
        [sys.executable, "-m", "benchmarks.bench_gate", "--serve-peer", kind], {}
    )


def bench_http(seconds: float, before: str | None, rounds: int = 4) -> None:
    """Table 4. Every server runs at once and the windows are interleaved (``rounds``
    rounds of ``seconds / rounds`` per server and client count), so that the load of a
    shared machine falls on all of them alike."""
    cases: list[tuple[str, Callable[[], AbstractContextManager[Served]]]] = []
    if before:
        cases.append((f"gate before ({Path(before).name})", lambda: before_gate(before)))
    cases.append(("gate after (uvicorn + h11), processes", lambda: gate_process({})))
    if before:
        cases.append(
            (
                f"gate before ({Path(before).name}), worker threads",
                lambda: before_gate(before, "thread"),
            )
        )
    cases += [
        ("gate after, worker threads", lambda: gate_process({}, pool="thread")),
        ("peer: the stack alone (Starlette/uvicorn)", _peer("stack")),
    ]
    try:
        import aiohttp  # noqa: F401

        cases.append(("peer: aiohttp alone", _peer("aiohttp")))
    except ImportError:
        print("(aiohttp is not installed: its row is left out; pip install aiohttp to add it)")
    cases.append(("peer: plain http.server (Nagle stall)", _peer("plain")))
    header = (
        f"{'trivial plan, keep-alive':<42} {'1 client req/s':>15} {'p50 ms':>7} {'p99 ms':>7} "
        f"{'4 clients req/s':>16} {'p50 ms':>7} {'p99 ms':>7}"
    )
    window = seconds / rounds
    with ExitStack() as stack:
        addresses = [stack.enter_context(start()).address for _, start in cases]
        for address in addresses:
            measure(address, 1, 0.3)  # warm-up
        results: dict[tuple[int, int], tuple[float, list[float]]] = {
            (i, n): (0.0, []) for i in range(len(cases)) for n in (1, 4)
        }
        for _ in range(rounds):
            for i, address in enumerate(addresses):
                for n in (1, 4):
                    elapsed, latencies = measure(address, n, window)
                    total, seen = results[i, n]
                    results[i, n] = (total + elapsed, seen + latencies)
    print(header)
    print("-" * len(header))
    for i, (name, _) in enumerate(cases):
        cells = []
        for n in (1, 4):
            elapsed, latencies = results[i, n]
            cells.append(
                (
                    len(latencies) / elapsed,
                    statistics.median(latencies) * 1e3,
                    percentile(latencies, 0.99) * 1e3,
                )
            )
        (r1, m1, q1), (r4, m4, q4) = cells
        print(f"{name:<42} {r1:>15,.0f} {m1:>7.2f} {q1:>7.2f} {r4:>16,.0f} {m4:>7.2f} {q4:>7.2f}")
    print(
        f"all servers up at once, {rounds} interleaved rounds; clients are threads of this "
        "process on the same 2 cores; the servers are subprocesses."
    )


def bench_pools(
    rover: RoverDescription, seconds: float, before: str | None, rounds: int = 3
) -> None:
    """Table 5 (module docstring), interleaved as table 4."""
    payload = json.dumps(as_plan_json(square_plan(rover), (1.0, 4.0, 0.0))).encode()
    query = "?map=scn01"
    cases: list[tuple[str, Callable[[], AbstractContextManager[Served]]]] = []
    if before:
        cases.append((f"before ({Path(before).name}), processes", lambda: before_gate(before)))
    cases += [
        ("worker processes (as shipped)", lambda: gate_process({})),
        ("worker threads", lambda: gate_process({}, pool="thread")),
    ]
    header = (
        f"{'12-step plan, keep-alive, 2 workers':<34} {'1 client req/s':>15} {'gate CPU':>9} "
        f"{'4 clients req/s':>16} {'gate CPU':>9} {'p50 ms':>7} {'p99 ms':>7}"
    )
    window = seconds / rounds
    with ExitStack() as stack:
        served = [stack.enter_context(start()) for _, start in cases]
        for server in served:
            measure(server.address, 2, 0.5, payload, query)  # warm-up
        totals: dict[tuple[int, int], tuple[float, float, list[float]]] = {
            (i, n): (0.0, 0.0, []) for i in range(len(cases)) for n in (1, 4)
        }
        for _ in range(rounds):
            for i, server in enumerate(served):
                for n in (1, 4):
                    cpu0 = tree_cpu_s(server.pid)
                    elapsed, latencies = measure(server.address, n, window, payload, query)
                    wall, cpu, seen = totals[i, n]
                    totals[i, n] = (
                        wall + elapsed,
                        cpu + tree_cpu_s(server.pid) - cpu0,
                        seen + latencies,
                    )
    print(header)
    print("-" * len(header))
    for i, (name, _) in enumerate(cases):
        (w1, c1, l1), (w4, c4, l4) = totals[i, 1], totals[i, 4]
        print(
            f"{name:<34} {len(l1) / w1:>15,.1f} {c1 / w1:>8.0%} {len(l4) / w4:>16,.1f} "
            f"{c4 / w4:>8.0%} {statistics.median(l4) * 1e3:>7.1f} {percentile(l4, 0.99) * 1e3:>7.1f}"
        )
    print(
        "gate CPU: CPU seconds of the gate and its workers per wall second (200% = both "
        "cores); p50/p99: 4 clients."
    )


def _echo(value: int) -> int:
    """A call that costs nothing: what a hand-off between processes costs alone."""
    return value


def _spin(seconds: float) -> float:
    """A call that runs ``seconds`` in the interpreter (interruptible)."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        pass
    return seconds


def _nothing() -> None:
    """The initializer of the executor (what the gate's pool does at a worker's start)."""


def bench_handoff(rover: RoverDescription, calls: int) -> None:
    """Table 6 (module docstring)."""
    import asyncio
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    from gate.pool import ProcessWorkerPool

    maps = {"lab": load_map("lab")}
    validator = Validator(rover, maps, GateConfig().playback, "lab")

    async def round_trips(submit: Callable[[int], Any], width: int) -> list[float]:
        out: list[float] = []

        async def one(i: int) -> None:
            t0 = time.perf_counter()
            await asyncio.wrap_future(submit(i))
            out.append(time.perf_counter() - t0)

        for i in range(0, calls, width):
            await asyncio.gather(*(one(i + k) for k in range(width)))
        return out

    rows: list[tuple[str, int, list[float]]] = []
    with ProcessWorkerPool(validator, 2) as pool:
        for width in (1, 4):
            asyncio.run(round_trips(lambda i: pool.submit_call(_echo, i), 4))  # warm
            rows.append(
                (
                    "gate pool (ProcessWorkerPool)",
                    width,
                    asyncio.run(round_trips(lambda i: pool.submit_call(_echo, i), width)),
                )
            )
        stop_s = []
        for _ in range(10):
            future = pool.submit_call(_spin, 30.0)
            deadline = time.monotonic() + 30
            while not future.running() and time.monotonic() < deadline:
                time.sleep(0.001)
            time.sleep(0.05)
            t0 = time.perf_counter()
            pool.cancel(future)
            with contextlib.suppress(Exception):
                future.result(60)
            stop_s.append(time.perf_counter() - t0)
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(2, mp_context=context, initializer=_nothing) as executor:
        for width in (1, 4):
            asyncio.run(round_trips(lambda i: executor.submit(_echo, i), 4))
            rows.append(
                (
                    "peer: ProcessPoolExecutor (spawn)",
                    width,
                    asyncio.run(round_trips(lambda i: executor.submit(_echo, i), width)),
                )
            )
    print(
        f"{'a trivial call from an event loop, 2 workers':<46} {'at once':>8} {'n':>6} "
        f"{'p50 us':>8} {'p99 us':>8}"
    )
    print("-" * 80)
    for name, width, values in rows:
        print(
            f"{name:<46} {width:>8} {len(values):>6} {statistics.median(values) * 1e6:>8.0f} "
            f"{percentile(values, 0.99) * 1e6:>8.0f}"
        )
    print(
        f"stopping a running call: gate pool {statistics.median(stop_s) * 1e3:.1f} ms p50, "
        f"{max(stop_s) * 1e3:.1f} ms max (interrupted; the worker kept); "
        "ProcessPoolExecutor: not possible (Future.cancel refuses a running call)."
    )


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--repeat", type=int, default=30, help="plan repetitions (default 30)")
    parser.add_argument("--seconds", type=float, default=2.0, help="per HTTP case and client count")
    parser.add_argument("--plans", type=int, default=8, help="random plans for the step-size table")
    parser.add_argument(
        "--before",
        metavar="DIR",
        help=f"a source tree of the hand-rolled server ({BEFORE_COMMIT}) to measure beside "
        f"this one, e.g. from `git archive {BEFORE_COMMIT} | tar -x -C DIR`",
    )
    parser.add_argument("--http-only", action="store_true", help="only the HTTP tables (4-6)")
    parser.add_argument(
        "--table",
        type=int,
        action="append",
        choices=range(1, 7),
        metavar="N",
        help="only table N (1-6; repeatable; default all)",
    )
    parser.add_argument(
        "--rounds", type=int, default=4, help="interleaved rounds of tables 4 and 5 (default 4)"
    )
    parser.add_argument(
        "--serve-peer", choices=("plain", "stack", "aiohttp"), help=argparse.SUPPRESS
    )
    args = parser.parse_args(argv)
    if args.serve_peer:
        serve_peer(args.serve_peer)
        return
    rover = load_rover()
    print(
        f"gate benchmark: Python {platform.python_version()}, pymunk {pymunk.version}, "
        f"{platform.machine()}, {os.cpu_count()} CPUs"
    )
    print()
    tables = set(args.table or ((4, 5, 6) if args.http_only else range(1, 7)))
    rounds = max(1, args.rounds)
    benches: list[tuple[int, Callable[[], None]]] = [
        (1, lambda: bench_plan(rover, max(3, args.repeat), args.before)),
        (2, lambda: bench_collision(rover)),
        (3, lambda: bench_step_size(rover, max(1, args.plans))),
        (4, lambda: bench_http(args.seconds, args.before, rounds)),
        # slow requests: longer
        (5, lambda: bench_pools(rover, 2 * args.seconds, args.before, rounds)),
        (6, lambda: bench_handoff(rover, 400)),
    ]
    printed = False
    for number, bench in benches:
        if number in tables:
            if printed:
                print()
            bench()
            printed = True


if __name__ == "__main__":
    main()
