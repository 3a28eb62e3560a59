"""The suite's verdict as a table for people or JSON for machines."""

from __future__ import annotations

import json
from collections.abc import Sequence
from typing import Any

from bridge.tools.conformance.rules import Rule
from bridge.tools.conformance.suite import RuleOutcome, RuleResult

__all__ = ["render_json", "render_list", "render_table"]


def render_table(results: Sequence[RuleResult], *, url: str, frames: bool = False) -> str:
    """One row per rule (id, outcome, frames exchanged, detail), a summary line, and the
    frames of every rule that failed (of every rule with ``frames``)."""
    rows = [("rule", "result", "frames", "detail")]
    rows += [(r.rule.id, r.outcome.value.upper(), str(len(r.frames)), r.detail) for r in results]
    widths = [max(len(row[i]) for row in rows) for i in range(3)]
    lines = [f"conformance of {url} (docs/protocol.md)", ""]
    for row in rows:
        lines.append(
            "  ".join(cell.ljust(w) for cell, w in zip(row, widths, strict=False)) + "  " + row[3]
        )
    counts = {o: sum(r.outcome is o for r in results) for o in RuleOutcome}
    lines += [
        "",
        f"{counts[RuleOutcome.PASS]} passed, {counts[RuleOutcome.FAIL]} failed, "
        f"{counts[RuleOutcome.NOT_RUN]} not run, of {len(results)} rules",
    ]
    for r in results:
        if r.outcome is RuleOutcome.FAIL or frames:
            lines += ["", f"== {r.rule.id} ({r.outcome.value}): {r.rule.statement}"]
            lines += [f"  {f.line()}" for f in r.frames]
            lines.append(f"  (+ {r.samples} sensor samples)")
    return "\n".join(lines) + "\n"


def render_json(results: Sequence[RuleResult], *, url: str) -> str:
    """Every result with its frames, as one JSON document."""
    doc: dict[str, Any] = {
        "device": url,
        "passed": sum(r.outcome is RuleOutcome.PASS for r in results),
        "failed": sum(r.outcome is RuleOutcome.FAIL for r in results),
        "not_run": sum(r.outcome is RuleOutcome.NOT_RUN for r in results),
        "rules": [
            {
                "id": r.rule.id,
                "section": r.rule.section,
                "statement": r.rule.statement,
                "outcome": r.outcome.value,
                "detail": r.detail,
                "duration_s": round(r.duration_s, 3),
                "sensor_samples": r.samples,
                "frames": [
                    {"t_s": f.t_s, "direction": f.direction, "frame": f.text} for f in r.frames
                ],
            }
            for r in results
        ],
    }
    return json.dumps(doc, indent=2) + "\n"


def render_list(rules: Sequence[Rule]) -> str:
    """``--list``: id, what it needs, the section, and the statement."""
    lines = []
    for rule in rules:
        needs = f" [needs {rule.needs}]" if rule.needs else ""
        lines.append(f"{rule.id}{needs} ({rule.section})\n    {rule.statement}")
    return "\n".join(lines) + "\n"
