"""Mutation testing of the conformance suite (docs/protocol.md, "Conformance suite"):
every mutant controller (:mod:`emulator.mutants`, the Python model with one rule broken)
must fail the rule it breaks, named; the real controllers pass every rule
(test_conformance.py). The suite runs in lockstep (virtual time, about a second a
mutant: :mod:`tests.bridge.lockstep_suite`)."""

from __future__ import annotations

import logging
import re
from collections.abc import Iterator
from pathlib import Path

import pytest

from bridge.tools.conformance import RULES
from emulator.controller import ControllerConfig, ControllerModel
from emulator.errors import InjectionError
from emulator.lockstep import lockstep_pair
from emulator.mutants import MUTANTS, UnknownMutantError, make_mutant, mutant
from emulator.twin import Twin
from firmware_proto.model.rover import RoverDescription

from .lockstep_suite import run_lockstep

PROTOCOL_MD = Path(__file__).resolve().parents[2] / "docs" / "protocol.md"


def _score_table() -> dict[str, tuple[str, set[str]]]:
    """docs/protocol.md's mutation table: mutant -> (rule that kills it, other rules it
    fails)."""
    text = PROTOCOL_MD.read_text(encoding="utf-8")
    table = text[text.index("### Mutation score") :]
    rows = {}
    for name, rule, others in re.findall(r"^\| `([^`]+)` \| `([^`]+)` \| ([^|]*) \|", table, re.M):
        rows[name] = (rule, set(re.findall(r"`([^`]+)`", others)))
    return rows


@pytest.fixture(autouse=True)
def _quiet() -> Iterator[None]:
    """A mutant run logs every injected fault and watchdog trip: not this test's news."""
    logging.disable(logging.WARNING)
    yield
    logging.disable(logging.NOTSET)


FAST = ("stopped-at-once", "no-accel-ramp", "no-brake-ramp")
"""The controllers issue #22 found the suite passing. The fast lane (``-m "not slow"``)
runs the first (tests/lanes.py HEAVY takes the other two out of it); every mutant runs
in the test command's soak part (tests/lanes.py IDLE, marker ``soak``): the whole score
costs about 40 CPU-seconds here (50 before the speed-ups of 2026-11-30)."""


@pytest.mark.parametrize(
    "name",
    [
        n if n in FAST else pytest.param(n, marks=[pytest.mark.slow, pytest.mark.virtual])
        for n in MUTANTS
    ],
)
def test_the_suite_fails_the_mutant_on_the_rule_it_breaks(
    name: str, rover: RoverDescription
) -> None:
    m = MUTANTS[name]
    run = run_lockstep(
        make_mutant(name, rover, Twin(rover), ControllerConfig(), seed=2), link=m.link
    )
    failed = run.failed()
    assert m.rule in failed, f"{name} ({m.breaks}) was not caught by {m.rule}: {failed}"
    # Not caught by accident: the failing rule says what it saw.
    assert failed[m.rule] and "could not start from a fresh session" not in failed[m.rule]
    # The score table says which other rules it fails, and stays true (lockstep: the
    # same every run).
    assert _score_table()[name] == (m.rule, set(failed) - {m.rule}), failed


def test_there_are_30_mutants_or_more_and_every_rule_kills_one() -> None:
    assert len(MUTANTS) >= 30
    assert {m.rule for m in MUTANTS.values()} <= set(RULES)
    assert set(RULES) <= {m.rule for m in MUTANTS.values()}
    # The two controllers issue #22 found the suite passing.
    assert MUTANTS["stopped-at-once"].rule == "stopped-at-rest"
    assert MUTANTS["no-accel-ramp"].rule == "accel-ramp"
    assert MUTANTS["no-brake-ramp"].rule == "braking"


def test_every_mutant_is_in_the_score_table_of_protocol_md() -> None:
    table = _score_table()
    assert list(table) == list(MUTANTS)
    assert {name: rule for name, (rule, _) in table.items()} == {
        m.name: m.rule for m in MUTANTS.values()
    }
    text = PROTOCOL_MD.read_text(encoding="utf-8")
    assert f"Score: {len(MUTANTS)} of {len(MUTANTS)} killed (100 %)" in text


def test_an_unknown_mutant_is_refused_with_the_known_names(rover: RoverDescription) -> None:
    with pytest.raises(UnknownMutantError, match="unknown mutant 'warp'; known: hello-delays"):
        mutant("warp")
    with pytest.raises(ValueError, match=r"known: .*stopped-at-once"):
        make_mutant("warp", rover, Twin(rover))


def test_a_lockstep_controller_refuses_link_faults(rover: RoverDescription) -> None:

    controller, _, _ = lockstep_pair(ControllerModel(rover, Twin(rover)))
    with pytest.raises(InjectionError, match="link faults need a served emulator"):
        controller.inject("link-drop=0.5")
    with pytest.raises(ValueError, match="unknown lockstep medium 'warp'; known: serial, can"):
        lockstep_pair(ControllerModel(rover, Twin(rover)), "warp")
