"""One check per kind of value (``firmware_proto/cli/values.py``), the same words in every
``rover`` command that takes it: each command is run as a real subprocess."""

from __future__ import annotations

import subprocess
import sys

import pytest

from firmware_proto.cli import values


def rover(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "firmware_proto.cli", *args],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )


BAUD = "baud must be an integer in 50..4000000 (bit/s), got '0'"
NODE = "node must be an integer in 1..15, got '16'"
PORT = "port must be an integer in 0..65535 (0 picks a free one), got '70000'"
LOSS = "loss must be a number in [0, 1), got '1'"


@pytest.mark.parametrize(
    ("args", "option", "message"),
    [
        (["bridge", "--device", "/dev/null", "--baud", "0"], "--baud", BAUD),
        (["bench", "stop", "--serial", "/dev/null", "--baud", "0"], "--baud", BAUD),
        (["emulate", "--serial", "--baud", "0"], "--baud", BAUD),
        (["stack", "up", "--baud", "0"], "--baud", BAUD),
        (["bridge", "--can", "virtual:x", "--node", "16"], "--node", NODE),
        (["bench", "stop", "--can", "virtual:x", "--node", "16"], "--node", NODE),
        (["conformance", "--can", "virtual:x", "--node", "16"], "--node", NODE),
        (["emulate", "--can", "virtual:x", "--node", "16"], "--node", NODE),
        (["frame", "dbc", "--node", "16"], "--node", NODE),
        (["gate", "--port", "70000"], "--port", PORT),
        (["emulate", "--serial", "--control-port", "70000"], "--control-port", PORT),
        (["go", "--goal", "1,1,0", "--view-port", "70000"], "--view-port", PORT),
        (["stack", "up", "--gate-port", "70000"], "--gate-port", PORT),
        (["stack", "up", "--loss", "1"], "--loss", LOSS),
        (["demo", "--loss", "1"], "--loss", LOSS),
    ],
)
def test_every_command_refuses_a_bad_value_in_the_same_words(
    args: list[str], option: str, message: str
) -> None:
    out = rover(*args)
    assert out.returncode == 2, out.stderr
    assert out.stderr.splitlines()[-1].endswith(f"error: argument {option}: {message}")


def test_the_checks_accept_their_limits_and_refuse_beyond() -> None:
    assert values.baud("50") == 50 and values.baud("4000000") == 4_000_000
    assert values.can_node("1") == 1 and values.can_node("0xF") == 15
    assert values.can_node_or_broadcast("0") == 0
    assert values.tcp_port("0") == 0 and values.tcp_port("65535") == 65535
    assert values.host_port("127.0.0.1:7700") == ("127.0.0.1", 7700)
    assert values.domain_id("232") == 232
    assert values.positive("0.5") == 0.5 and values.non_negative("0") == 0.0
    assert values.loss_ratio("0") == 0.0 and values.loss_ratio("0.999") == 0.999
    for check, text in [
        (values.baud, "49"),
        (values.baud, "fast"),
        (values.can_node, "0"),
        (values.tcp_port, "-1"),
        (values.host_port, "7700"),
        (values.host_port, "h:0"),
        (values.domain_id, "233"),
        (values.positive, "0"),
        (values.positive, "nan"),
        (values.non_negative, "-1"),
        (values.positive_int, "1.5"),
        (values.loss_ratio, "1"),
        (values.loss_ratio, "-0.1"),
        (values.loss_ratio, "nan"),
    ]:
        with pytest.raises(values.ValueArgumentError):
            check(text)
    with pytest.raises(ValueError, match=r"^baud: baud must be an integer in 50\.\.4000000"):
        values.check(values.baud, 0, "baud")
