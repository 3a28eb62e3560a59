"""ROS arguments to long options: what launch_ros appends to our programs' command lines
becomes the options they already understand."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import pytest

from firmware_proto.cli.rosargs import (
    argv_from_ros_args,
    node_parameters,
    parameters_to_argv,
    parse_ros_args,
    ros_node_parameters,
    split_ros_args,
)

LAUNCH_ROS_TAIL = [
    "--ros-args",
    "--log-level",
    "info",
    "-r",
    "__node:=rover_emulator",
    "-r",
    "__ns:=/rover1",
    "--params-file",
    "/tmp/hil.yaml",
    "-p",
    "seed:=7",
    "-r",
    "odom:=odom_raw",
    "--enable-rosout-logs",
]


def test_the_ros_block_is_split_off_wherever_it_is() -> None:
    own, ros = split_ros_args(["--serial", *LAUNCH_ROS_TAIL])
    assert own == ["--serial"]
    assert ros == LAUNCH_ROS_TAIL[1:]
    own, ros = split_ros_args(["--ros-args", "-p", "a:=1", "--", "--serial", "--ros-args", "-p"])
    assert (own, ros) == (["--serial"], ["-p", "a:=1", "-p"])
    assert split_ros_args(["--map", "lab"]) == (["--map", "lab"], [])


def test_node_name_namespace_files_and_typed_parameters_are_read() -> None:
    parsed = parse_ros_args(
        [*LAUNCH_ROS_TAIL[1:], "-p", "serial:=true", "-p", "map:='lab'", "-p", "dt:=0.002"]
    )
    assert (parsed.node_name, parsed.namespace, parsed.params_files, parsed.params) == (
        "rover_emulator",
        "/rover1",
        ("/tmp/hil.yaml",),
        {"seed": 7, "serial": True, "map": "lab", "dt": 0.002},
    )
    assert parsed.sources[0] == ("file", "/tmp/hil.yaml")
    assert parse_ros_args(["-p", "other_node:seed:=3"]).params == {}  # another node's


@pytest.mark.parametrize(
    ("args", "error"),
    [
        (["-p"], "needs a value"),
        (["--params-file"], "needs a value"),
        (["-p", "seed=3"], "name:=value"),
        (["-r", "a"], "from:=to"),
    ],
)
def test_malformed_ros_arguments_are_refused(args: list[str], error: str) -> None:
    with pytest.raises(ValueError, match=error):
        parse_ros_args(args)


DOC: dict[str, Any] = {
    "/**": {"ros__parameters": {"seed": 1, "map": "lab"}},
    "/**/rover_emulator": {"ros__parameters": {"seed": 2, "serial": True}},
    "rover_emulator": {"ros__parameters": {"seed": 3}},
    "/rover1/rover_emulator": {"ros__parameters": {"seed": 4, "twin": {"dt": 0.002}}},
    "rover_bridge": {"ros__parameters": {"device": "/tmp/x"}},
}


def test_sections_apply_from_general_to_specific_as_in_ros() -> None:
    assert node_parameters(DOC, "rover_emulator", "/rover1") == {
        "seed": 4,
        "map": "lab",
        "serial": True,
        "twin.dt": 0.002,
    }
    assert node_parameters(DOC, "rover_emulator") == {"seed": 3, "map": "lab", "serial": True}
    assert node_parameters(DOC, "rover_gate") == {"seed": 1, "map": "lab"}
    assert node_parameters(None, "x") == {}
    with pytest.raises(ValueError, match="mapping"):
        node_parameters(["not", "a", "mapping"], "x")


RCL_CASES: list[list[str]] = [
    ["--params-file", "F", "-p", "seed:=9", "-p", "map:=moon"],
    ["-p", "seed:=9", "--params-file", "F"],
    ["-p", "rover_emulator:seed:=8", "--params-file", "F"],
    ["--params-file", "F", "-p", "rover_emulator:seed:=8", "-p", "rover_gate:seed:=7"],
    ["-p", "extra:=1", "-r", "__node:=rover_gate", "--params-file", "F"],
]
"""ROS arguments (``F`` stands for the parameters file of ``DOC``) whose merge rcl
decides by order and section: a ``-p`` wins over ``/**`` only."""

RCL_EXPECTED: list[dict[str, Any]] = [
    {"seed": 3, "map": "moon", "serial": True},
    {"seed": 3, "map": "lab", "serial": True},
    {"seed": 2, "map": "lab", "serial": True},  # "rover_emulator" came first, /**/.. later
    {"seed": 8, "map": "lab", "serial": True},
    {"seed": 1, "map": "lab", "extra": 1},
]


def _doc_file(tmp_path: Path) -> Path:
    file = tmp_path / "params.yaml"
    file.write_text(json.dumps({k: v for k, v in DOC.items() if k != "/rover1/rover_emulator"}))
    return file


@pytest.mark.parametrize(("case", "expected"), list(zip(RCL_CASES, RCL_EXPECTED, strict=True)))
def test_files_and_overrides_merge_in_rcl_order(
    tmp_path: Path, case: list[str], expected: dict[str, Any]
) -> None:
    file = _doc_file(tmp_path)
    args = [str(file) if a == "F" else a for a in case]
    got = ros_node_parameters(
        parse_ros_args(args), "rover_emulator", lambda p: json.loads(Path(p).read_text())
    )
    assert got == expected


# rclpy's first context opens DDS sockets that live as long as the process: a
# process-wide resource, not a leak of this test. It needs ROS 2, so it is not fast.
@pytest.mark.slow
@pytest.mark.allow_leaks
def test_the_pure_reader_agrees_with_rcl(tmp_path: Path) -> None:
    pytest.importorskip("rclpy", reason="rcl's own parser needs the ROS 2 wheels")
    from firmware_proto.cli.rclargs import rclpy_node_parameters

    file = _doc_file(tmp_path)
    for case, expected in zip(RCL_CASES, RCL_EXPECTED, strict=True):
        args = [str(file) if a == "F" else a for a in case]
        assert rclpy_node_parameters(args, "rover_emulator").params == expected, case


def test_parameters_become_long_options() -> None:
    assert parameters_to_argv(
        {
            "serial": True,
            "speed_factor": 4.0,
            "inject": ["slip:left=0.3", "reboot@t=5"],
            "link": "",
            "record": None,
            "verbose": False,
            "twin.dt": 0.002,
        }
    ) == [
        "--serial",
        "--speed-factor",
        "4.0",
        "--inject",
        "slip:left=0.3",
        "--inject",
        "reboot@t=5",
        "--twin-dt",
        "0.002",
    ]


def test_files_then_command_line_parameters_make_the_options() -> None:
    loaded: list[str] = []

    def load(path: str) -> Any:
        loaded.append(path)
        return DOC

    argv = argv_from_ros_args(LAUNCH_ROS_TAIL[1:], "default_name", load)
    assert loaded == ["/tmp/hil.yaml"]
    # -p seed:=7 is a /** override: the node's own sections of the file win, as in rcl.
    assert argv == ["--seed", "4", "--map", "lab", "--serial", "--twin-dt", "0.002"]
    # Without a __node remap the default name picks the section.
    assert argv_from_ros_args(["--params-file", "f"], "rover_bridge", load) == [
        "--seed",
        "1",
        "--map",
        "lab",
        "--device",
        "/tmp/x",
    ]


def test_an_unreadable_parameters_file_is_a_usage_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The command-line edge (cli_rosargs) reads the files; with or without PyYAML, a
    file it cannot read ends the program with status 2 and says which file."""
    from firmware_proto.cli.rosparams import parse_args_with_ros_args

    parser = argparse.ArgumentParser(prog="rover_emulator")
    parser.add_argument("--seed", type=int, default=0)
    missing = tmp_path / "missing.yaml"
    with pytest.raises(SystemExit) as exit_info:
        parse_args_with_ros_args(parser, ["--ros-args", "--params-file", str(missing)], "x")
    assert exit_info.value.code == 2
    assert str(missing) in capsys.readouterr().err
    args = parse_args_with_ros_args(parser, ["--seed", "4", "--ros-args", "-p", "seed:=3"], "x")
    assert args.seed == 4  # the program's own options win
