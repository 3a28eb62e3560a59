"""``rover status``/``clear-stop --ros`` that hear no bridge name the lone bridge's
namespace (docs/commands.md): the wording, checked in the fast lane; the commands
printing it are checked against real DDS in tests/planner/test_console.py."""

from __future__ import annotations

import argparse

from planner.ground.cli_console import namespace_hint, register_status


def test_the_default_namespace_points_a_lone_bridge_to_the_root() -> None:
    hint = namespace_hint(None)
    assert hint.startswith("; ") and hint.endswith("add --namespace /")
    assert "bridge started alone" in hint


def test_a_namespace_given_gets_no_hint() -> None:
    assert namespace_hint("/") == ""
    assert namespace_hint("ground") == ""


def test_the_status_parser_leaves_the_namespace_unset_by_default() -> None:
    """The hint keys on ``--namespace`` being absent: the parser must not fill it in."""
    parser = argparse.ArgumentParser()
    sub = parser.add_subparsers()
    register_status(sub)
    assert parser.parse_args(["status"]).namespace is None
    assert parser.parse_args(["status", "--namespace", "/"]).namespace == "/"
