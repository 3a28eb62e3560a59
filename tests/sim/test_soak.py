"""The bulk of the link's behaviour in virtual time: thousands of seeded scenarios
against each controller (docs/sim.md), every invariant checked after each.

The test command plays 5,000 scenarios per controller (four chunks of 1,250, in its
soak part: marker ``soak``), on both media, which is more than one simulated
rover-hour each; the fast lane (``-m "not slow"``) plays 40 per controller."""

from __future__ import annotations

import pytest

from sim.scenario import CONTROLLERS, MEDIA
from sim.soak import SoakReport, soak

CHUNK = 1250
CHUNKS = 4
QUICK = 40
"""Scenarios per controller in the fast lane's quick soak (about a second of CPU each)."""
FIRST_SEED = {"python": 0, "c": 100_000}
"""Each controller plays its own seeds (a seed picks the medium)."""


def _check(report: SoakReport) -> None:
    assert report.failures == [], "\n".join(report.lines())


@pytest.mark.slow
@pytest.mark.virtual
@pytest.mark.soak  # .ci/test runs these in a part of their own, on CPU no other part wants
# About 10-20 s of CPU; .ci/test runs it below every other part and stops it while its
# serial part and VM run (a chunk took 919 s of wall time there on a slow host).
@pytest.mark.timeout(1800)
@pytest.mark.parametrize("chunk", range(CHUNKS))
@pytest.mark.parametrize("controller", CONTROLLERS)
def test_thousands_of_seeded_scenarios_keep_every_invariant(controller: str, chunk: int) -> None:
    first = FIRST_SEED[controller] + chunk * CHUNK
    report = soak(range(first, first + CHUNK), controllers=(controller,), media=MEDIA)
    print("\n".join(report.lines()))
    _check(report)
    assert report.scenarios == CHUNK
    # A quarter of a simulated rover-hour per chunk: an hour per controller and run.
    assert report.sim_s >= 900.0
    # The faults happened: the scenarios are not idle.
    counts = report.counts
    assert counts["reboots"] > 50 and counts["watchdog_trips"] > 50, counts
    assert counts["completed"] > 1000 and counts["aborted"] > 500, counts


@pytest.mark.timeout(120)
@pytest.mark.parametrize("controller", CONTROLLERS)
def test_a_quick_soak_for_the_fast_lane(controller: str) -> None:
    first = FIRST_SEED[controller] + CHUNKS * CHUNK
    report = soak(range(first, first + QUICK), controllers=(controller,), media=MEDIA)
    _check(report)
    assert report.by_controller[controller][0] == QUICK
