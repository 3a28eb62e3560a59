"""A ``rover`` subcommand run as a child process, its output collected as it comes."""

from __future__ import annotations

import subprocess
import sys
import threading
import time
from collections.abc import Mapping
from typing import IO


def run_rover(
    *args: str, env: Mapping[str, str] | None = None, timeout_s: float = 120.0
) -> subprocess.CompletedProcess[str]:
    """``rover ARGS`` run to its end (``python -m firmware_proto.cli``), its output
    captured as text, whatever its exit status; in ``env`` (default: this process's),
    killed after ``timeout_s`` (``subprocess.TimeoutExpired``)."""
    return subprocess.run(
        [sys.executable, "-m", "firmware_proto.cli", *args],
        capture_output=True,
        text=True,
        timeout=timeout_s,
        env=None if env is None else dict(env),
        check=False,
    )


class Child:
    """A ``rover`` subprocess whose stdout and stderr lines are collected as they come."""

    def __init__(self, args: list[str], env: dict[str, str]) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "firmware_proto.cli", *args],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env=env,
        )
        self.lines: list[str] = []
        self.errors: list[str] = []
        self._new = threading.Condition()
        self._readers = [
            threading.Thread(target=self._read, args=(self.proc.stdout, self.lines), daemon=True),
            threading.Thread(target=self._read, args=(self.proc.stderr, self.errors), daemon=True),
        ]
        for reader in self._readers:
            reader.start()

    def _read(self, stream: IO[str], into: list[str]) -> None:
        for line in stream:
            with self._new:
                into.append(line.rstrip())
                self._new.notify_all()
        with self._new:
            self._new.notify_all()

    def wait_for(self, needle: str, timeout_s: float = 60.0) -> str:
        """The first stdout line containing ``needle``."""
        deadline = time.monotonic() + timeout_s
        with self._new:
            while True:
                hit = next((x for x in self.lines if needle in x), None)
                if hit is not None:
                    return hit
                left = deadline - time.monotonic()
                if left <= 0 or not self._readers[0].is_alive():
                    raise AssertionError(f"no line with {needle!r}: {self.lines[-10:]}")
                self._new.wait(left)

    def wait(self, timeout_s: float) -> int:
        """Wait for the process to end and its output to be read; its exit status."""
        status = self.proc.wait(timeout_s)
        for reader in self._readers:
            reader.join(5)
        for stream in (self.proc.stdout, self.proc.stderr):
            if stream is not None:
                stream.close()
        return status

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(15)
            except subprocess.TimeoutExpired:
                self.proc.kill()
        self.wait(5)
