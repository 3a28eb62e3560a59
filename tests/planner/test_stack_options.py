"""``rover stack up --ground/--twin`` and what the stack tells ``rover go``: the options'
checks and the export line, without starting a stack (the stack on a ground, with a
calibrated twin, is started by tests/planner/test_calibrate_real.py)."""

from __future__ import annotations

from pathlib import Path

import pytest

from firmware_proto.cli import build_parser, main
from planner.stack.stackenv import TWIN_ENV, export_line, stack_environment


def test_the_ground_is_the_emulators_so_not_with_a_device(
    capsys: pytest.CaptureFixture[str],
) -> None:
    status = main(["stack", "up", "--ground", "loose", "--device", "/dev/rover-motor"])
    assert status == 2
    assert "--ground is the emulator's ground" in capsys.readouterr().err


def test_a_twin_that_is_not_there_is_refused_before_anything_starts(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    status = main(["stack", "up", "--twin", str(tmp_path / "none.toml")])
    assert status == 2
    assert "none.toml: no such file" in capsys.readouterr().err


def test_the_stack_exports_its_twin_and_rover_go_plans_by_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    twin = tmp_path / "twin.toml"
    variables = stack_environment(101, "http://127.0.0.1:1", "", twin=twin)
    assert variables[TWIN_ENV] == str(twin)
    assert f"{TWIN_ENV}={twin}" in export_line(variables)
    assert TWIN_ENV not in stack_environment(101, "http://127.0.0.1:1", "")
    monkeypatch.setenv(TWIN_ENV, str(twin))
    args = build_parser().parse_args(["go", "--goal", "behind_table"])
    assert args.rover == str(twin)
    given = build_parser().parse_args(["go", "--goal", "behind_table", "--rover", "other.toml"])
    assert given.rover == "other.toml"
    monkeypatch.delenv(TWIN_ENV)
    assert build_parser().parse_args(["go", "--goal", "behind_table"]).rover is None


def test_a_console_token_on_the_command_line_is_refused_before_anything_starts(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """``ps`` shows arguments to every user: the console's token comes from the
    environment or is made at random, never from argv (docs/commands.md)."""
    status = main(["stack", "up", "--console-token", "s3cret"])
    assert status == 2
    err = capsys.readouterr().err
    assert "--console-token is no longer accepted" in err and "ROVER_CONSOLE_TOKEN" in err
    assert "s3cret" not in err


def test_a_console_off_loopback_needs_the_token_in_the_environment(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv("ROVER_CONSOLE_TOKEN", raising=False)
    status = main(["stack", "up", "--console-host", "0.0.0.0"])
    assert status == 2
    assert "refusing to listen on '0.0.0.0' without a token" in capsys.readouterr().err
