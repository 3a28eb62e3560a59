"""The conformance suite in lockstep: a controller (the Python model, the C core, a
mutant) in process, the suite's host on the same virtual clock, an in-memory serial line
or a python-can ``virtual`` bus between them (:mod:`emulator.lockstep`). A whole run is
about 30 s of virtual time and takes about a second.

``python -m tests.bridge.lockstep_suite --firmware c`` runs it as a program (for the C
core's sanitizer build, which needs libasan preloaded in a process of its own) and
prints one JSON line: every rule's outcome and detail, and the virtual time.
``--mutation-table`` runs it against every mutant (:mod:`emulator.mutants`) and prints
the rows of docs/protocol.md's mutation score table (firmware_proto/wire/codegen/
protocol.md.tmpl) and the score.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from bridge.errors import ConformanceError
from bridge.tools.conformance import RULES, Context, Rule, RuleResult, WireHost, run_suite
from emulator.controller import ControllerConfig, ControllerModel
from emulator.errors import InjectionError
from emulator.firmware import FIRMWARES, make_controller
from emulator.lockstep import LockstepController, lockstep_pair
from emulator.mutants import MUTANTS, mutant
from emulator.twin import Twin
from firmware_proto.linkio.endpoint import Endpoint
from firmware_proto.model.rover import load_rover


@dataclass(frozen=True)
class LockstepRun:
    """One run: the verdicts and the virtual time it took, s."""

    results: list[RuleResult]
    virtual_s: float

    def failed(self) -> dict[str, str]:
        """Rule id -> detail of every rule that did not pass."""
        return {r.rule.id: r.detail for r in self.results if r.outcome.value != "pass"}


class _Control:
    """The lockstep controller's ``inject`` as a control port (its refusals are the
    suite's errors, as a TCP control port's are)."""

    def __init__(self, controller: LockstepController) -> None:
        self._controller = controller

    def inject(self, fault: str) -> dict[str, Any]:
        try:
            return self._controller.inject(fault)
        except InjectionError as exc:
            raise ConformanceError(f"control refused {fault!r}: {exc}") from exc


def run_lockstep(
    model: ControllerModel,
    medium: str = "serial",
    *,
    rules: list[Rule] | None = None,
    control: bool = True,
    link: Callable[[Endpoint], None] | None = None,
) -> LockstepRun:
    """The suite against ``model`` (not yet booted) in lockstep on ``medium``; ``link``
    changes the controller's endpoint first (a mutant's)."""
    controller, endpoint, clock = lockstep_pair(model, medium, node=3)
    if link is not None:
        link(controller.endpoint)
    controller.open()
    try:
        with WireHost(endpoint, clock=clock) as host:
            ctx = Context(host, _Control(controller) if control else None, model.rover)
            results = run_suite(ctx, rules if rules is not None else list(RULES.values()))
    finally:
        controller.close()
    return LockstepRun(results, clock.now())


def make(firmware: str, seed: int = 2) -> ControllerModel:
    """A fresh controller of ``firmware`` on the packaged rover, on an open plane."""
    rover = load_rover()
    return make_controller(firmware, rover, Twin(rover), ControllerConfig(), seed=seed)


def mutant_run(name: str, medium: str = "serial") -> LockstepRun:
    """The suite against mutant ``name`` (its link change applied)."""
    m = mutant(name)
    rover = load_rover()
    return run_lockstep(
        m.model(rover, Twin(rover), ControllerConfig(), seed=2), medium, link=m.link
    )


def mutation_table() -> tuple[list[str], int]:
    """The mutation score table's rows (mutant, the rule that must kill it, the other
    rules it fails, what it breaks) and how many were killed by their rule."""
    rows, killed = [], 0
    for name, m in MUTANTS.items():
        failed = mutant_run(name).failed()
        killed += m.rule in failed
        others = ", ".join(f"`{r}`" for r in failed if r != m.rule) or "-"
        caught = f"`{m.rule}`" if m.rule in failed else f"NOT CAUGHT by `{m.rule}`"
        rows.append(f"| `{name}` | {caught} | {others} | {m.breaks} |")
    return rows, killed


def main(argv: list[str] | None = None) -> int:
    """Run the suite in lockstep; print one JSON line (or the mutation table); 0 when
    every rule passed (every mutant was killed)."""
    p = argparse.ArgumentParser(prog="python -m tests.bridge.lockstep_suite")
    p.add_argument("--firmware", choices=FIRMWARES, default="python")
    p.add_argument("--medium", choices=("serial", "can"), default="serial")
    p.add_argument("--mutation-table", action="store_true")
    args = p.parse_args(argv)
    if args.mutation_table:
        logging.disable(logging.WARNING)
        rows, killed = mutation_table()
        sys.stdout.write("\n".join(rows) + f"\n\n{killed} of {len(rows)} killed\n")
        return 0 if killed == len(rows) else 1
    run = run_lockstep(make(args.firmware), args.medium)
    doc = {
        "outcomes": {r.rule.id: r.outcome.value for r in run.results},
        "failed": run.failed(),
        "virtual_s": round(run.virtual_s, 3),
    }
    sys.stdout.write(json.dumps(doc) + "\n")
    return 1 if run.failed() else 0


if __name__ == "__main__":
    sys.exit(main())
