"""The main() of the programs ros2 run starts: options and ROS parameters read, then one
exit status and at most one line on stderr, whatever ``run`` did."""

from __future__ import annotations

import argparse

import pytest

from firmware_proto.cli.program import error_text, ros_main


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="rover_thing")
    parser.add_argument("--map", default="lab")
    parser.add_argument("--rtt", type=float, default=3.0)
    return parser


def test_ros_parameters_become_options_and_the_programs_own_win() -> None:
    seen: list[argparse.Namespace] = []

    def run(args: argparse.Namespace) -> int:
        seen.append(args)
        return 3

    argv = ["--map", "scn01", "--ros-args", "-p", "map:=scn02", "-p", "rtt:=1.5"]
    assert ros_main(_parser(), run, argv) == 3
    (args,) = seen
    assert (args.map, args.rtt) == ("scn01", 1.5)
    assert not hasattr(args, "ros_args")


def test_a_program_with_its_own_node_gets_the_ros_arguments_whole() -> None:
    seen: list[list[str]] = []

    def run(args: argparse.Namespace) -> int:
        seen.append(args.ros_args)
        return 0

    argv = ["--map", "scn01", "--ros-args", "-p", "node_id:=3", "-r", "__ns:=/r1"]
    assert ros_main(_parser(), run, argv, node=True) == 0
    assert seen == [["-p", "node_id:=3", "-r", "__ns:=/r1"]]


def test_a_failure_is_one_line_and_exit_1(capsys: pytest.CaptureFixture[str]) -> None:
    def run(args: argparse.Namespace) -> int:
        raise ValueError("--rtt must be >= 0, got -1")

    assert ros_main(_parser(), run, []) == 1
    assert capsys.readouterr().err == "rover_thing: error: --rtt must be >= 0, got -1\n"


def test_an_unexpected_error_names_its_type(capsys: pytest.CaptureFixture[str]) -> None:
    def run(args: argparse.Namespace) -> int:
        raise KeyError("lab")

    assert ros_main(_parser(), run, []) == 1
    assert capsys.readouterr().err == "rover_thing: error: KeyError: 'lab'\n"


def test_ctrl_c_is_130(capsys: pytest.CaptureFixture[str]) -> None:
    def run(args: argparse.Namespace) -> int:
        raise KeyboardInterrupt

    assert ros_main(_parser(), run, []) == 130
    assert capsys.readouterr().err == "rover_thing: interrupted\n"


@pytest.mark.parametrize(
    "argv", [["--nonsense"], ["--ros-args", "-p"], ["--ros-args", "-p", "rtt:=fast"]]
)
def test_a_usage_error_exits_2_before_anything_runs(argv: list[str]) -> None:
    ran: list[bool] = []

    def run(args: argparse.Namespace) -> int:
        ran.append(True)
        return 0

    with pytest.raises(SystemExit) as info:
        ros_main(_parser(), run, argv)
    assert info.value.code == 2
    assert ran == []


def test_error_text() -> None:
    assert error_text(OSError("cannot open /dev/rover-motor")) == "cannot open /dev/rover-motor"
    assert error_text(TypeError("x")) == "TypeError: x"
