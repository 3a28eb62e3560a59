"""The protocol conformance suite: the host side of every rule of docs/protocol.md,
played on the wire against any controller (``rover conformance``).

- :mod:`bridge.tools.conformance.wirehost`: :class:`WireHost`, a protocol host on one transport;
- :mod:`bridge.tools.conformance.control`: :class:`ControlClient`, for a device's control port
  (a reboot or a fault the host cannot cause);
- :mod:`bridge.tools.conformance.context`: :class:`Context`, what a rule works with;
- :mod:`bridge.tools.conformance.rules`: the rules, :data:`RULES`;
- :mod:`bridge.tools.conformance.suite`: :func:`run_suite` and the verdicts;
- :mod:`bridge.tools.conformance.report`: table and JSON.
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
