"""Many scenarios in a row: a range of seeds, or as many as fit in a wall-clock budget,
with their figures (scenarios per second, virtual hours, speed against real time) and
every failure's one-line reproducer.

Each seed plays on the controller and medium it picks from those asked for
(:func:`assignment`: seed by seed through every combination), so that a range covers
them evenly and a failure's reproducer names the exact one.
"""

from __future__ import annotations

import itertools
import time
from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

from sim.rig import ScenarioOutcome, run_scenario
from sim.scenario import DEFAULT_TICK_S, make_scenario

__all__ = ["SoakReport", "assignment", "soak"]


def assignment(seed: int, controllers: tuple[str, ...], media: tuple[str, ...]) -> tuple[str, str]:
    """The controller and medium ``seed`` plays on: every combination in turn."""
    pairs = list(itertools.product(controllers, media))
    return pairs[seed % len(pairs)]


@dataclass
class SoakReport:
    """What a soak did.

    Attributes:
        scenarios: scenarios played.
        sim_s: virtual time simulated, s.
        wall_s: wall time spent, s (the host's clock: a figure, never an assertion).
        failures: the outcomes that broke an invariant, in seed order.
        counts: what happened over all scenarios, by name (:attr:`ScenarioOutcome.counts`).
        by_controller: scenarios and virtual seconds per controller.
    """

    scenarios: int = 0
    sim_s: float = 0.0
    wall_s: float = 0.0
    failures: list[ScenarioOutcome] = field(default_factory=list)
    counts: Counter[str] = field(default_factory=Counter)
    by_controller: dict[str, tuple[int, float]] = field(default_factory=dict)

    @property
    def rate(self) -> float:
        """Scenarios per wall second."""
        return self.scenarios / self.wall_s if self.wall_s > 0 else 0.0

    @property
    def speedup(self) -> float:
        """Virtual seconds per wall second."""
        return self.sim_s / self.wall_s if self.wall_s > 0 else 0.0

    def lines(self) -> list[str]:
        """The summary, for a terminal."""
        out = [
            f"{self.scenarios} scenarios, {self.sim_s / 3600.0:.2f} simulated rover-hours in "
            f"{self.wall_s:.1f} s: {self.rate:.0f} scenarios/s, {self.speedup:.0f}x real time, "
            f"{len(self.failures)} failed"
        ]
        for name, (n, sim_s) in sorted(self.by_controller.items()):
            out.append(f"  {name}: {n} scenarios, {sim_s / 3600.0:.2f} h")
        keys = ("steps", "completed", "aborted", "rejected", "reboots", "watchdog_trips")
        out.append("  " + ", ".join(f"{k} {self.counts[k]}" for k in keys))
        out.append(
            f"  counted, not failed (docs/sim.md): {self.counts['excused_jumps']} odometry "
            "jumps from a controller's samples before a session"
        )
        for failure in self.failures:
            out.append(f"FAIL {failure.scenario.reproducer}")
            out += [f"  {v.line()}" for v in failure.violations]
        return out


def soak(
    seeds: Iterable[int],
    *,
    controllers: tuple[str, ...] = ("python",),
    media: tuple[str, ...] = ("serial",),
    mutants: tuple[str, ...] = (),
    controller_mutant: str = "",
    leak_samples: bool = False,
    zero_steps: bool = False,
    tick_s: float = DEFAULT_TICK_S,
    budget_s: float | None = None,
    stop_on_failure: bool = False,
    on_outcome: Callable[[ScenarioOutcome], None] | None = None,
    clock: Callable[[], float] = time.perf_counter,
) -> SoakReport:
    """Play the scenarios of ``seeds`` in order.

    Args:
        seeds: the seeds (any iterable: a range, or ``itertools.count()`` with a budget).
        controllers, media: what the seeds play on (:func:`assignment`).
        mutants, controller_mutant, leak_samples, zero_steps, tick_s: as
            :func:`sim.scenario.make_scenario`.
        budget_s: stop before starting a scenario once this much wall time has passed.
        stop_on_failure: stop after the first failing scenario.
        on_outcome: called with every outcome, as it comes.
        clock: the wall clock for the budget and the figures.
    """
    report = SoakReport()
    start = clock()
    for seed in seeds:
        if budget_s is not None and clock() - start >= budget_s:
            break
        controller, medium = assignment(seed, controllers, media)
        scenario = make_scenario(
            seed,
            controller=controller,
            medium=medium,
            mutants=mutants,
            controller_mutant=controller_mutant,
            leak_samples=leak_samples,
            zero_steps=zero_steps,
            tick_s=tick_s,
        )
        outcome = run_scenario(scenario)
        report.scenarios += 1
        report.sim_s += outcome.sim_s
        report.counts.update(outcome.counts)
        n, sim_s = report.by_controller.get(controller, (0, 0.0))
        report.by_controller[controller] = (n + 1, sim_s + outcome.sim_s)
        if on_outcome is not None:
            on_outcome(outcome)
        if not outcome.ok:
            report.failures.append(outcome)
            if stop_on_failure:
                break
    report.wall_s = clock() - start
    return report
