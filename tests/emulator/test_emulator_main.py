"""``rover_emulator``, the console script that ``ros2 run`` and the HIL launch file start:
the options of ``rover emulate``, and launch_ros's ``--ros-args`` standing for them."""

from __future__ import annotations

import argparse
import signal
from collections.abc import Iterator
from pathlib import Path

import pytest

from emulator.cli_emulate import add_arguments, controller_config, main
from firmware_proto.linkio.trafficio import read_log


@pytest.fixture(autouse=True)
def _keep_signal_handlers() -> Iterator[None]:
    """main() installs SIGINT/SIGTERM handlers for its own process; give pytest its own
    back."""
    saved = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    yield
    for sig, handler in saved.items():
        signal.signal(sig, handler)


def test_ros_arguments_stand_for_options(capsys: pytest.CaptureFixture[str]) -> None:
    argv = [
        "--ros-args",
        "--log-level",
        "warn",
        "-r",
        "__node:=rover_emulator",
        "-p",
        "serial:=true",
        "-p",
        "duration:=0.2",
        "-p",
        "speed_factor:=4.0",
    ]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert out.startswith("DEVICE /dev/pts/")


def test_the_command_line_records_a_session(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log = tmp_path / "emu.rlog"
    assert main(["--serial", "--seed", "9", "--duration", "0.1", "--record", str(log)]) == 0
    assert "DEVICE" in capsys.readouterr().out
    read = read_log(log)
    assert read.kind == "serial"
    assert read.metadata["role"] == "emulator"
    assert read.metadata["seed"] == "9"
    assert read.metadata["speed_factor"] == "1.0"


def test_malformed_ros_arguments_are_a_usage_error(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main(["--serial", "--ros-args", "-p", "speed_factor=4"])
    assert exit_info.value.code == 2
    assert "name:=value" in capsys.readouterr().err


def test_a_parameters_file_section_configures_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    pytest.importorskip("yaml", reason="PyYAML comes with ROS 2; it is not installed here")
    params = tmp_path / "hil.yaml"
    params.write_text(
        "/**/rover_emulator:\n  ros__parameters:\n    serial: true\n    duration: 0.1\n",
        encoding="utf-8",
    )
    assert main(["--ros-args", "--params-file", str(params)]) == 0
    assert capsys.readouterr().out.startswith("DEVICE /dev/pts/")


def test_watchdog_and_telemetry_rate_options_set_the_firmware() -> None:
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    args = parser.parse_args(
        ["--serial", "--speed-factor", "2", "--watchdog-ms", "1000", "--telemetry-hz", "100"]
    )
    config = controller_config(args)
    assert (config.watchdog_ms, config.telemetry_hz, config.timeout_scale) == (1000, 100, 2.0)
    defaults = controller_config(parser.parse_args(["--serial"]))
    assert (defaults.watchdog_ms, defaults.telemetry_hz) == (250, 50)


def test_a_watchdog_out_of_range_is_refused(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--serial", "--watchdog-ms", "20000", "--duration", "5"]) == 1
    out, err = capsys.readouterr()
    assert out == ""
    assert err.strip() == "rover_emulator: error: --watchdog-ms must be in 50..10000, got 20000"
