"""Live view benchmark: push latency to a browser, and the view's CPU beside the mission's.

1. **Push latency, synthetic feed** (always): a :class:`~planner.view.ViewHub` and its
   server on 127.0.0.1 fed poses as the ground station's port tap feeds them (odometry
   at ``--odom-hz``, the reported pose at a fifth of that) for ``--seconds``; latency
   from the tap to the client parsing the event, on the shared wall clock. Clients:
   headless Chromium through Playwright (``--browser``) and a plain Python client on a
   socket (the peer); the limit is the view's 10 Hz update period.
2. **The demo with the view** (``--demo``; ROS 2 in the private network namespace):
   ``rover demo --view`` with Chromium on the page; CPU per wall second of mission of
   the view's threads beside the rest of the ground station's process and the
   browser's, and the page's latencies of the mission's real poses.

Run it (the demo part as the tests run, in a private network namespace)::

    .venv/bin/python -m benchmarks.bench_view --browser
    unshare -n -- bash -c 'ip link set lo up && ip link set lo multicast on &&
        exec .venv/bin/python -m benchmarks.bench_view --browser --demo'
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import resource
import shutil
import socket
import sys
import threading
import time
from pathlib import Path
from typing import Any

from benchmarks.common import summary, table
from bridge.ros.rosport.msgs import Odometry
from firmware_proto.model.worldmap import load_map
from planner.view import ViewConfig, ViewHub, ViewServer

WORLD = "lab"
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]


def _odom(x: float, y: float) -> Odometry:
    msg = Odometry()
    msg.pose.pose.position.x = x
    msg.pose.pose.position.y = y
    msg.pose.pose.orientation.w = 1.0
    return msg


def _cpu_of_threads(prefix: str) -> float:
    """CPU seconds of the live threads whose name starts with ``prefix``."""
    total = 0.0
    for t in threading.enumerate():
        if t.name.startswith(prefix) and t.ident is not None and t.is_alive():
            try:
                total += time.clock_gettime(time.pthread_getcpuclockid(t.ident))
            except (OSError, ProcessLookupError):
                continue
    return total


def _process_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def _descendants_cpu(root: int) -> float:
    """CPU seconds of every live descendant process of ``root`` (the browser's)."""
    ticks = os.sysconf("SC_CLK_TCK")
    parents: dict[int, int] = {}
    cpu: dict[int, float] = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:
            continue
        fields = stat.rsplit(")", 1)[1].split()
        parents[int(entry.name)] = int(fields[1])
        cpu[int(entry.name)] = (int(fields[11]) + int(fields[12])) / ticks
    total = 0.0
    for pid, seconds in cpu.items():
        p = pid
        while p in parents and p not in (0, 1):
            p = parents[p]
            if p == root:
                total += seconds
                break
    return total


class _SseClient:
    """The peer: a plain socket reading the push channel, timing each pose event."""

    def __init__(self, url: str) -> None:
        host, port = url.split("//")[1].split("/", maxsplit=1)[0].rsplit(":", 1)
        self.sock = socket.create_connection((host, int(port)), timeout=10)
        self.sock.sendall(f"GET /events HTTP/1.1\r\nHost: {host}:{port}\r\n\r\n".encode())
        self.latencies: list[float] = []
        self._thread = threading.Thread(target=self._read, name="bench-sse", daemon=True)
        self._thread.start()

    def _read(self) -> None:
        event = ""
        with self.sock.makefile("rb") as f:
            try:
                for raw in f:
                    line = raw.decode()
                    if line.startswith("event: "):
                        event = line[7:].strip()
                    elif line.startswith("data: ") and event == "pose":
                        now = time.time()
                        data = json.loads(line[6:])
                        if data.get("tap_s"):
                            self.latencies.append(now - data["tap_s"])
            except OSError:
                return

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self.sock.shutdown(socket.SHUT_RDWR)
        self.sock.close()
        self._thread.join(5.0)


def _with_browser(url: str, ready: threading.Event, done: threading.Event) -> dict[str, Any]:
    """Open ``url`` in headless Chromium, set ``ready`` once the page is live, keep it
    until ``done``; the page's pose latencies and this thread's CPU."""
    from playwright.sync_api import sync_playwright

    out: dict[str, Any] = {"latencies": []}
    path = os.environ.get("ROVER_CHROMIUM") or shutil.which("chromium")
    if path is None:
        raise SystemExit("no chromium: apt-get install chromium")
    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=path, headless=True, args=CHROMIUM_ARGS)
        try:
            page = browser.new_page(viewport={"width": 1200, "height": 700})
            page.goto(url)
            page.wait_for_function("() => window.roverView.connected", timeout=30_000)
            ready.set()
            while not done.wait(0.5):
                page.evaluate("0")  # keep the driver's loop turning
            out["latencies"] = page.evaluate("window.roverView.latencies")
        finally:
            browser.close()
    out["driver_thread_cpu_s"] = time.thread_time()
    return out


def synthetic(seconds: float, odom_hz: float, browser: bool) -> str:
    hub = ViewHub(load_map(WORLD), rtt_s=3.0).start()
    server = ViewServer(hub, ViewConfig(), on_stop=lambda: "benchmark").start()
    results: dict[str, Any] = {}
    ready = threading.Event()
    done = threading.Event()
    browser_thread = None
    if browser:
        browser_thread = threading.Thread(
            target=lambda: results.update(_with_browser(server.url, ready, done)),
            name="bench-browser",
        )
        browser_thread.start()
        if not ready.wait(60):
            raise SystemExit("the browser did not open the page")
    client = _SseClient(server.url)
    try:
        period = 1.0 / odom_hz
        t0 = time.monotonic()
        cpu0 = _cpu_of_threads("view-")
        browser0 = _descendants_cpu(os.getpid()) if browser else 0.0
        n = 0
        while time.monotonic() - t0 < seconds:
            x = 1.2 + 0.01 * n
            hub.tap("received", "/bench/odom", _odom(x, 3.0))
            if n % 5 == 0:
                hub.tap("received", "/bench/odom_ground", _odom(x, 3.0))
            n += 1
            next_at = t0 + n * period
            time.sleep(max(0.0, next_at - time.monotonic()))
        elapsed = time.monotonic() - t0
        view_cpu = _cpu_of_threads("view-") - cpu0
        browser_cpu = _descendants_cpu(os.getpid()) - browser0 if browser else 0.0
    finally:
        done.set()
        if browser_thread is not None:
            browser_thread.join(60)
        client.close()
        server.close()
        hub.close()
    rows = []
    if browser:
        rows.append(("headless Chromium (EventSource, page JS)", summary(results["latencies"])))
    rows.append(("Python socket client (peer: no browser)", summary(client.latencies)))
    rows.append(
        (
            "limit: the view's update period (10 Hz)",
            {"n": 0, "p50": 100.0, "p95": 100.0, "p99": 100.0, "max": 100.0},
        )
    )
    out = [
        table(
            f"Push latency, tap to client, synthetic feed: odometry {odom_hz:g} Hz + "
            f"reported pose {odom_hz / 5:g} Hz for {elapsed:.1f} s",
            rows,
            "The clients were connected at once; ms on the wall clock they share.",
        ),
        "",
        f"View threads' CPU during the feed: {view_cpu * 1e3 / elapsed:.1f} ms per second "
        f"({hub.records} events, {1.2 * odom_hz:g} poses/s)",
    ]
    if browser:
        out.append(
            f"Headless Chromium's CPU showing the page: {browser_cpu * 1e3 / elapsed:.1f} ms "
            "per second (all its processes)"
        )
    return "\n".join(out)


def demo(speed: float, browser: bool) -> str:
    from planner.stack.demo import Demo, DemoConfig

    marks: dict[str, float] = {}
    url = threading.Event()
    ready = threading.Event()
    done = threading.Event()
    results: dict[str, Any] = {}
    browser_thread: threading.Thread | None = None

    def say(line: str) -> None:
        print(line, flush=True)
        if line.startswith("VIEW "):
            results["url"] = line.split()[1]
            url.set()
        if "] mission: " in line:
            marks["t0"] = time.monotonic()
            marks["cpu0"] = _process_cpu()
            marks["view0"] = _cpu_of_threads("view-")
            marks["browser0"] = _descendants_cpu(os.getpid()) if browser else 0.0

    config = DemoConfig(
        speed=speed, record=None, picture=Path("/tmp/bench_view_demo.png"), view=ViewConfig()
    )

    def start_browser() -> None:
        if url.wait(120):
            results.update(_with_browser(results["url"], ready, done))

    with Demo(config, say=say) as the_demo:
        if browser:
            browser_thread = threading.Thread(target=start_browser, name="bench-browser")
            browser_thread.start()
        try:
            result = the_demo.run()
            t1 = time.monotonic()
            cpu1 = _process_cpu()
            view1 = _cpu_of_threads("view-")
            browser1 = _descendants_cpu(os.getpid()) if browser else 0.0
        finally:
            done.set()
            if browser_thread is not None:
                browser_thread.join(60)
    seconds = t1 - marks["t0"]
    view_s = view1 - marks["view0"]
    # The browser driver's thread runs in this process too: not the mission's cost.
    driver_s = results.get("driver_thread_cpu_s", 0.0) if browser else 0.0
    own_s = (cpu1 - marks["cpu0"]) - view_s - driver_s
    browser_s = browser1 - marks.get("browser0", 0.0)
    lines = [
        f"CPU per second of mission, rover demo --view --speed {speed:g} "
        f"({seconds:.1f} s wall from the mission line to the end; "
        f"{'REACHED' if result.report.reached else 'not reached'})",
        "",
        "| what | CPU ms per mission second | share of one core |",
        "|---|---:|---:|",
        f"| the mission's own (ground station process, view excluded) | {own_s / seconds * 1e3:.1f} "
        f"| {own_s / seconds * 100:.1f}% |",
        f"| the live view (hub, HTTP, connections) | {view_s / seconds * 1e3:.1f} "
        f"| {view_s / seconds * 100:.1f}% |",
    ]
    if browser:
        lines.append(
            f"| headless Chromium showing the page (all its processes) | "
            f"{browser_s / seconds * 1e3:.1f} | {browser_s / seconds * 100:.1f}% |"
        )
        lines += [
            "",
            table(
                "Push latency of the mission's poses, ground station tap to the page",
                [("headless Chromium, rover demo --view", summary(results["latencies"]))],
            ),
        ]
    lines.append(
        "\nThe rover side (emulator, bridge, link, gate processes) is not counted in either."
    )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--seconds", type=float, default=20.0, help="synthetic feed length")
    parser.add_argument("--odom-hz", type=float, default=50.0, help="synthetic odometry rate")
    parser.add_argument("--browser", action="store_true", help="also time headless Chromium")
    parser.add_argument("--demo", action="store_true", help="also run rover demo --view")
    parser.add_argument("--speed", type=float, default=1.0, help="the demo's --speed")
    parser.add_argument("--quick", action="store_true", help="2 s synthetic feed, no demo")
    args = parser.parse_args(argv)
    seconds = 2.0 if args.quick else args.seconds
    print(synthetic(seconds, args.odom_hz, args.browser))
    sys.stdout.flush()
    if args.demo and not args.quick:
        print()
        print(demo(args.speed, args.browser))


if __name__ == "__main__":
    main()
