"""The protocol conformance suite: the host side of every rule of docs/protocol.md,
played on the wire against any controller (``rover conformance``).

- :mod:`bridge.tools.conformance.host`: :class:`WireHost`, a protocol host on one transport;
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
from bridge.tools.conformance.host import FrameRecord, WireHost
from bridge.tools.conformance.report import render_json, render_list, render_table
from bridge.tools.conformance.rules import RULES, Rule
from bridge.tools.conformance.suite import Outcome, RuleResult, exit_status, run_suite, select_rules

__all__ = [
    "RULES",
    "Context",
    "ControlClient",
    "FrameRecord",
    "Outcome",
    "Rule",
    "RuleResult",
    "WireHost",
    "exit_status",
    "render_json",
    "render_list",
    "render_table",
    "run_suite",
    "select_rules",
]
