"""The wire simulator: the host's protocol core, a controller (the Python model or the C
firmware core) and its twin, and a serial line or a CAN bus between them, in virtual
time, with seeded faults; invariants checked after every scenario, and any failure
played again from its seed (docs/sim.md, ``rover sim``). Also the calibration's
missions driven in lockstep (:mod:`sim.calibration_runs`).

Above the bridge and the emulator: it imports both (and the protocol), and nothing of
ours imports it but its own command and the tests.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from firmware_proto.lazyexports import lazy_exports

if TYPE_CHECKING:
    from sim.checks import RULES, Violation
    from sim.rig import Rig, ScenarioOutcome, run_scenario
    from sim.scenario import CONTROLLERS, MEDIA, Scenario, make_scenario

__getattr__, __dir__ = lazy_exports(
    __name__,
    {
        "sim.checks": ("RULES", "Violation"),
        "sim.rig": ("ScenarioOutcome", "Rig", "run_scenario"),
        "sim.scenario": ("CONTROLLERS", "MEDIA", "Scenario", "make_scenario"),
    },
)

__all__ = [
    "CONTROLLERS",
    "MEDIA",
    "RULES",
    "Rig",
    "Scenario",
    "ScenarioOutcome",
    "Violation",
    "make_scenario",
    "run_scenario",
]
