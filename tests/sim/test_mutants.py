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
    pytest.param("samples-outside-session", "odometry", 26, id="samples-outside-session"),
]
"""(mutant, the invariant it breaks, the first seed that finds it against both
controllers): the fixes of issue #22, undone."""

FOUND = [
    pytest.param("settle-by-guess", 1481, "can", "truthful", id="settle-by-guess"),
    pytest.param("watchdog-frame-twice", 3371, "can", "counters", id="watchdog-frame-twice"),
    pytest.param("blind-clear-takes-fault", 5005, "can", "release", id="blind-clear-takes-fault"),
    pytest.param("nonce-from-ident-only", 101284, "serial", "counters", id="nonce-from-ident-only"),
]
"""(mutant, seed, medium, the invariant it breaks): the bugs the simulator found in
LinkCore, each now fixed."""


ISSUE_40 = [
    pytest.param("", "clear-ignores-generation", 6, "serial", "release", id="hole-1"),
    pytest.param("refused-clear-retried", "", 36, "serial", "release", id="hole-2"),
    pytest.param("clear-drops-stop", "", 24, "serial", "stopped", id="hole-3"),
    pytest.param("step-refused-during-clear", "", 82, "serial", "order", id="hole-4"),
    pytest.param("boot-ident-ignored", "reboot-keeps-nonce", 20, "serial", "odometry", id="hole-5"),
    pytest.param("lost-from-read-total", "", 4, "serial", "counters", id="hole-6"),
    pytest.param("clear-copies-queue", "", 24, "can", "repeat", id="hole-7"),
    pytest.param("request-ids-from-one", "", 16, "serial", "request-id", id="hole-8"),
]
"""(host mutant, controller mutant, seed, medium, the invariant it breaks): the holes of
issue #40, each with its fix undone, found by seed. A controller mutant is the Python
model with one rule broken (:mod:`emulator.mutants`): hole 5 has two fixes, the
controller's (a new boot nonce differs from the last; conformance rule ``reboot`` kills
the same mutant) and the bridge's (a boot IDENT is a reboot whatever its nonce): it is
found with both undone, and each alone closes it
(:func:`test_hole_5_either_fix_alone_closes_it`)."""


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


def test_hole_5_a_repeated_nonce_shows_as_the_issue_saw_it() -> None:
    """A controller whose reboot keeps its boot nonce: /odom jumps, the reboot is not
    counted and the restarted frame counter is counted as lost frames, each seen against
    the simulator's knowledge of every frame's boot."""
    broken = make_scenario(
        20, medium="serial", mutants=("boot-ident-ignored",), controller_mutant="reboot-keeps-nonce"
    )
    lines = [v.line() for v in run_scenario(broken).violations]
    assert any("odometry moved" in x for x in lines), lines
    assert any("reboots is 0, the simulator saw 1" in x for x in lines), lines
    assert any("lost_frames 172, the frame counter's gaps" in x for x in lines), lines


@pytest.mark.parametrize("seed", [7, 9, 20, 26, 41, 87])
def test_hole_5_either_fix_alone_closes_it(seed: int) -> None:
    """A controller that repeats its nonce, against the bridge as it is: the boot IDENT,
    or a session lost on the serial link, tells the reboot (odometry re-based, the
    reboot counted, the counter's restart no loss); and a conforming controller against
    the bridge that relies on the nonce. The seeds reboot the controller on a live link
    (20), during an unplug (7, 26), a cut (9) and right after answering a HELLO (41,
    87): a reboot that repeats the nonce while the link is down shows no sign, and the
    simulator lets the host count it or not (sim.checks)."""
    keeps = make_scenario(seed, medium="serial", controller_mutant="reboot-keeps-nonce")
    assert {"reboot", "hello-reboot"} & {f.kind for f in keeps.faults}, keeps.faults
    outcome = run_scenario(keeps)
    assert outcome.ok, outcome.violations
    relies = make_scenario(seed, medium="serial", mutants=("boot-ident-ignored",))
    outcome = run_scenario(relies)
    assert outcome.ok, outcome.violations


def test_hole_6_is_a_reboot_crossing_a_hello() -> None:
    """Its seed holds the scenario element made for it: the controller answers the HELLO
    after an outage and reboots at once, both IDENTs in one read."""
    scenario = make_scenario(4, medium="serial", mutants=("lost-from-read-total",))
    assert "hello-reboot" in {f.kind for f in scenario.faults}
    outcome = run_scenario(scenario, trace=True)
    assert any("hello-reboot armed" in line for line in outcome.trace)
    [violation] = [v for v in outcome.violations if "lost_frames" in v.text][:1]
    assert "less each reboot's say" in violation.text


def test_hole_8_is_a_bridge_restarted_on_one_boot() -> None:
    """Its seed restarts the bridge after an operator's STOP: the new bridge's first
    request (its clear) took the id of the old bridge's STOP. With ids drawn at random the
    two bridges' ids do not meet."""
    scenario = make_scenario(16, medium="serial", mutants=("request-ids-from-one",))
    assert "host-restart" in {f.kind for f in scenario.faults}
    [violation] = run_scenario(scenario).violations
    assert violation.text.endswith("sent request id 1, which bridge 0 used on this controller boot")
    fixed = run_scenario(dataclasses.replace(scenario, mutants=()))
    assert fixed.ok and fixed.counts["id_collisions"] == 0


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
