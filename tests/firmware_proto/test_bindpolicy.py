"""The bind and token policy the gate and the live view share."""

from __future__ import annotations

from pathlib import Path

import pytest

from firmware_proto.errors import BindPolicyError, ProtoError
from firmware_proto.http.bindpolicy import (
    HostPolicy,
    bearer_token,
    check_bind,
    check_token,
    host_name,
    is_loopback,
    token_matches,
)


def test_loopback_addresses() -> None:
    for host in ("127.0.0.1", "127.9.9.9", "::1", "localhost"):
        assert is_loopback(host), host
    for host in ("0.0.0.0", "::", "10.0.0.1", "gate.example", "", "127.0.0.1.example"):
        assert not is_loopback(host), host


def test_a_public_address_needs_a_token() -> None:
    check_bind("127.0.0.1", None)
    check_bind("0.0.0.0", "k3Jf9-xQ2mPz8vLw")
    with pytest.raises(BindPolicyError, match="without a token: give --token, or bind") as info:
        check_bind("0.0.0.0", None, hint="--token")
    assert isinstance(info.value, ValueError)
    assert isinstance(info.value, ProtoError)
    for bad in ("", "a\nb", "tab\there"):
        with pytest.raises(BindPolicyError, match="view token must be"):
            check_token(bad, what="view token")
    check_token(None)


def test_bearer_tokens_are_parsed_and_compared() -> None:
    assert bearer_token("Bearer abc") == "abc"
    assert bearer_token("bearer  abc ") == "abc"
    assert bearer_token("Basic abc") is None
    assert bearer_token("") is None
    assert bearer_token(None) is None
    assert token_matches("abc", "abc")
    assert not token_matches("abd", "abc")
    assert not token_matches(None, "abc")
    assert not token_matches("\udcff", "abc")  # undecodable header bytes do not raise


def test_a_token_for_a_public_address_must_be_strong() -> None:
    strong = "k3Jf9-xQ2mPz8vLw"
    check_bind("0.0.0.0", strong)
    check_bind("127.0.0.1", "s3cret")  # loopback: any well-formed token
    for weak in ("t", "s3cret-token", "aaaaaaaaaaaaaaaaaaaa", "abababababababababab"):
        with pytest.raises(BindPolicyError, match="too weak"):
            check_bind("10.0.0.5", weak)
    with pytest.raises(BindPolicyError, match="printable"):
        check_token(" padded ")


def test_host_names_are_parsed_strictly() -> None:
    assert host_name("127.0.0.1:8080") == "127.0.0.1"
    assert host_name("LocalHost.") == "localhost"
    assert host_name("[::1]:80") == "::1"
    assert host_name("gate.lab:8080") == "gate.lab"
    for bad in (None, "", "[::1", "[nope]:1", "a b", "x:y", "évil.test", "[::1]x"):
        assert host_name(bad) is None, bad


def test_the_host_must_name_this_server() -> None:
    loop = HostPolicy.for_bind("127.0.0.1")
    for ok in ("127.0.0.1:9", "localhost:9", "[::1]:9", "127.0.0.2"):
        assert loop.allows(ok), ok
    for bad in ("rebind.example:9", "10.0.0.1", "localhost.example", None):
        assert not loop.allows(bad), bad
    wild = HostPolicy.for_bind("0.0.0.0", ["rover-ground", "Gate.Lab."])
    for ok in ("10.1.2.3:80", "[fe80::1]:80", "rover-ground", "gate.lab:8080"):
        assert wild.allows(ok), ok
    assert not wild.allows("rebind.example")
    one = HostPolicy.for_bind("10.0.0.5")
    assert one.allows("10.0.0.5:80") and not one.allows("10.0.0.6") and not one.allows("x")


def test_a_token_comes_from_a_file_never_the_command_line(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    from firmware_proto.http.tokenfile import read_token_file, refuse_token_argument

    good = tmp_path / "token"
    good.write_text("k3Jf9-xQ2mPz8vLw\n")
    good.chmod(0o600)
    assert read_token_file(good) == "k3Jf9-xQ2mPz8vLw"
    assert not caplog.records
    good.chmod(0o644)
    assert read_token_file(good) == "k3Jf9-xQ2mPz8vLw"
    assert "may be read by other users" in caplog.text
    for text in ("", "\n", "two\nlines\n", "x" * 5000):
        bad = tmp_path / "bad"
        bad.write_text(text)
        with pytest.raises(BindPolicyError, match="token file"):
            read_token_file(bad)
    with pytest.raises(BindPolicyError, match="cannot read"):
        read_token_file(tmp_path / "missing")
    error = refuse_token_argument("--token", "--token-file", "ROVER_GATE_TOKEN")
    assert isinstance(error, ValueError)
    assert "ps" in str(error) and "--token-file FILE" in str(error)
