"""``rover gate`` as a real subprocess, and ``rover gate check`` (exit codes, PNG, JSON)."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from firmware_proto.cli import main
from firmware_proto.model.rover import RoverDescription

from .client import call, post_plan
from .plans import STOP_AT_LAB_START, fwd, plan, step, turn

WAIT_S = 60.0
ROVER = str(Path(sys.executable).with_name("rover"))


@pytest.mark.parametrize("stop_signal", [signal.SIGTERM, signal.SIGINT])
def test_rover_gate_serves_until_a_signal(stop_signal: signal.Signals) -> None:
    proc = subprocess.Popen(
        [ROVER, "gate", "--port", "0", "--workers", "1", "--map", "scn01"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None
        first = proc.stdout.readline().split()
        assert first[0] == "GATE"
        host, port = first[1].removeprefix("http://").split(":")
        address = (host, int(port))
        assert host == "127.0.0.1"
        health = call(address, "GET", "/health").json()
        assert (health["pool"], health["workers"], health["default_map"]) == ("process", 1, "scn01")
        verdict = post_plan(address, plan((2.0, 4.0, 0.0), fwd(1.0))).json()
        assert verdict["approved"] is True
        assert verdict["replay"]["map"] == "scn01"
        proc.send_signal(stop_signal)
        _, err = proc.communicate(timeout=WAIT_S)
        assert proc.returncode == 0, err
        assert "shutting down" in err
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate(timeout=WAIT_S)


def test_rover_gate_script_takes_its_options_from_ros_arguments(tmp_path: Path) -> None:
    """``rover_gate`` as launch_ros starts it: a parameters file section, then ``-p``
    (which wins), then SIGTERM from the launch system."""
    pytest.importorskip("yaml", reason="PyYAML (the ros-params extra, or ROS 2) is missing")
    params = tmp_path / "hil.yaml"
    params.write_text(
        "/**/rover_gate:\n  ros__parameters:\n    map: scn01\n    port: 0\n    pool: thread\n",
        encoding="utf-8",
    )
    ros_args = ["--ros-args", "-r", "__node:=rover_gate", "--params-file", str(params)]
    proc = subprocess.Popen(
        [str(Path(sys.executable).with_name("rover_gate")), *ros_args, "-p", "map:=scn02"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None
        first = proc.stdout.readline().split()
        assert first and first[0] == "GATE", proc.stderr.read() if proc.stderr else ""
        host, port = first[1].removeprefix("http://").split(":")
        health = call((host, int(port)), "GET", "/health").json()
        assert (health["pool"], health["default_map"]) == ("thread", "scn02")
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=WAIT_S)
        assert proc.returncode == 0, err
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate(timeout=WAIT_S)


def test_rover_gate_script_refuses_malformed_ros_arguments() -> None:
    done = subprocess.run(
        [str(Path(sys.executable).with_name("rover_gate")), "--ros-args", "-p", "port=1"],
        capture_output=True,
        text=True,
        timeout=WAIT_S,
        check=False,
    )
    assert done.returncode == 2
    assert "name:=value" in done.stderr


def test_rover_gate_refuses_a_public_address_without_a_token() -> None:
    done = subprocess.run(
        [ROVER, "gate", "--host", "0.0.0.0", "--port", "0"],
        capture_output=True,
        text=True,
        timeout=WAIT_S,
        check=False,
    )
    assert done.returncode == 1
    assert "without a token" in done.stderr


def test_the_token_comes_from_a_file_never_the_command_line(tmp_path: Path) -> None:
    """``--token`` would show the token in ``ps``: refused, saying what to do; a weak
    token for a public address is refused; ``--token-file`` serves."""

    def gate(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run(
            [ROVER, "gate", "--port", "0", *args],
            capture_output=True,
            text=True,
            timeout=WAIT_S,
            check=False,
        )

    done = gate("--token", "s3cret-token-0123456789")
    assert done.returncode == 1
    assert "ps" in done.stderr and "--token-file" in done.stderr
    weak = tmp_path / "weak"
    weak.write_text("s3cret\n")
    done = gate("--host", "0.0.0.0", "--token-file", str(weak))
    assert done.returncode == 1 and "too weak" in done.stderr
    done = gate("--host", "0.0.0.0", "--token-file", str(tmp_path / "missing"))
    assert done.returncode == 1 and "cannot read" in done.stderr
    strong = tmp_path / "token"
    strong.write_text("k3Jf9-xQ2mPz8vLw\n")
    strong.chmod(0o600)
    proc = subprocess.Popen(
        [ROVER, "gate", "--port", "0", "--pool", "thread", "--token-file", str(strong)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None
        first = proc.stdout.readline().split()
        assert first and first[0] == "GATE"
        host, port = first[1].removeprefix("http://").split(":")
        address = (host, int(port))
        assert call(address, "GET", "/health").status == 401
        assert call(address, "GET", "/health", token="k3Jf9-xQ2mPz8vLw").status == 200
        proc.send_signal(signal.SIGTERM)
        proc.communicate(timeout=WAIT_S)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate(timeout=WAIT_S)


def _check(tmp_path: Path, body: object, *args: str) -> tuple[int, str, str]:
    plan_file = tmp_path / "plan.json"
    plan_file.write_text(json.dumps(body) if not isinstance(body, str) else body)
    return _run_check(["gate", "check", str(plan_file), *args])


def _run_check(argv: list[str]) -> tuple[int, str, str]:
    import contextlib
    import io

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main(argv)
        except SystemExit as exc:  # argparse usage errors
            code = int(exc.code or 0)
    return code, out.getvalue(), err.getvalue()


def test_check_exit_codes(tmp_path: Path, rover: RoverDescription) -> None:
    code, out, _ = _check(tmp_path, STOP_AT_LAB_START)
    assert code == 0 and out.startswith("APPROVED")
    code, out, _ = _check(tmp_path, plan((6.2, 3.0, 0.0), *(step("FWD", 60, 30000),) * 3))
    assert code == 1 and out.startswith("REJECTED collision at step 1")
    assert "table" in out
    code, _, err = _check(tmp_path, {"goal": {"x": 0}, "commands": []})
    assert code == 2 and "/commands" in err
    code, _, err = _check(tmp_path, "not json")
    assert code == 2 and "not valid JSON" in err
    code, _, err = _run_check(["gate", "check", str(tmp_path / "missing.json")])
    assert code == 2 and "cannot read" in err
    unwritable = str(tmp_path / "no-such-dir" / "v.png")
    code, out, err = _check(tmp_path, STOP_AT_LAB_START, "--png", unwritable)
    assert code == 2 and out.startswith("APPROVED")  # the verdict is still printed
    assert "cannot write" in err and "picture" not in out
    code, _, err = _check(tmp_path, STOP_AT_LAB_START, "--map", "atlantis")
    assert code == 2 and "atlantis" in err
    code, _, err = _check(tmp_path, STOP_AT_LAB_START, "--start", "1,2")
    assert code == 2 and "start" in err
    code, _, _ = _check(tmp_path, STOP_AT_LAB_START, "--bogus")
    assert code == 2
    code, out, _ = _check(tmp_path, plan((1.2, 3.0, 90.0), turn(rover, 60)), "--yaw-tol", "45")
    assert code == 0


def test_check_start_json_and_png(tmp_path: Path) -> None:
    png = tmp_path / "verdict.png"
    code, out, _ = _check(
        tmp_path,
        plan((3.0, 2.0, 0.0), fwd(1.0)),
        "--start",
        "2,2,0",
        "--png",
        str(png),
        "--json",
    )
    assert code == 0
    verdict = json.loads(out)
    assert verdict["start_pose"] == {"x": 2.0, "y": 2.0, "yaw_deg": 0.0}
    assert verdict["replay"]["render"] is True
    assert png.read_bytes().startswith(b"\x89PNG\r\n\x1a\n")


def test_ctrl_c_to_the_process_group_drains_cleanly() -> None:
    import os

    proc = subprocess.Popen(
        [ROVER, "gate", "--port", "0", "--workers", "2"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,  # its own process group, as in a terminal
    )
    try:
        assert proc.stdout is not None
        url = proc.stdout.readline().split()[1]
        host, port = url.removeprefix("http://").split(":")
        assert post_plan((host, int(port)), STOP_AT_LAB_START).status == 200
        os.killpg(proc.pid, signal.SIGINT)  # parent and workers alike
        _, err = proc.communicate(timeout=WAIT_S)
        assert proc.returncode == 0, err
        assert "Traceback" not in err
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate(timeout=WAIT_S)


def test_check_draws_the_start_with_its_own_noise(tmp_path: Path) -> None:
    body = plan((3.0, 2.0, 0.0), fwd(1.0))
    spreads = []
    for sigma in ("0", "0.05"):
        code, out, err = _check(
            tmp_path,
            body,
            "--start",
            "2,2,0",
            "--samples",
            "20",
            "--start-sigma-m",
            sigma,
            "--start-sigma-deg",
            "0",
            "--json",
        )
        assert code in (0, 1), err
        low, _mid, high = json.loads(out)["uncertainty"]["goal_error"]["lateral_m"]
        spreads.append(high - low)
    # A start known to 5 cm lands the twins centimetres apart across the path.
    assert spreads[1] > spreads[0] + 0.05
    code, _, err = _check(tmp_path, body, "--samples", "4", "--start-sigma-deg", "90")
    assert code == 2 and "start_sigma_deg" in err
