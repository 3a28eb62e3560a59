"""The operator's commands against a running stack: ``rover status``, ``stop``,
``clear-stop`` and ``echo``, each timed from its start to its exit (what the operator
waits for), through the stack's console socket and over ROS 2 (``--ros --namespace /``:
the bridge's own topics, the same side as the console, so that the difference is the
path, not the emulated link), in the same run, idle and beside busy processes.

Run (in the private network namespace, as the tests run)::

    unshare -n -- bash -c 'ip link set lo up && ip link set lo multicast on &&
        exec .venv/bin/python -m benchmarks.bench_console --busy 0,4 --runs 20'

One ``rover stack up --speed 4`` serves every case. Each command is a fresh process of
the ``rover`` command line, as typed at a console; ``stop`` and ``clear-stop`` alternate,
so that each STOP finds the rover released. The limit is issue #41's: 1 s p99.
``--quick`` (the smoke test) runs 2 of each through the console only, idle.
"""

from __future__ import annotations

import argparse
import ctypes
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks.common import summary, table
from benchmarks.load import BusyLoad

__all__ = ["main"]

_COMMANDS: list[tuple[str, list[str]]] = [
    ("status", ["status"]),
    ("stop", ["stop"]),
    ("clear-stop", ["clear-stop"]),
    ("echo command_status --count 1", ["echo", "command_status", "--count", "1"]),
]
_ROS = ["--ros", "--namespace", "/"]
_CALL_TIMEOUT_S = 60.0
LIMIT_S = 1.0
"""Issue #41's bound: each command answers within 1 s, p99."""


def _rover(args: list[str], env: dict[str, str]) -> tuple[float, int, str]:
    """Run ``rover ARGS``; its wall time (s), exit status and last line of output."""
    t0 = time.perf_counter()
    try:
        out = subprocess.run(
            [sys.executable, "-m", "firmware_proto.cli", *args, "--timeout", "10"],
            capture_output=True,
            text=True,
            timeout=_CALL_TIMEOUT_S,
            env=env,
            check=False,
        )
    except subprocess.TimeoutExpired:
        return time.perf_counter() - t0, -1, f"no exit within {_CALL_TIMEOUT_S:g} s"
    took = time.perf_counter() - t0
    text = (out.stdout + out.stderr).strip().splitlines()
    return took, out.returncode, text[-1] if text else ""


def _end_with_parent() -> None:
    """In the stack's process, before it runs: SIGTERM when this benchmark dies (a test's
    time limit kills it), so that the stack stops its parts instead of leaving them."""
    libc = ctypes.CDLL(None, use_errno=True)
    pr_set_pdeathsig = 1
    libc.prctl(pr_set_pdeathsig, signal.SIGTERM)


class _Stack:
    """``rover stack up --speed 4`` until closed; its export line as an environment."""

    def __init__(self, directory: Path) -> None:
        # The stack claims its ROS domain where the caller's stacks do (the test run's
        # directory), so that it never shares one with another stack.
        self.env = {"ROVER_STACK_DIR": str(directory), **os.environ}
        self._log = (directory / "stack.out").open("w")
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "firmware_proto.cli", "stack", "up", "--speed", "4"],
            stdout=self._log,
            stderr=subprocess.STDOUT,
            env=self.env,
            preexec_fn=_end_with_parent,  # noqa: PLW1509 (no other thread runs yet here)
        )
        deadline = time.monotonic() + 180
        text = ""
        while "STACK UP" not in text:
            if time.monotonic() > deadline or self.proc.poll() is not None:
                self.close()
                raise RuntimeError(f"the stack did not come up: {text[-2000:]}")
            time.sleep(0.5)
            text = (directory / "stack.out").read_text()
        line = next(x for x in text.splitlines() if x.strip().startswith("export "))
        for item in line.strip()[len("export ") :].split():
            name, _, value = item.partition("=")
            self.env[name] = value

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(2)
            try:
                self.proc.wait(60)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(10)
        self._log.close()


def _measure(env: dict[str, str], runs: int, paths: list[str]) -> dict[str, list[float]]:
    times: dict[str, list[float]] = {}
    failures: list[str] = []
    for _ in range(runs):
        for name, args in _COMMANDS:
            for path in paths:
                full = [*args, *(_ROS if path == "ROS 2" else [])]
                took, status, last = _rover(full, env)
                ok = status in (0, 3)  # 3: status says the rover is held (it is, after stop)
                key = f"rover {name} ({path})"
                if ok:
                    times.setdefault(key, []).append(took)
                else:
                    failures.append(f"{key}: exit {status}: {last}")
    for failure in failures:
        print(f"failed (not in the table): {failure}", flush=True)
    return times


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--busy", default="0,4", help="busy processes, comma-separated (0,4)")
    p.add_argument("--runs", type=int, default=20, help="runs of each command on each path")
    p.add_argument(
        "--quick", action="store_true", help="2 runs through the console only, idle (smoke)"
    )
    args = p.parse_args(argv)
    busies = [0] if args.quick else [int(x) for x in args.busy.split(",")]
    runs = 2 if args.quick else args.runs
    paths = ["console"] if args.quick else ["console", "ROS 2"]
    with tempfile.TemporaryDirectory(prefix="rover-bench-console-") as tmp:
        stack = _Stack(Path(tmp))
        try:
            for busy in busies:
                with BusyLoad(busy, duration_s=3600):
                    load = os.getloadavg()[0]
                    times = _measure(stack.env, runs, paths)
                rows = [(key, summary(values)) for key, values in sorted(times.items())]
                print(
                    table(
                        f"Operator commands against a running stack, beside {busy} busy "
                        f"processes (wall time of each command, start to exit; the "
                        f"machine's load average {load:.1f} as it began)",
                        rows,
                        f"limit: {LIMIT_S * 1e3:.0f} ms p99 (issue #41). Console: the "
                        "stack's console socket (no ROS 2 in the command). ROS 2: "
                        "--ros --namespace / (the bridge's own topics, discovery in each "
                        "command).",
                    )
                )
                print(flush=True)
        finally:
            stack.close()
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
