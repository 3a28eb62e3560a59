"""The ``rover`` entry point and its protocol tools, run as a real subprocess."""

from __future__ import annotations

import subprocess
import sys

import cantools
import pytest

from firmware_proto.wire.framing import FrameDecoder
from firmware_proto.wire.messages import Motion


def rover(*args: str, timeout: float = 60.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "firmware_proto.cli", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        check=False,
    )


def test_help_lists_subcommands() -> None:
    out = rover("--help")
    assert out.returncode == 0
    assert "frame" in out.stdout and "roundtrip" in out.stdout


def test_encode_then_decode_round_trip() -> None:
    enc = rover("frame", "encode", "MOTION", "seq=7", "command=FWD", "speed=30", "distance=23000")
    assert enc.returncode == 0, enc.stderr
    wire = bytes.fromhex(enc.stdout)
    assert [f.message for f in FrameDecoder().feed(wire)] == [Motion(7, 1, 30, 23000)]
    dec = rover("frame", "decode", enc.stdout.strip())
    assert dec.returncode == 0
    assert "MOTION seq=7 command=FWD speed=30 distance=23000" in dec.stdout


def test_encode_errors_are_clear_and_exit_1() -> None:
    out = rover("frame", "encode", "MOTION", "seq=1", "command=FWD", "speed=61", "distance=0")
    assert out.returncode == 1
    assert "MOTION.speed=61 outside its limit 0..60" in out.stderr
    assert "Traceback" not in out.stderr
    loose = rover(
        "frame", "encode", "--loose", "MOTION", "seq=1", "command=FWD", "speed=61", "distance=0"
    )
    assert loose.returncode == 0
    missing = rover("frame", "encode", "MOTION", "seq=1")
    assert missing.returncode == 1 and "needs command=" in missing.stderr
    unknown = rover("frame", "encode", "WARP")
    assert unknown.returncode == 1 and "known:" in unknown.stderr


def test_can_encode_and_decode() -> None:
    enc = rover("frame", "encode", "--can", "3", "STOP", "stop_id=9", "source=DRIFT")
    assert enc.returncode == 0
    arb, data = enc.stdout.strip().split("#")
    assert int(arb, 16) == 3
    dec = rover("frame", "decode", "--can-id", f"0x{arb}", data)
    assert "node 3: STOP stop_id=9 source=DRIFT" in dec.stdout


def test_decode_of_garbage_reports_drops_and_exits_1() -> None:
    out = rover("frame", "decode", "00 11 22 33 00")
    assert out.returncode == 1
    assert "dropped" in out.stdout
    bad = rover("frame", "decode", "zz")
    assert bad.returncode == 1 and "not hex" in bad.stderr


@pytest.mark.parametrize("node", ["0", "16", "-1", "2000"])
def test_dbc_refuses_a_node_that_is_not_a_controller(node: str) -> None:
    out = rover("frame", "dbc", "--node", node)
    assert out.returncode == 2  # a usage error, in the words every command uses
    assert out.stderr.splitlines()[-1] == (
        f"rover frame dbc: error: argument --node: node must be an integer in 1..15, got {node!r}"
    )


@pytest.mark.parametrize("node", [1, 15])
def test_dbc_for_a_valid_node_loads_in_cantools_with_that_nodes_ids(node: int) -> None:
    out = rover("frame", "dbc", "--node", str(node))
    assert out.returncode == 0, out.stderr
    db = cantools.database.load_string(out.stdout, database_format="dbc")
    assert isinstance(db, cantools.database.can.Database)
    ids = [m.frame_id for m in db.messages]
    assert len(set(ids)) == len(ids)
    assert all(i & 0xF == node and i <= 0x7FF for i in ids)


@pytest.mark.parametrize(
    ("args", "error"),
    [
        (["encode", "--seq", "256", "STOP", "stop_id=1", "source=0"], "--seq 256 outside 0..255"),
        (["encode", "--seq", "-1", "STOP", "stop_id=1", "source=0"], "--seq -1 outside 0..255"),
        (["encode", "--can", "1", "--seq", "3", "STOP", "stop_id=1", "source=0"], "--seq is"),
        (["decode", "--can-id", "-1", "0001"], "--can-id -1 is not a CAN identifier"),
        (["decode", "--can-id", "0x20000000", "0001"], "is not a CAN identifier"),
    ],
)
def test_out_of_range_numeric_options_fail_with_one_line(args: list[str], error: str) -> None:
    out = rover("frame", *args)
    assert out.returncode == 1
    assert out.stdout == ""
    [line] = out.stderr.splitlines()
    assert line.startswith("rover frame: error: ") and error in line


@pytest.mark.parametrize("node", ["16", "-1"])
def test_encode_refuses_a_node_outside_0_to_15_as_a_usage_error(node: str) -> None:
    out = rover("frame", "encode", "--can", node, "STOP", "stop_id=1", "source=0")
    assert out.returncode == 2 and out.stdout == ""
    assert "node must be an integer in 0..15 (0: broadcast)" in out.stderr.splitlines()[-1]


def test_encode_takes_fields_after_its_options() -> None:
    out = rover("frame", "encode", "STOP", "--can", "3", "stop_id=9", "source=DRIFT")
    assert out.returncode == 0, out.stderr
    assert (
        out.stdout
        == rover("frame", "encode", "--can", "3", "STOP", "stop_id=9", "source=DRIFT").stdout
    )
    bad = rover("frame", "encode", "STOP", "--can", "3", "stop_id=9", "--bogus")
    assert bad.returncode == 2 and "unrecognized arguments" in bad.stderr


def test_decode_of_bytes_without_a_frame_says_why() -> None:
    out = rover("frame", "decode", "deadbeef")
    assert out.returncode == 1 and out.stdout == ""
    [line] = out.stderr.splitlines()
    assert line.startswith("rover frame: error: no frame decoded from 4 byte(s): ")
    assert "without a frame delimiter" in line


def test_numeric_options_at_their_limits_are_accepted() -> None:
    enc = rover("frame", "encode", "--seq", "255", "STOP", "stop_id=1", "source=0")
    assert enc.returncode == 0, enc.stderr
    assert [f.seq for f in FrameDecoder().feed(bytes.fromhex(enc.stdout))] == [255]
    bad = rover("frame", "decode", "--can-id", "zz", "0001")
    assert bad.returncode == 2 and "expected an integer such as 19 or 0x013" in bad.stderr


def test_generate_check_passes_on_a_fresh_tree() -> None:
    out = rover("frame", "generate", "--check")
    assert out.returncode == 0, out.stdout


def test_roundtrip_over_a_real_pty() -> None:
    out = rover("roundtrip", "--count", "3000", "--seed", "4")
    assert out.returncode == 0, out.stdout + out.stderr
    assert "result: OK" in out.stdout
    assert "altered frames delivered: 0" in out.stdout


def test_roundtrip_help_prints_its_percent_sign_once() -> None:
    # argparse %-formats help= strings but not a description without %(prog)s.
    out = rover("roundtrip", "--help")
    assert out.returncode == 0
    assert "1% by default" in " ".join(out.stdout.split()) and "%%" not in out.stdout
