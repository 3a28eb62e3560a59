"""``rover demo`` and ``rover go`` as a user runs them: real processes, real DDS on
loopback (private network namespace), real HTTP, real pty."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import IO, Any

import pytest

from bridge.rosport import loopback_config
from tests.planner.conftest import MAPS_DIR

pytestmark = pytest.mark.dds


def test_rover_demo_plans_detours_stops_on_drift_replans_and_arrives(tmp_path: Path) -> None:
    picture = tmp_path / "demo.png"
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "firmware_proto.cli",
            "demo",
            "--speed",
            "4",
            "--picture",
            str(picture),
        ],
        capture_output=True,
        text=True,
        timeout=240,
        check=False,
        cwd=tmp_path,
    )
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-3000:]
    text = out.stdout
    assert "collision at step" in text and "(dogleg): approved" in text  # around the table
    assert "INJECTING slip:left" in text
    assert "drift STOP:" in text and "detection to STOP" in text
    assert "re-plan 1:" in text
    assert "REACHED" in text
    assert picture.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def _go(
    url: str, picture: Path, *args: str, timeout_s: float = 60.0
) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [
            sys.executable,
            "-m",
            "firmware_proto.cli",
            "go",
            "--map",
            "lab",
            "--gate",
            url,
            "--rtt",
            "0.1",
            "--picture",
            str(picture),
            *args,
        ],
        capture_output=True,
        text=True,
        timeout=timeout_s,
        check=False,
        env={**os.environ, "CYCLONEDDS_URI": loopback_config()},
    )


def test_rover_go_refuses_bad_goals_and_options_cleanly(
    tmp_path: Path, gate_process_url: str
) -> None:
    picture = tmp_path / "m.png"
    for args, status, complaint in (
        (["--goal", "3.9,3.0,0"], 1, "obstacle 'table'"),  # checked before waiting for the rover
        (["--goal", "9.5,3.0,0"], 1, "outside map 'lab'"),
        (["--goal", "nan,1,0"], 2, "not finite"),
        (["--goal", "1,2"], 2, "X,Y,YAW_DEG"),
        (["--goal", "2,3,0", "--start", "1,inf,0"], 2, "not finite"),
        (["--goal", "2,3,0", "--drift-linear", "0"], 2, "--drift-linear: must be finite and > 0"),
        (["--goal", "2,3,0", "--drift-angular", "nan"], 2, "--drift-angular"),
        (["--goal", "2,3,0", "--drift-samples", "1.5"], 2, "--drift-samples"),
    ):
        out = _go(gate_process_url, picture, *args)
        assert out.returncode == status, (args, out.stdout + out.stderr)
        assert "Traceback" not in out.stderr, out.stderr
        # One error line (a usage error comes after the usage synopsis).
        last = out.stderr.strip().splitlines()[-1]
        assert last.startswith("rover go: error: ") and complaint in last, (args, out.stderr)
        assert out.stderr.count("error:") == 1, out.stderr
    assert not picture.exists()


def test_rover_go_without_a_reporting_rover_sends_nothing(
    tmp_path: Path, gate_process_url: str
) -> None:
    """No bridge, no link: no pose comes, and without --start nothing is assumed."""
    out = _go(gate_process_url, tmp_path / "m.png", "--goal", "2.7,3.0,0", "--pose-wait", "2")
    assert out.returncode == 1, out.stdout + out.stderr
    assert "the rover reported no pose" in out.stderr and "--start" in out.stderr
    assert "Traceback" not in out.stderr
    assert "step 1/" not in out.stdout


def test_rover_go_move_and_wait_plans_without_an_unreachable_gate_from_a_map_file(
    tmp_path: Path,
) -> None:
    with socket.socket() as probe:  # a port nobody listens on
        probe.bind(("127.0.0.1", 0))
        url = f"http://127.0.0.1:{probe.getsockname()[1]}"
    common = ["--move-and-wait", "--goal", "2.7,3.0,0", "--start", "1.2,3.0,0"]
    out = _go(url, tmp_path / "m.png", *common)  # --map lab: a name only the gate knows
    assert out.returncode == 1, out.stdout + out.stderr
    assert "is not answering" in out.stderr and "--map FILE.json" in out.stderr
    lab = MAPS_DIR / "lab.json"
    out = _go(url, tmp_path / "m.png", *common, "--map", str(lab), "--time-scale", "4")
    # No rover here either: the first command times out, and the rover is sent STOP.
    assert out.returncode == 1, out.stdout + out.stderr
    assert "the route is planned by the heuristic planner alone and NOT validated" in out.stdout
    assert "NOT REACHED (step 0 got no 'completed' in time" in out.stdout
    assert "Traceback" not in out.stderr


class _Child:
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


def _status(port: int) -> dict[str, Any]:
    with socket.create_connection(("127.0.0.1", port), timeout=5) as sock:
        sock.sendall(b"status\n")
        answer = json.loads(sock.makefile().readline())
    assert answer["ok"], answer
    status: dict[str, Any] = answer["status"]
    return status


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_rover_go_interrupted_mid_step_stops_the_rover_and_says_cancelled(
    tmp_path: Path, gate_process_url: str, sig: signal.Signals
) -> None:
    env = {**os.environ, "CYCLONEDDS_URI": loopback_config()}
    device = tmp_path / "rover-motor"
    children: list[_Child] = []
    try:
        emulator = _Child(
            [
                "emulate",
                "--serial",
                "--link",
                str(device),
                "--map",
                "lab",
                "--seed",
                "1",
                "--speed-factor",
                "4",
                "--control-port",
                "0",
            ],
            env,
        )
        children.append(emulator)
        control = int(emulator.wait_for("CONTROL ").rsplit(":", 1)[1])
        children.append(_Child(["bridge", "--device", str(device), "--ros-backend", "dds"], env))
        children[-1].wait_for("BRIDGE ")
        children.append(
            _Child(["link", "--rtt", "0.1", "--seed", "1", "--ros-backend", "dds"], env)
        )
        children[-1].wait_for("LINK ")
        go = _Child(
            [
                "go",
                "--goal",
                "1.2,1.5,-90",  # turn right (about 1.7 s wall), then south
                "--map",
                "lab",
                "--gate",
                gate_process_url,
                "--rtt",
                "0.1",
                "--time-scale",
                "4",
                "--picture",
                str(tmp_path / "m.png"),
            ],
            env,
        )
        children.append(go)
        line = go.wait_for("start (")  # the rover's own pose, the lab's start
        x, y, _ = (float(v) for v in line.split("start (", 1)[1].split(" deg")[0].split(","))
        assert abs(x - 1.2) < 0.05 and abs(y - 3.0) < 0.05, line
        go.wait_for(" running, ETA ")  # progress during a step
        assert any(abs(v) > 0.01 for v in _status(control)["wheel_mps"])  # it is driving
        go.proc.send_signal(sig)
        assert go.wait(60) == 128 + sig, go.errors
        go.wait_for("NOT REACHED (cancelled by the operator)", timeout_s=0)
        assert not any("Traceback" in line for line in go.errors), go.errors
        assert go.errors[-1] == "rover go: cancelled by the operator; the rover was sent STOP"
        deadline = time.monotonic() + 10
        while _status(control)["wheel_mps"] != [0.0, 0.0]:
            assert time.monotonic() < deadline, "the rover did not come to rest"
            time.sleep(0.05)
        assert _status(control)["stop_latched"]
    finally:
        for child in reversed(children):
            child.stop()
