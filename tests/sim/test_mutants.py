"""The simulator finds real bugs by itself: each fix of the host's core, undone on
purpose (a mutant: a subclass of the core, :data:`sim.linkmutants.MUTANTS`), is found
within the test command's budget, with the one command line that plays it again; with the fix in
place the same scenario passes.

The two bugs of issue #22 are searched for from seed 0 in the test command (marked
``slow`` and ``virtual``: about 14 s each), and the seeds that search finds are replayed
in the fast lane; the three the simulator found in the core (docs/sim.md, "Bugs found")
stay as regression seeds."""

from __future__ import annotations

import dataclasses
import shlex
import subprocess
import sys

import pytest

from sim.linkmutants import MUTANTS
from sim.rig import ScenarioOutcome, run_scenario
from sim.scenario import CONTROLLERS, MEDIA, make_scenario
from sim.soak import soak

SEARCH = 1000
"""Scenarios a #22 mutant gets to be found in, from seed 0."""

ISSUE_22 = [
    pytest.param("auto-clear-survives", "auto-clear", 1, id="auto-clear-survives"),
    pytest.param("samples-outside-session", "odometry", 22, id="samples-outside-session"),
]
"""(mutant, the invariant it breaks, the first seed that finds it against both
controllers): the fixes of issue #22, undone."""

FOUND = [
    pytest.param("settle-by-guess", 1481, "can", "truthful", id="settle-by-guess"),
    pytest.param("watchdog-frame-twice", 3371, "can", "counters", id="watchdog-frame-twice"),
]
"""(mutant, seed, medium, the invariant it breaks): the bugs the simulator found in
LinkCore, each now fixed."""


ISSUE_40 = [
    pytest.param("", "clear-ignores-generation", 6, "serial", "release", id="hole-1"),
    pytest.param("refused-clear-retried", "", 36, "serial", "release", id="hole-2"),
    pytest.param("clear-drops-stop", "", 24, "serial", "stopped", id="hole-3"),
    pytest.param("step-refused-during-clear", "", 82, "serial", "order", id="hole-4"),
    pytest.param("clear-copies-queue", "", 1, "can", "repeat", id="hole-7"),
]
"""(host mutant, controller mutant, seed, medium, the invariant it breaks): the holes of
issue #40 that the latch generation closes, each with its fix undone, found by seed. A
controller mutant is the Python model with one rule broken (:mod:`emulator.mutants`)."""


MASKED = {"auto-clear-after-fault-frame"}
"""Found by the simulator against protocol v2 controllers (docs/sim.md, "Bugs found" 3);
a v3 controller answers a repeated CLEAR_STOP id CLEARED without releasing anything,
which makes the bug unreachable from the wire: the fix and its mutant stay for a
controller that does not."""


def test_every_mutant_is_tested() -> None:
    tested = {"auto-clear-survives", "samples-outside-session"} | {p.values[0] for p in FOUND}
    tested |= {p.values[0] for p in ISSUE_40 if p.values[0]}
    assert tested | MASKED == set(MUTANTS)


def _failures_of(mutant: str, controller: str, rule: str, seeds: range) -> list[ScenarioOutcome]:
    """The failures ``seeds`` show against ``mutant`` (the search stops at the first);
    each breaks ``rule`` and passes with the fix in place. The controller also sends
    samples before a session, as a protocol v2 one did: without them the second bug
    cannot happen (a v3 controller sends none)."""
    report = soak(
        seeds,
        controllers=(controller,),
        media=MEDIA,
        mutants=(mutant,),
        leak_samples=True,
        stop_on_failure=len(seeds) > 1,
    )
    assert report.failures, f"{mutant} not found in seeds {seeds.start}..{seeds.stop - 1}"
    for failure in report.failures:
        assert rule in {v.rule for v in failure.violations}, failure.violations
        fixed = run_scenario(dataclasses.replace(failure.scenario, mutants=()))
        assert fixed.ok, fixed.violations
    return report.failures


@pytest.mark.slow
@pytest.mark.virtual
@pytest.mark.timeout(600)  # about 14 s of CPU; .ci/test runs it below the real-time tests
@pytest.mark.parametrize("controller", CONTROLLERS)
@pytest.mark.parametrize(("mutant", "rule", "first_seed"), ISSUE_22)
def test_the_simulator_finds_each_fix_of_issue_22_undone(
    mutant: str, rule: str, first_seed: int, controller: str
) -> None:
    found = _failures_of(mutant, controller, rule, range(SEARCH))[0]
    print(f"{mutant}: found at {found.scenario.reproducer}")
    assert found.scenario.seed == first_seed, "the search changed: update ISSUE_22"


@pytest.mark.parametrize("controller", CONTROLLERS)
@pytest.mark.parametrize(("mutant", "rule", "first_seed"), ISSUE_22)
def test_the_seeds_that_find_issue_22s_fixes_undone_still_do(
    mutant: str, rule: str, first_seed: int, controller: str
) -> None:
    """The fast lane's share of the search above: its finds, replayed."""
    _failures_of(mutant, controller, rule, range(first_seed, first_seed + 1))


@pytest.mark.timeout(60)
@pytest.mark.parametrize("controller", CONTROLLERS)
@pytest.mark.parametrize(("mutant", "seed", "medium", "rule"), FOUND)
def test_each_bug_the_simulator_found_stays_found_and_fixed(
    mutant: str, seed: int, medium: str, rule: str, controller: str
) -> None:
    broken = make_scenario(seed, controller=controller, medium=medium, mutants=(mutant,))
    outcome = run_scenario(broken)
    assert rule in {v.rule for v in outcome.violations}, outcome.violations
    fixed = run_scenario(dataclasses.replace(broken, mutants=()))
    assert fixed.ok, fixed.violations


@pytest.mark.timeout(60)
@pytest.mark.parametrize(("mutant", "controller_mutant", "seed", "medium", "rule"), ISSUE_40)
def test_each_hole_of_issue_40_is_found_with_its_fix_undone_and_closed_with_it(
    mutant: str, controller_mutant: str, seed: int, medium: str, rule: str
) -> None:
    controllers = ("python",) if controller_mutant else CONTROLLERS
    for controller in controllers:
        broken = make_scenario(
            seed,
            controller=controller,
            medium=medium,
            mutants=(mutant,) if mutant else (),
            controller_mutant=controller_mutant,
        )
        outcome = run_scenario(broken)
        assert rule in {v.rule for v in outcome.violations}, (controller, outcome.violations)
        fixed = run_scenario(dataclasses.replace(broken, mutants=(), controller_mutant=""))
        assert fixed.ok, (controller, fixed.violations)


@pytest.mark.timeout(120)
def test_a_failure_replays_exactly_from_its_one_line_reproducer() -> None:
    scenario = make_scenario(778, controller="c", medium="serial", mutants=("auto-clear-survives",))
    first = run_scenario(scenario)
    again = run_scenario(scenario)
    assert not first.ok
    assert (again.digest, again.violations) == (first.digest, first.violations)
    # The printed line, as an operator would paste it, in a process of its own.
    argv = shlex.split(scenario.reproducer)
    assert argv[:2] == ["rover", "sim"]
    done = subprocess.run(
        [sys.executable, "-m", "firmware_proto.cli", *argv[1:]],
        capture_output=True,
        text=True,
        timeout=100,
        check=False,
    )
    assert done.returncode == 1, done.stderr
    assert f"digest {first.digest}" in done.stdout
    for violation in first.violations:
        assert violation.line() in done.stdout
    assert f"reproduce: {scenario.reproducer}" in done.stdout


def test_an_unknown_mutant_is_refused_with_the_known_ones() -> None:
    from bridge.link.linktypes import LinkConfig
    from sim.linkmutants import make_link_core

    with pytest.raises(ValueError, match="known: " + ", ".join(sorted(MUTANTS))):
        make_link_core(LinkConfig("sim://x"), ["no-such-fix"])


def test_mutants_combine_and_the_product_core_holds_no_switch() -> None:
    import inspect

    from bridge.link import controllerlink, linkcore
    from bridge.link.linktypes import LinkConfig
    from sim.linkmutants import make_link_core

    every = make_link_core(LinkConfig("sim://x"), MUTANTS)
    assert isinstance(every, linkcore.LinkCore)
    assert type(make_link_core(LinkConfig("sim://x"))) is linkcore.LinkCore
    for cls in (linkcore.LinkCore, controllerlink.ControllerLink):
        assert "mutants" not in inspect.signature(cls).parameters
        assert "self.mutants" not in inspect.getsource(cls)
