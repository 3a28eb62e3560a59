"""Hostile clients against the live view and the gate, timed.

Each table sets a figure beside load against the same figure unloaded, measured in the
same run on the same machine; ``--before DIR`` adds to tables 1 and 3 the rows of
another tree (``git archive <commit> | tar -x -C DIR``), served with ``PYTHONPATH=DIR``.

1. **The view's STOP beside a flood of ``GET /state``** (``--view``): a view server
   whose hub holds full trails (5,000 points each) and is fed odometry at 50 Hz; a
   flood of ``N`` keep-alive connections from 127.0.0.2 sending ``GET /state`` in
   rounds of 5; ``POST /stop`` from 127.0.0.1 on a fresh connection every 20 ms, timed
   to (a) the answer, (b) ``on_stop``'s call (what stops the wheels). Idle, 100 x 5 and
   300 x 5 (over the per-address limit). A refused STOP (503, reset) counts as
   ``refused``.
2. **An ordinary plan beside a costly one** (``--gate``, two worker processes): client
   A (127.0.0.2) asks for ``samples=2000`` on the slowest valid plan (refused), then
   keeps asking for the most the gate admits; client B (127.0.0.3) posts bench_gate's
   12-step plan in a row. B's latency beside A, against B alone.
3. **``/health`` beside bad bodies** (``--gate``): four clients post 63 kB bodies with
   1,250 schema violations in a loop; a fifth asks ``GET /health`` every 20 ms.

``--busy N`` repeats each table beside ``N`` busy processes (``benchmarks.load``). A
case probes for at most a minute (the ``n`` column says how many probes it had).

Run::

    .venv/bin/python -m benchmarks.bench_hostile --view --gate
    .venv/bin/python -m benchmarks.bench_hostile --view --gate --before /tmp/tree-main --busy 4
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

from benchmarks.common import summary, table
from benchmarks.load import BusyLoad

REPO_ROOT = Path(__file__).resolve().parents[1]
PROBE_PERIOD_S = 0.02
FLOOD_SOURCE = "127.0.0.2"
"""The flood's source address (the STOPs come from 127.0.0.1)."""
TRAIL_POINTS = 5000


# -- subprocess roles ---------------------------------------------------------------------
def _serve_view(trail_points: int) -> int:
    """A view whose hub holds full trails and is fed as a mission feeds it; prints
    ``VIEW <host> <port>`` and serves until stdin closes. STOP answers the monotonic
    time it reached ``on_stop``."""
    from bridge.ros.rosport.msgs import Odometry
    from firmware_proto.model.worldmap import load_map
    from planner.view import ViewConfig, ViewHub, ViewServer

    def odom(x: float, y: float) -> Odometry:
        msg = Odometry()
        msg.pose.pose.position.x = x
        msg.pose.pose.position.y = y
        msg.pose.pose.orientation.w = 1.0
        return msg

    hub = ViewHub(load_map("lab")).start()
    for i in range(trail_points + 10):  # 2 cm apart: every point kept
        hub.tap("received", "/ground/odom_ground", odom(1.0 + 0.02 * (i % 300), 1.0 + i // 300))
        hub.tap("received", "/ground/odom", odom(0.02 * (i % 300), i // 300))
        if i % 500 == 0:
            time.sleep(0.01)  # let the hub keep up (its inbox drops the oldest)
    server = ViewServer(hub, ViewConfig(), on_stop=lambda: f"{time.monotonic():.6f}").start()
    done = threading.Event()

    def feed() -> None:
        i = 0
        while not done.wait(0.02):
            i += 1
            hub.tap("received", "/ground/odom", odom(0.001 * i, 0.0))
            if i % 5 == 0:
                hub.tap("received", "/ground/odom_ground", odom(1.0 + 0.001 * i, 3.0))

    feeder = threading.Thread(target=feed, daemon=True)
    feeder.start()
    host, port = server.url.split("//")[1].split("/")[0].rsplit(":", 1)
    print(f"VIEW {host} {port}", flush=True)
    sys.stdin.read()
    done.set()
    feeder.join(5)
    server.close()
    hub.close()
    return 0


async def _flood(host: str, port: int, conns: int, per_conn: int) -> None:
    """``conns`` keep-alive connections from :data:`FLOOD_SOURCE`, each sending ``GET
    /state`` ``per_conn`` times in a row, in rounds until stdin closes; prints ``FLOOD`` once the first round is
    under way."""
    request = f"GET /state HTTP/1.1\r\nHost: {host}:{port}\r\n\r\n".encode()
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    loop.add_reader(sys.stdin.fileno(), stop.set)

    async def one() -> None:
        while not stop.is_set():
            try:
                reader, writer = await asyncio.open_connection(
                    host, port, local_addr=(FLOOD_SOURCE, 0)
                )
            except OSError:
                await asyncio.sleep(0.05)
                continue
            try:
                for _ in range(per_conn):
                    writer.write(request)
                    head = await reader.readuntil(b"\r\n\r\n")
                    length = 0
                    for line in head.split(b"\r\n"):
                        if line.lower().startswith(b"content-length:"):
                            length = int(line.split(b":", 1)[1])
                    await reader.readexactly(length)
            except (OSError, asyncio.IncompleteReadError):
                pass
            finally:
                writer.close()

    tasks = [asyncio.create_task(one()) for _ in range(conns)]
    print("FLOOD", flush=True)
    await stop.wait()
    for t in tasks:
        t.cancel()
    await asyncio.gather(*tasks, return_exceptions=True)


# -- helpers ------------------------------------------------------------------------------
@contextlib.contextmanager
def _child(
    argv: list[str], tree: Path | None, ready: str
) -> Iterator[tuple[subprocess.Popen[str], list[str]]]:
    """A subprocess of this module (``tree`` first on its path); yields it and the words
    of its first line once that line starts with ``ready``."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(str(p) for p in (tree, REPO_ROOT) if p is not None)
    proc = subprocess.Popen(
        [sys.executable, str(Path(__file__).resolve()), *argv],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
        env=env,
    )
    try:
        assert proc.stdout is not None
        words = proc.stdout.readline().split()
        if not words or words[0] != ready:
            raise RuntimeError(f"{argv[0]} did not start")
        yield proc, words
    finally:
        if proc.stdin is not None:
            with contextlib.suppress(OSError):
                proc.stdin.close()
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            proc.send_signal(signal.SIGKILL)
            proc.wait(10)


def _post_stop(host: str, port: int) -> tuple[float, float | None] | None:
    """One STOP on a fresh connection: (seconds to the whole answer, seconds to
    ``on_stop``'s call or ``None``); ``None`` when it was refused (not 202, or reset)."""
    body = (
        f"POST /stop HTTP/1.1\r\nHost: {host}:{port}\r\nX-Rover-View: 1\r\n"
        "Content-Length: 0\r\nConnection: close\r\n\r\n"
    ).encode()
    t0 = time.monotonic()
    chunks = []
    try:
        with socket.create_connection((host, port), timeout=120) as sock:
            sock.sendall(body)
            while chunk := sock.recv(65536):
                chunks.append(chunk)
    except ConnectionResetError:
        return None
    t1 = time.monotonic()
    answer = b"".join(chunks)
    head, _, rest = answer.partition(b"\r\n\r\n")
    if b" 202 " not in head.split(b"\r\n", 1)[0]:
        return None
    reached = None
    with contextlib.suppress(ValueError, KeyError, TypeError):
        reached = float(json.loads(rest)["stop"]) - t0
    return t1 - t0, reached


CASE_S = 60.0
"""Longest a case probes (a tree where STOP waits seconds gives fewer probes)."""


def _probe_stops(host: str, port: int, count: int) -> tuple[list[float], list[float], int]:
    """``count`` STOPs (at most :data:`CASE_S`): the answers' and the arrivals'
    seconds, and how many were refused."""
    answers: list[float] = []
    reached: list[float] = []
    refused = 0
    end = time.monotonic() + CASE_S
    for _ in range(count):
        if time.monotonic() > end:
            break
        timed = _post_stop(host, port)
        if timed is None:
            refused += 1
        else:
            answers.append(timed[0])
            if timed[1] is not None:
                reached.append(timed[1])
        time.sleep(PROBE_PERIOD_S)
    return answers, reached, refused


def view_table(
    trees: list[tuple[str, Path | None]],
    probes: int,
    floods: list[tuple[int, int]],
    trail_points: int = TRAIL_POINTS,
) -> str:
    """Table 1 (module docstring)."""
    rows: list[tuple[str, dict[str, float]]] = []
    for label, tree in trees:
        with _child(["--serve-view", str(trail_points)], tree, "VIEW") as (_, words):
            host, port = words[1], int(words[2])
            _probe_stops(host, port, 3)  # warm up
            for conns, per_conn in [(0, 0), *floods]:
                case = "idle" if conns == 0 else f"beside {conns} x {per_conn} GET /state"
                if conns == 0:
                    answers, reached, refused = _probe_stops(host, port, probes)
                else:
                    flood = ["--flood", host, str(port), str(conns), str(per_conn)]
                    with _child(flood, None, "FLOOD"):
                        answers, reached, refused = _probe_stops(host, port, probes)
                rows.append((f"{label}: answer, {case}, {refused} refused", summary(answers)))
                if reached:
                    rows.append((f"{label}: STOP reached the mission, {case}", summary(reached)))
    return table(
        "View: POST /stop on a fresh connection, every 20 ms",
        rows,
        "answer: from sending the request to the whole answer; reached: from sending to "
        "on_stop's call (what sets the mission's cancel event). Done when p99 < 100 ms "
        "beside 300 x 5.",
    )


# -- the gate ------------------------------------------------------------------------------
SLOWEST = {
    "goal": {"x": 1.2, "y": 3.0, "yaw_deg": 0.0},
    "commands": [{"command": "FWD", "speed": 1, "distance": 30000}] * 12,
}
SQUARE = {
    "goal": {"x": 1.0, "y": 4.0, "yaw_deg": 0.0},
    "commands": [
        {"command": c, "speed": v, "distance": d}
        for c, v, d in [("FWD", 60, 28750), ("FWD", 60, 28750), ("LEFT", 30, 15484)] * 4
    ],
}
SQUARE_QUERY = "map=scn01&start=1.0,4.0,0"


def _bad_body() -> bytes:
    step = {"command": "JUMP", "speed": 99, "distance": -1}
    return json.dumps({"goal": {"x": 1, "y": 1, "yaw_deg": 0}, "commands": [step] * 1250}).encode()


def _post(
    address: tuple[str, int], body: bytes, query: str = "", source: str | None = None
) -> tuple[int, bytes, float]:
    """One POST /validate_plan on a fresh connection: status, body, seconds."""
    import http.client

    conn = http.client.HTTPConnection(
        *address, timeout=600, source_address=(source, 0) if source else None
    )
    t0 = time.monotonic()
    try:
        conn.request(
            "POST",
            "/validate_plan" + (f"?{query}" if query else ""),
            body,
            {"Content-Type": "application/json"},
        )
        response = conn.getresponse()
        data = response.read()
        return response.status, data, time.monotonic() - t0
    finally:
        conn.close()


def _get(address: tuple[str, int], path: str) -> float:
    import http.client

    conn = http.client.HTTPConnection(*address, timeout=600)
    t0 = time.monotonic()
    try:
        conn.request("GET", path)
        conn.getresponse().read()
        return time.monotonic() - t0
    finally:
        conn.close()


@contextlib.contextmanager
def _gate(tree: Path | None, workers: int = 2) -> Iterator[tuple[str, int]]:
    """``rover gate`` of ``tree`` (this one when ``None``) on a free port."""
    from benchmarks.common import server_process

    env = {"PYTHONPATH": str(tree)} if tree is not None else {}
    # python -m firmware_proto.cli: the rover command of whichever tree is first on the path
    argv = [sys.executable, "-m", "firmware_proto.cli", "gate", "--port", "0"]
    argv += ["--workers", str(workers)]
    with server_process(argv, env) as served:
        yield served.address


def _bad_bodies(host: str, port: int, clients: int) -> int:
    """``clients`` threads posting bad 63 kB bodies until stdin closes; prints ``BAD``."""
    body = _bad_body()
    stop = threading.Event()

    def loop() -> None:
        while not stop.is_set():
            with contextlib.suppress(OSError):
                _post((host, port), body)

    threads = [threading.Thread(target=loop, daemon=True) for _ in range(clients)]
    for t in threads:
        t.start()
    print("BAD", flush=True)
    sys.stdin.read()
    stop.set()
    for t in threads:
        t.join(60)
    return 0


def health_table(trees: list[tuple[str, Path | None]], probes: int) -> str:
    """Table 3 (module docstring)."""
    rows: list[tuple[str, dict[str, float]]] = []
    for label, tree in trees:
        with _gate(tree) as address:
            host, port = address
            _get(address, "/health")
            alone = []
            for _ in range(probes):
                alone.append(_get(address, "/health"))
                time.sleep(PROBE_PERIOD_S)
            rows.append((f"{label}: GET /health, alone", summary(alone)))
            beside = []
            with _child(["--bad-bodies", host, str(port), "4"], None, "BAD"):
                time.sleep(0.5)  # the four clients under way
                for _ in range(probes):
                    beside.append(_get(address, "/health"))
                    time.sleep(PROBE_PERIOD_S)
            rows.append((f"{label}: GET /health, beside 4 x bad 63 kB bodies", summary(beside)))
    return table(
        "Gate: GET /health every 20 ms, alone and beside four clients of bad bodies",
        rows,
        "Bad bodies: 1,250 schema violations in 63 kB, posted in a loop. Done when p99 < "
        "50 ms beside them.",
    )


def fairness_table(rounds: int) -> str:
    """Table 2 (module docstring), this tree only."""
    with _gate(None) as address:
        square = json.dumps(SQUARE).encode()
        _post(address, square, SQUARE_QUERY)  # warm
        alone = [_post(address, square, SQUARE_QUERY, "127.0.0.3")[2] for _ in range(rounds)]
        status, data, _ = _post(address, json.dumps(SLOWEST).encode(), "samples=2000", "127.0.0.2")
        refused = f"samples=2000 on the slowest plan: {status} {json.loads(data).get('error')}"
        most = int(json.loads(data)["message"].split("at most ")[1].split()[0])
        stop = threading.Event()
        costly: list[float] = []

        def a_loop() -> None:
            body = json.dumps(SLOWEST).encode()
            while not stop.is_set():
                code, _, took = _post(address, body, f"samples={most}", "127.0.0.2")
                if code == 200:
                    costly.append(took)

        a = threading.Thread(target=a_loop, daemon=True)
        a.start()
        time.sleep(1.0)  # A's chunks on the workers
        beside = [_post(address, square, SQUARE_QUERY, "127.0.0.3")[2] for _ in range(rounds)]
        stop.set()
        a.join(600)
    rows = [
        ("B: bench_gate's 12-step plan, alone", summary(alone)),
        (f"B: the same, beside A's samples={most} on the slowest plan", summary(beside)),
    ]
    ratio = summary(beside)["p50"] / summary(alone)["p50"]
    return table(
        "Gate (2 worker processes): an ordinary plan from client B beside a costly request "
        "from client A",
        rows,
        f"{refused} (at once, nothing queued); then A asks for samples={most}, the most the "
        f"gate admits for that plan, in a loop ({len(costly)} answered). B's p50 beside A is "
        f"{ratio:.2f}x its p50 alone. Done when within 2x.",
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--view", action="store_true", help="table 1: the view's STOP")
    parser.add_argument("--gate", action="store_true", help="tables 2 and 3: the gate")
    parser.add_argument("--before", type=Path, help="a tree to measure beside this one")
    parser.add_argument("--busy", type=int, default=0, help="also beside N busy processes")
    parser.add_argument("--probes", type=int, default=200, help="STOPs per case")
    parser.add_argument("--quick", action="store_true", help="a few probes, a small flood")
    parser.add_argument("--serve-view", type=int, help=argparse.SUPPRESS)
    parser.add_argument("--flood", nargs=4, help=argparse.SUPPRESS)
    parser.add_argument("--bad-bodies", nargs=3, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.serve_view is not None:
        return _serve_view(args.serve_view)
    if args.flood:
        host, port, conns, per_conn = args.flood
        asyncio.run(_flood(host, int(port), int(conns), int(per_conn)))
        return 0
    if args.bad_bodies:
        host, port, clients = args.bad_bodies
        return _bad_bodies(host, int(port), int(clients))
    trees: list[tuple[str, Path | None]] = [("this tree", None)]
    if args.before is not None:
        trees.insert(0, (f"before ({args.before.name})", args.before))
    probes = 10 if args.quick else args.probes
    floods = [(20, 2)] if args.quick else [(100, 5), (300, 5)]
    trail = 500 if args.quick else TRAIL_POINTS
    loads = [0] + ([args.busy] if args.busy else [])
    for busy in loads:
        with BusyLoad(busy):
            suffix = f" (beside {busy} busy processes)" if busy else " (no other load)"
            if args.view:
                text = view_table(trees, probes, floods, trail)
                print(text.replace("\n", suffix + "\n", 1))
                print()
            if args.gate:
                for text in (
                    fairness_table(5 if args.quick else 40),
                    health_table(trees, probes),
                ):
                    print(text.replace("\n", suffix + "\n", 1))
                    print()
    return 0


if __name__ == "__main__":
    sys.exit(main())
