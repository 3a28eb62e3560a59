"""``rover onboard``'s start-up rules that need no ROS 2: the uplink token comes from the
environment only, and without one the program refuses to start unless told
``--insecure`` (docs/onboard.md, "Tokens"). The program at work is
tests/bridge/test_onboard_mission.py's."""

from __future__ import annotations

import pytest

from bridge.cli_onboard import main
from bridge.ros.rosport import open_port, qos
from bridge.ros.rosport.contract import EMERGENCY_STOP, WHEEL_INSTRUCTIONS
from bridge.ros.rosport.msgs import Bool, Int16MultiArray
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
    args += ["--bridge-timeout", "0"]
    assert main([*args, *(["--insecure"] if insecure else [])]) == 0
    out = capsys.readouterr()
    ready = next(x for x in out.out.splitlines() if x.startswith("ONBOARD "))
    want = "INSECURE: no token, tags not checked" if insecure else "uplinks must be signed"
    assert ready.endswith(f"({want})")
    assert "onboard: boot " in out.err


def test_it_says_onboard_only_once_the_bridge_hears_its_steps_and_stop(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """Review A7: ONBOARD was printed before anything subscribed to its STOP (the
    program's wait for the bridge was never called): a guard STOP could reach nobody."""
    monkeypatch.setenv(TOKEN_ENV, "s3cret")
    args = ["--ros-backend", "inprocess", "--duration", "0.01", "--no-realtime"]
    assert main([*args, "--bridge-timeout", "0.2"]) == 1
    out = capsys.readouterr()
    assert "ONBOARD" not in out.out
    assert "no bridge subscribed to wheel_instructions and emergency_stop" in out.err
    # the bridge's two subscriptions, on the same in-process bus
    with open_port("inprocess", node_name="bridge") as bridge:
        bridge.subscribe(WHEEL_INSTRUCTIONS, Int16MultiArray, lambda _m: None, qos.COMMAND)
        bridge.subscribe(EMERGENCY_STOP, Bool, lambda _m: None, qos.STOP)
        assert main([*args, "--bridge-timeout", "10"]) == 0
    assert any(x.startswith("ONBOARD ") for x in capsys.readouterr().out.splitlines())
