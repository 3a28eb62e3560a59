"""The protocol conformance suite: the host side of every rule of docs/protocol.md,
played on the wire against any controller (``rover conformance``; docs/protocol.md,
"Conformance suite").
"""

from __future__ import annotations

from bridge.tools.conformance.context import Context
from bridge.tools.conformance.control import ControlClient
from bridge.tools.conformance.report import render_json, render_list, render_table
from bridge.tools.conformance.rules import RULES, Rule
from bridge.tools.conformance.suite import (
    RuleOutcome,
    RuleResult,
    exit_status,
    run_suite,
    select_rules,
)
from bridge.tools.conformance.wirehost import FrameRecord, WireHost

__all__ = [
    "RULES",
    "Context",
    "ControlClient",
    "FrameRecord",
    "Rule",
    "RuleOutcome",
    "RuleResult",
    "WireHost",
    "exit_status",
    "render_json",
    "render_list",
    "render_table",
    "run_suite",
    "select_rules",
]
