"""The bind and token policy the gate and the live view share."""

from __future__ import annotations

import pytest

from firmware_proto.errors import BindPolicyError, ProtoError
from firmware_proto.http.bindpolicy import (
    bearer_token,
    check_bind,
    check_token,
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
    check_bind("0.0.0.0", "t")
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
