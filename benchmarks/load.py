"""A load generator of our own: N busy processes, each bounded in time.

Run beside anything that must keep time::

    .venv/bin/python -m benchmarks.load --busy 4 --duration 600

Each process spins ``while True: pass`` at normal priority (a perception stack or a
build on the rover's computer) and ends by itself after ``--duration`` seconds, so a
load left behind by a crash cannot outlive it. :class:`BusyLoad` is the same as a
context manager for the benchmarks.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import subprocess
import sys
import time
from types import TracebackType

__all__ = ["BusyLoad"]

# A child asks for normal scheduling (it inherits a real-time parent's) and ends when
# its parent goes (a killed benchmark must not leave busy loops behind).
_SPIN = (
    "import os, sys, time\n"
    "os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))\n"
    "end = time.monotonic() + float(sys.argv[1])\n"
    "parent = int(sys.argv[2])\n"
    "while time.monotonic() < end and os.getppid() == parent:\n"
    "    for _ in range(10000):\n"
    "        pass\n"
)


class BusyLoad:
    """``count`` busy processes for at most ``duration_s``, ended on exit or when this process ends."""

    def __init__(self, count: int, duration_s: float = 3600.0) -> None:
        if count < 0 or not duration_s > 0:
            raise ValueError("count must be >= 0 and duration > 0")
        self.count = count
        self.duration_s = duration_s
        self._procs: list[subprocess.Popen[bytes]] = []

    def start(self) -> BusyLoad:
        """Start the processes."""
        for _ in range(self.count):
            self._procs.append(
                subprocess.Popen(
                    [sys.executable, "-c", _SPIN, str(self.duration_s), str(os.getpid())],
                    stdin=subprocess.DEVNULL,
                )
            )
        return self

    def stop(self) -> None:
        """End every process (idempotent)."""
        for proc in self._procs:
            if proc.poll() is None:
                proc.kill()
        for proc in self._procs:
            proc.wait(10)
        self._procs.clear()

    def __enter__(self) -> BusyLoad:
        return self.start()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.stop()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--busy", type=int, default=4, help="busy processes (default 4)")
    parser.add_argument(
        "--duration", type=float, default=600.0, help="seconds before they end (default 600)"
    )
    args = parser.parse_args(argv)
    if args.busy < 1 or not args.duration > 0:
        parser.error("--busy must be >= 1 and --duration > 0")
    print(f"{args.busy} busy processes for {args.duration:g} s (Ctrl-C ends them)", flush=True)
    with BusyLoad(args.busy, args.duration), contextlib.suppress(KeyboardInterrupt):
        time.sleep(args.duration)
    return 0


if __name__ == "__main__":
    sys.exit(main())
