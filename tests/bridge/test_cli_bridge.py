"""``rover_bridge`` / ``rover bridge``: every parameter from the command line (``--param``)
and from ``--ros-args`` on every backend; unknown or bad ones are usage errors (exit 2)."""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path

import pytest

from bridge.cli_bridge import add_arguments, main, resolve_params
from bridge.errors import ParameterError
from bridge.ros.params import BridgeParams

REPO = Path(__file__).resolve().parents[2]


def _args(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="rover_bridge")
    add_arguments(parser)
    return parser.parse_args(argv)


def _resolve(own: list[str], ros: Sequence[str] = (), **env: str) -> BridgeParams:
    params, _layer = resolve_params(_args(*own), ros, env=env)
    return params


def test_every_parameter_is_settable_with_param() -> None:
    params = _resolve(
        [
            "--param",
            "topic_odom=wheel_odom",
            "--param",
            "base_frame=rover_base",
            "--param",
            "diagnostics_hz=2.5",
            "--param",
            "auto_clear_watchdog=false",
            "--param",
            "can_interface=virtual",
            "--param",
            "node_id=0x7",
        ]
    )
    assert params.topic_odom == "wheel_odom" and params.base_frame == "rover_base"
    assert params.diagnostics_hz == 2.5 and params.auto_clear_watchdog is False
    assert params.url == "can://virtual/can0?node=7"
    # The named option wins over --param for the same parameter.
    assert _resolve(["--param", "node_id=3", "--node", "4", "--can", "virtual:x"]).node_id == 4
    # Every field has a way in: --param takes any of them.
    for name, value in BridgeParams().to_dict().items():
        text = str(value).lower() if isinstance(value, bool) else str(value)
        assert getattr(_resolve(["--param", f"{name}={text}"]), name) == value, name


@pytest.mark.parametrize(
    ("argv", "complaint"),
    [
        (["--param", "nonsense=1"], "unknown parameter 'nonsense' (command line)"),
        (["--param", "node_id=16"], "node_id: 16 is outside 1..15"),
        (["--param", "heartbeat_hz=fast"], "heartbeat_hz (command line): 'fast'"),
        (["--param", "auto_clear_watchdog=maybe"], "auto_clear_watchdog"),
        (["--param", "topic_odom="], "topic_odom: empty topic name"),
    ],
)
def test_bad_param_values_name_themselves(argv: list[str], complaint: str) -> None:
    with pytest.raises(ParameterError, match=complaint.replace("(", r"\(").replace(")", r"\)")):
        _resolve(argv)


def test_param_needs_name_equals_value(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_:
        main(["--param", "node_id"])
    assert exit_.value.code == 2
    assert "--param needs NAME=VALUE" in capsys.readouterr().err


def test_ros_p_sets_bridge_parameters_on_every_backend() -> None:
    for backend in ("rclpy-process", "rclpy", "inprocess"):
        params = _resolve(
            ["--ros-backend", backend],
            ["-p", "node_id:=9", "-p", "can_interface:=virtual", "-p", "heartbeat_hz:=20"],
        )
        assert (params.node_id, params.can_interface, params.heartbeat_hz) == (9, "virtual", 20.0)
    # The command line wins over ROS parameters, which win over the environment.
    params = _resolve(
        ["--node", "3"],
        ["-p", "node_id:=9", "-p", "baud:=57600"],
        ROVER_BRIDGE_BAUD="38400",
        ROVER_BRIDGE_MOTION_RETRIES="5",
    )
    assert (params.node_id, params.baud, params.motion_retries) == (3, 57600, 5)
    # The backend itself may come from -p.
    assert _resolve([], ["-p", "ros_backend:=inprocess"]).ros_backend == "inprocess"
    # The namespace remap places the node, unless a parameter says otherwise.
    assert _resolve([], ["-r", "__ns:=/rover1"]).namespace == "/rover1"
    assert _resolve([], ["-r", "__ns:=/"]).namespace == ""


def test_ros_params_file_gives_the_node_its_sections(tmp_path: Path) -> None:
    pytest.importorskip("yaml", reason="PyYAML (the ros-params extra, or ROS 2) is missing")
    file = tmp_path / "params.yaml"
    file.write_text(
        "/**:\n"
        "  ros__parameters:\n"
        "    use_sim_time: false\n"
        "    diagnostics_hz: 2.0\n"
        "/**/rover_bridge:\n"
        "  ros__parameters:\n"
        "    topic_odom: wheel_odom\n"
        "    auto_clear_watchdog: false\n"
        "    motion_retries: 5\n"
        "other_node:\n"
        "  ros__parameters:\n"
        "    nonsense: 1\n"
        "renamed:\n"
        "  ros__parameters:\n"
        "    odom_frame: renamed_odom\n"
    )
    ros = ["--params-file", str(file), "-p", "motion_retries:=6", "-p", "diagnostics_hz:=4.0"]
    params = _resolve([], ros)
    assert (params.topic_odom, params.auto_clear_watchdog, params.diagnostics_hz) == (
        "wheel_odom",
        False,
        4.0,  # -p after the file wins over its /** section
    )
    assert params.motion_retries == 5  # but not over the node's own section, as in rcl
    assert params.odom_frame == "odom"  # another node's section
    renamed, layer = resolve_params(
        _args(), ["--params-file", str(file), "-r", "__node:=renamed"], env={}
    )
    assert layer.node_name == "renamed" and renamed.odom_frame == "renamed_odom"
    assert renamed.topic_odom == "odom"  # the rover_bridge section is not this node's now


def test_unknown_ros_parameters_are_refused_not_ignored(tmp_path: Path) -> None:
    with pytest.raises(ParameterError, match=r"unknown parameter 'nonsense' \(ROS parameter\)"):
        _resolve(["--ros-backend", "inprocess"], ["-p", "nonsense:=1"])
    with pytest.raises(ParameterError, match="node_id: 99 is outside"):
        _resolve(["--ros-backend", "rclpy"], ["-p", "node_id:=99"])
    with pytest.raises(ParameterError, match="use_sim_time"):
        _resolve([], ["-p", "use_sim_time:=true"])
    # rcl's own parser reads them (rclpy is installed): its words (issue #41).
    with pytest.raises(ValueError, match=r"refused by rcl.*'-p node_id=3'"):
        _resolve([], ["-p", "node_id=3"])
    with pytest.raises(ValueError, match=r"refused by rcl.*missing\.yaml"):
        _resolve([], ["--params-file", str(tmp_path / "missing.yaml")])


def test_the_default_backend_is_rclpy_in_a_child_and_takes_ros_parameters_like_any() -> None:
    """One order of precedence on every backend: the node then declares the result."""
    assert _resolve([]).ros_backend == "rclpy-process"
    params = _resolve(["--ros-backend", "rclpy"], ["-p", "node_id:=7"])
    assert params.node_id == 7
    assert _resolve(["--node", "3"], ["-p", "node_id:=7"]).node_id == 3
    with pytest.raises(ParameterError, match="unknown parameter 'nonsense'"):
        _resolve(["--ros-backend", "rclpy"], ["-p", "nonsense:=1"])
    with pytest.raises(ParameterError, match="ros_backend: 'dds'"):
        _resolve([], ["-p", "ros_backend:=dds"])


def _run(*argv: str) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("ROVER_BRIDGE_")}
    return subprocess.run(
        [sys.executable, "-m", "bridge.cli_bridge", *argv],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=REPO,
        env=env,
        check=False,
    )


def test_rover_bridge_process_takes_ros_parameters_on_inprocess(tmp_path: Path) -> None:
    done = _run(
        "--ros-backend",
        "inprocess",
        "--duration",
        "0.2",
        "--ros-args",
        "-p",
        "can_interface:=virtual",
        "-p",
        "can_channel:=cli-bridge-test",
        "-p",
        "node_id:=7",
    )
    # Nothing answers on that bus: stopped without reaching a controller, it says so.
    assert done.returncode == 3, done.stderr
    assert "stopped without ever reaching a controller" in done.stderr.splitlines()[-1]
    assert done.stdout.splitlines()[0] == "BRIDGE can://virtual/cli-bridge-test?node=7 inprocess"
    # The process asks for short interpreter slices, so a STOP never waits 5 ms for one.
    assert "thread switch interval 0.0005 s (was 0.0050 s)" in done.stderr


@pytest.mark.parametrize(
    ("argv", "complaint"),
    [
        (["--ros-args", "-p", "nonsense:=1"], "unknown parameter 'nonsense' (ROS parameter)"),
        (["--ros-args", "-p", "node_id:=99"], "parameter node_id: 99 is outside 1..15"),
        (["--param", "nonsense=1"], "unknown parameter 'nonsense' (command line)"),
        # rcl's own parser reads --ros-args where rclpy is installed (issue #41).
        (["--ros-args", "-p"], "ROS arguments refused by rcl"),
    ],
)
def test_rover_bridge_process_refuses_bad_parameters_with_exit_2(
    argv: list[str], complaint: str
) -> None:
    done = _run("--ros-backend", "inprocess", "--device", "/nonexistent", *argv)
    assert done.returncode == 2, done.stderr
    assert f"rover_bridge: error: {complaint}" in done.stderr
    assert "BRIDGE" not in done.stdout


@pytest.mark.parametrize(
    ("device", "complaint"),
    [
        ("socket://nohost", "socket:// needs HOST:PORT"),
        ("gopher://rover", "unknown"),
    ],
)
def test_a_malformed_device_url_is_a_usage_error_and_records_nothing(
    tmp_path: Path, device: str, complaint: str
) -> None:
    log = tmp_path / "traffic.rlog"
    done = _run("--ros-backend", "inprocess", "--device", device, "--record", str(log))
    assert done.returncode == 2, done.stderr
    assert "rover_bridge: error:" in done.stderr and complaint in done.stderr
    assert "BRIDGE" not in done.stdout
    assert not log.exists()


def test_rover_bridge_asks_for_real_time_and_no_realtime_turns_it_off() -> None:
    common = ("--ros-backend", "inprocess", "--duration", "0.2", "--can", "virtual:rt-test")
    done = _run(*common)
    assert done.returncode == 3, done.stderr  # nothing on that bus: never reached a controller
    said = [line for line in done.stderr.splitlines() if line.startswith("realtime:")]
    assert len(said) == 1
    if os.geteuid() == 0:
        assert said[0] == "realtime: SCHED_RR priority 20, memory locked"
    off = _run(*common, "--no-realtime")
    said_off = [line for line in off.stderr.splitlines() if line.startswith("realtime:")]
    assert len(said_off) == 1 and said_off[0].startswith("realtime: off (SCHED_OTHER, nice ")
    bad = _run(*common, "--rt-priority", "100")
    assert bad.returncode == 2
    assert "parameter rt_priority: 100 is outside 0..99" in bad.stderr


def test_a_frozen_bridge_logs_its_stall_and_the_controller_trips(tmp_path: Path) -> None:
    """The bridge's computer holds it up past the controller's watchdog: the controller
    stops the rover, and the bridge's stall (how long, where) is in the stall log the
    stack shares, where ``rover go`` and ``rover demo`` read it (docs/realtime.md)."""
    import signal
    import time

    from firmware_proto.runtime.stall import read_stalls
    from tests.child import Child

    log = tmp_path / "stalls.jsonl"
    env = {**os.environ, "ROVER_STALL_LOG": str(log)}
    emulator = Child(["emulate", "--serial", "--seed", "2"], env)
    bridge: Child | None = None
    try:
        device = emulator.wait_for("DEVICE ").split()[1]
        bridge = Child(["-v", "bridge", "--device", device, "--ros-backend", "inprocess"], env)
        bridge.wait_for("BRIDGE ")
        _wait_lines(bridge.errors, "handshake done", 20.0)
        # Three freezes: after each, whichever of its threads runs first, the bridge
        # declares the link lost (the controller's watchdog stopped the rover meanwhile:
        # docs/protocol.md, Watchdog and heartbeats) and handshakes again.
        for freeze in range(1, 4):
            os.kill(bridge.proc.pid, signal.SIGSTOP)
            time.sleep(0.6)  # the freeze: more than twice the watchdog
            os.kill(bridge.proc.pid, signal.SIGCONT)
            _wait_count(emulator.errors, "watchdog: no valid frame", freeze, 10.0)
            _wait_count(bridge.errors, "link lost:", freeze, 10.0)
            _wait_count(bridge.errors, "handshake done", freeze + 1, 20.0)
        deadline = time.monotonic() + 10.0
        while not [r for r in read_stalls(log) if r.process == "bridge" and r.ms >= 400]:
            assert time.monotonic() < deadline, read_stalls(log)
            time.sleep(0.05)
        (record, *_) = [r for r in read_stalls(log) if r.process == "bridge" and r.ms >= 400]
        assert record.pid == bridge.proc.pid
        assert record.stack  # where its threads were
    finally:
        if bridge is not None:
            os.kill(bridge.proc.pid, signal.SIGCONT)
            bridge.stop()
        emulator.stop()


def _wait_lines(lines: list[str], needle: str, timeout_s: float) -> None:
    _wait_count(lines, needle, 1, timeout_s)


def _wait_count(lines: list[str], needle: str, count: int, timeout_s: float) -> None:
    import time

    deadline = time.monotonic() + timeout_s
    while sum(needle in line for line in lines) < count:
        assert time.monotonic() < deadline, f"fewer than {count} {needle!r} in {lines}"
        time.sleep(0.05)
