"""Run rules against a controller and collect one verdict per rule.

:func:`run_suite` prepares a fresh session before each rule (``Context.prepare``), runs
it, and turns what happened into a :class:`RuleResult` (``not run`` is never a pass). A
rule that leaves the controller in a state the next cannot start from makes the next one
fail in its preparation, saying so.
"""

from __future__ import annotations

import enum
import logging
import time
from collections.abc import Iterable
from dataclasses import dataclass

from bridge.errors import ConformanceError, RuleFailedError, RuleNotRunError
from bridge.tools.conformance.context import Context
from bridge.tools.conformance.rules import RULES, Rule
from bridge.tools.conformance.wirehost import FrameRecord
from firmware_proto.linkio.errors import ExpectationError, LinkError

__all__ = ["RuleOutcome", "RuleResult", "exit_status", "run_suite", "select_rules"]

logger = logging.getLogger(__name__)


class RuleOutcome(enum.Enum):
    """A rule's verdict."""

    PASS = "pass"
    FAIL = "fail"
    NOT_RUN = "not run"


@dataclass(frozen=True)
class RuleResult:
    """What one rule found.

    Attributes:
        outcome: pass, fail or not run.
        detail: on pass a note, on fail what went wrong, when not run what it needs.
        frames: the frames exchanged while it ran (sensor samples only counted).
        samples: sensor samples (ENCODERS, WHEEL_SPEEDS, IMU, POSE) received meanwhile.
        duration_s: how long it took, preparation included.
    """

    rule: Rule
    outcome: RuleOutcome
    detail: str
    frames: tuple[FrameRecord, ...]
    samples: int
    duration_s: float


def select_rules(ids: Iterable[str] = ()) -> list[Rule]:
    """The rules named (all, in running order, when none are).

    Raises:
        ConformanceError: an unknown id; lists the known ones.
    """
    wanted = [i for text in ids for i in text.split(",") if i]
    unknown = [i for i in wanted if i not in RULES]
    if unknown:
        raise ConformanceError(f"unknown rule {', '.join(unknown)}; known: {', '.join(RULES)}")
    return [r for r in RULES.values() if not wanted or r.id in wanted]


def run_suite(ctx: Context, rules: Iterable[Rule]) -> list[RuleResult]:
    """Run each rule in turn against the controller behind ``ctx``."""
    results = []
    for rule in rules:
        results.append(_run_one(ctx, rule))
        logger.info("rule %s: %s", rule.id, results[-1].outcome.value)
    return results


def _run_one(ctx: Context, rule: Rule) -> RuleResult:
    host = ctx.host
    host.start_log()
    started = time.monotonic()
    try:
        try:
            ctx.prepare()
        except (RuleFailedError, ExpectationError) as exc:
            raise RuleFailedError(f"could not start from a fresh session: {exc}") from exc
        outcome, detail = RuleOutcome.PASS, rule.run(ctx)
    except RuleNotRunError as exc:
        outcome, detail = RuleOutcome.NOT_RUN, str(exc)
    except (ConformanceError, ExpectationError, LinkError) as exc:
        # A check that failed, an answer that did not come (or came and must not), a
        # control port or a link that failed.
        outcome, detail = RuleOutcome.FAIL, str(exc)
    frames, samples = host.take_log()
    return RuleResult(rule, outcome, detail, frames, samples, time.monotonic() - started)


def exit_status(results: Iterable[RuleResult]) -> int:
    """0 when every rule passed, 1 when any failed, 3 when none failed but some were not
    run (an incomplete verdict is not a pass)."""
    outcomes = {r.outcome for r in results}
    if RuleOutcome.FAIL in outcomes:
        return 1
    if RuleOutcome.NOT_RUN in outcomes:
        return 3
    return 0
