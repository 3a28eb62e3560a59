"""``rover onboard``'s start-up rules that need no ROS 2: the uplink token comes from the
environment only, and without one the program refuses to start unless told
``--insecure`` (docs/onboard.md, "Tokens"). The program at work is
tests/bridge/test_onboard_mission.py's."""

from __future__ import annotations

import pytest

from bridge.cli_onboard import main
from firmware_proto.model.uplink import TOKEN_ENV


def test_without_a_token_it_refuses_to_start(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """Review A3: the stack and the demo ran it with no token ("no token: tags not
    checked"): any process on the ROS domain could publish a plan that drives."""
    monkeypatch.delenv(TOKEN_ENV, raising=False)
    monkeypatch.setenv("ROVER_GATE_TOKEN", "the-gate-s")  # never the uplink's
    assert main(["--ros-backend", "inprocess", "--duration", "0.01"]) == 2
    err = capsys.readouterr().err
    assert f"no uplink token: set ${TOKEN_ENV}" in err and "--insecure" in err


def test_the_token_is_no_command_line_option(capsys: pytest.CaptureFixture[str]) -> None:
    """A command line is readable by every user in /proc: the token is not one."""
    with pytest.raises(SystemExit) as exited:
        main(["--token", "s3cret"])
    assert exited.value.code == 2
    assert "unrecognized arguments: --token" in capsys.readouterr().err


@pytest.mark.parametrize("insecure", [False, True], ids=["token", "insecure"])
def test_with_a_token_or_insecure_it_starts_and_says_which(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], insecure: bool
) -> None:
    if insecure:
        monkeypatch.delenv(TOKEN_ENV, raising=False)
    else:
        monkeypatch.setenv(TOKEN_ENV, "s3cret")
    args = ["--ros-backend", "inprocess", "--duration", "0.01", "--no-realtime"]
    assert main([*args, *(["--insecure"] if insecure else [])]) == 0
    out = capsys.readouterr()
    ready = next(x for x in out.out.splitlines() if x.startswith("ONBOARD "))
    want = "INSECURE: no token, tags not checked" if insecure else "uplinks must be signed"
    assert ready.endswith(f"({want})")
    assert "onboard: boot " in out.err
