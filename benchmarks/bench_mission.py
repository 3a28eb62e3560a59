"""The thesis's experiment (chapter 6) in our stack: planning, missions, drift STOP.

Run: ``.venv/bin/python -m benchmarks.bench_mission [--goals N] [--speed X] [--quick]``.

Everything real: a ``rover gate`` subprocess over HTTP on 127.0.0.1 validates; each
mission drives the emulator (controller model and twin) on a real pty through the bridge
node, the link relay (3 s round trip by default) and the executor (:mod:`tests.rig`).
The rover runs ``--speed`` times faster than real time (every timer scales); mission
times are in mission seconds (wall x speed), planning counts at its real speed.

Three tables:

1. *Planning* (thesis 6.2): ``--goals`` goals per scenario map from its start
   (:func:`planner.plan.experiment.trial_goals`; ``--colliding``: only goals whose
   straight route's bare footprint hits something, the thesis's "designed to
   collide"). The share of straight plans that collide (gate / bare geometry), of
   geometric collisions the gate intercepted, approved, and mean repair cycles, beside
   the thesis's figures.
2. *Missions* (thesis 6.2, last paragraph): each approved goal driven twice from the
   start on a fresh rig: gated (:class:`~planner.ground.mission.MissionRunner`: plan,
   validate, repair, then the event-driven executor with drift control) and
   move-and-wait (:class:`~planner.ground.mission.MoveAndWait`: drives cut to 0.5 m,
   each confirmed through the round trip, then 2 s to decide; no gate, no drift
   control). The share completed, the mean mission time of each and the reduction,
   beside the thesis's.
3. *Drift STOP* (thesis 6.3): ``--drift-trials`` missions on the lab map with slip on
   both wheels (traction 10 %): drift detected to STOP handed to the ROS port (ground),
   and STOP frame in to wheel targets zero (rover); p50/p99 beside the thesis's and the
   pty round trip of the same run.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass

from benchmarks.common import gate_process, pty_round_trip, summary, table
from firmware_proto.model.plan import Plan
from firmware_proto.model.pose import Pose
from firmware_proto.model.rover import load_rover
from planner.ground.mission import MissionReport, MissionRunner, MoveAndWait
from planner.plan.experiment import (
    ExperimentResult,
    footprint_hits,
    run_planning_experiment,
    trial_goals,
)
from planner.plan.gate_client import GateClient
from planner.plan.orchestrator import PlannerOrchestrator
from planner.plan.planner import HeuristicLowLevelPlanner
from tests.rig import HilRig

THESIS_COLLISIONS = {"scn01": 0.40, "scn02": 0.70, "scn03": 0.90}
THESIS_CYCLES = {"scn01": 1.2, "scn02": 2.4, "scn03": 3.8}
THESIS_REDUCTION = -0.425
"""Mission time against move-and-wait at high density (thesis 6.2)."""
THESIS_DRIFT_STOP_MS = 8.4


@dataclass(frozen=True)
class MissionPair:
    """One goal driven gated and move-and-wait; times in mission seconds."""

    map_name: str
    goal_name: str
    gated: MissionReport
    baseline: MissionReport | None
    speed: float

    @property
    def gated_s(self) -> float:
        """Planning (real time) plus driving (wall x speed)."""
        g = self.gated
        return g.planning_s + (g.elapsed_s - g.planning_s) * self.speed

    @property
    def baseline_s(self) -> float | None:
        """The move-and-wait operator's time, or ``None`` when it did not finish."""
        if self.baseline is None or not self.baseline.reached:
            return None
        return self.baseline.elapsed_s * self.speed


def colliding_goals(
    planner: HeuristicLowLevelPlanner, n: int, seed: int = 0
) -> list[tuple[str, Pose]]:
    """The first ``n`` goals of :func:`trial_goals` (suggested, then random) whose
    straight route from the map's start hits something on the map (bare footprint).

    Raises:
        ValueError: fewer than ``n`` such goals among the first 50 x ``n`` candidates.
    """
    world = planner.world
    assert world is not None
    out = []
    for name, goal in trial_goals(world, planner, 50 * n, seed=seed):
        route = planner.route(world.start, goal, world=world)
        if footprint_hits(planner, world, route):
            out.append((name, goal))
            if len(out) == n:
                return out
    raise ValueError(f"map {world.name!r}: fewer than {n} colliding goals found")


def planning(
    url: str, maps: Sequence[str], goals: int, colliding: bool = False
) -> dict[str, ExperimentResult]:
    """Table 1's experiment on each map."""
    rover = load_rover()
    out = {}
    with GateClient(url, timeout_s=120.0) as client:
        for name in maps:
            world = client.get_map(name)
            planner = HeuristicLowLevelPlanner(rover, world=world)
            orchestrator = PlannerOrchestrator(planner, client, map_name=name, world=world)
            chosen = colliding_goals(planner, goals) if colliding else None
            out[name] = run_planning_experiment(orchestrator, goals, goals=chosen, seed=0)
    return out


def missions(
    url: str, results: dict[str, ExperimentResult], speed: float, rtt_s: float, seed: int
) -> list[MissionPair]:
    """Table 2: every approved goal of table 1, gated then move-and-wait."""
    rover = load_rover()
    pairs = []
    with GateClient(url, timeout_s=120.0) as client:
        for name, result in results.items():
            world = client.get_map(name)
            orchestrator = PlannerOrchestrator(
                HeuristicLowLevelPlanner(rover, world=world), client, map_name=name, world=world
            )
            for i, trial in enumerate(t for t in result.trials if t.approved):
                with HilRig(name, speed=speed, rtt_s=rtt_s, seed=seed + i) as rig:
                    gated = MissionRunner(orchestrator, rig.executor, replans=1).run(
                        trial.goal, start=world.start
                    )
                baseline = None
                plans: tuple[Plan, ...] = tuple(run.plan for run in gated.runs)
                if gated.reached and not gated.drift_events:
                    with HilRig(
                        name, speed=speed, rtt_s=rtt_s, seed=seed + i, drift_control=False
                    ) as rig:
                        operator = MoveAndWait(rig.executor, time_scale=speed)
                        baseline = operator.drive(trial.goal, world.start, plans)
                pair = MissionPair(name, trial.name, gated, baseline, speed)
                pairs.append(pair)
                print(
                    f"  {name} {trial.name}: gated {'reached' if gated.reached else 'NOT reached'}"
                    f" in {pair.gated_s:.1f} s ({gated.steps_executed} steps), move-and-wait "
                    + (
                        f"{pair.baseline_s:.1f} s ({baseline.steps_executed} steps)"
                        if baseline is not None and pair.baseline_s is not None
                        else "not run"
                        if baseline is None
                        else f"NOT reached ({baseline.reason})"
                    ),
                    file=sys.stderr,
                    flush=True,
                )
    return pairs


def drift_trials(url: str, n: int, speed: float, rtt_s: float) -> tuple[list[float], list[float]]:
    """Table 3: detection->STOP on the ground and STOP->zero on the rover, seconds."""
    rover = load_rover()
    detect_to_stop: list[float] = []
    stop_to_zero: list[float] = []
    with GateClient(url, timeout_s=60.0) as client:
        world = client.get_map("lab")
        s = world.start
        raw = {
            "goal": {"x": s.x + 1.5, "y": s.y, "yaw_deg": s.yaw_deg},
            "commands": [
                {"command": "FWD", "speed": 60, "distance": rover.m_to_units(1.0)},
                {"command": "FWD", "speed": 60, "distance": rover.m_to_units(0.5)},
            ],
        }
        verdict = client.validate(raw, map_name="lab")
        if not verdict.approved:
            raise RuntimeError(f"the drift plan was not approved: {verdict.summary()}")
        plan = Plan.from_dict(raw)
        for i in range(n):
            with HilRig(
                "lab", speed=speed, rtt_s=rtt_s, seed=100 + i, faults=("slip:both=0.1",)
            ) as rig:
                result = rig.executor.execute(plan, verdict)
                if result.outcome != "drift" or result.stop_latency_s is None:
                    print(f"  trial {i}: no drift STOP ({result.outcome})", file=sys.stderr)
                    continue
                detect_to_stop.append(result.stop_latency_s)
                deadline = time.monotonic() + 10.0
                while not rig.emulator.stop_reactions and time.monotonic() < deadline:
                    time.sleep(0.005)
                stop_to_zero.extend(rig.emulator.stop_reactions[:1])
    return detect_to_stop, stop_to_zero


def _pct(v: float | None) -> str:
    return "n/a" if v is None else f"{100 * v:.0f} %"


def _num(v: float | None, fmt: str = ".2f") -> str:
    return "n/a" if v is None else format(v, fmt)


def planning_table(results: dict[str, ExperimentResult]) -> str:
    lines = [
        "Planning (thesis 6.2), from each map's start",
        "",
        "| map | goals | straight plan collides (gate / geometry) | intercepted | approved "
        "| mean repair cycles (colliding) | thesis: collides, cycles |",
        "|---|---:|---|---:|---:|---:|---|",
    ]
    for name, r in results.items():
        thesis = (
            f"{_pct(THESIS_COLLISIONS.get(name))}, {_num(THESIS_CYCLES.get(name), '.1f')}"
            if name in THESIS_CYCLES
            else ""
        )
        lines.append(
            f"| {name} | {len(r.trials)} | {_pct(r.collision_share)} / {_pct(r.geometric_share)} "
            f"| {_pct(r.interception_share)} | {_pct(r.approved_share)} "
            f"| {_num(r.mean_repair_cycles)} | {thesis} |"
        )
    return "\n".join(lines)


def mission_table(pairs: list[MissionPair], planned: dict[str, int], rtt_s: float) -> str:
    lines = [
        f"Missions at {rtt_s:g} s round trip: gated against move-and-wait (mission seconds)",
        "",
        "| map | goals | completed gated (of all goals) | gated mean s | move-and-wait mean s "
        "| reduction | thesis |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for name, goals in planned.items():
        mine = [p for p in pairs if p.map_name == name]
        done = sum(p.gated.reached for p in mine)
        both = [p for p in mine if p.gated.reached and p.baseline_s is not None]
        gated = statistics.fmean(p.gated_s for p in both) if both else None
        mnw = statistics.fmean(p.baseline_s for p in both if p.baseline_s) if both else None
        reduction = (gated / mnw - 1.0) if gated is not None and mnw else None
        thesis = f"{100 * THESIS_REDUCTION:.1f} %" if name == "scn03" else ""
        lines.append(
            f"| {name} | {goals} | {done} ({_pct(done / goals if goals else None)}) "
            f"| {_num(gated, '.1f')} | {_num(mnw, '.1f')} "
            f"| {'n/a' if reduction is None else f'{100 * reduction:+.1f} %'} | {thesis} |"
        )
    lines += [
        "",
        "Means over the goals both modes completed. Gated: planning + validation + repairs "
        "(real time), then each step published and confirmed through the link, drift control "
        "on. Move-and-wait: the same route, drives cut to 0.5 m, every command confirmed "
        "through the round trip and then 2 s for the operator.",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--maps", default="scn01,scn02,scn03", help="scenario maps (comma list)")
    parser.add_argument("--goals", type=int, default=10, help="goals per map (default 10)")
    parser.add_argument(
        "--speed", type=float, default=10.0, help="mission seconds per wall second (default 10)"
    )
    parser.add_argument("--rtt", type=float, default=3.0, help="link round trip, s (default 3)")
    parser.add_argument("--drift-trials", type=int, default=20, help="slip trials (default 20)")
    parser.add_argument(
        "--colliding",
        action="store_true",
        help="only goals whose straight route hits something on the map",
    )
    parser.add_argument("--no-missions", action="store_true", help="skip table 2")
    parser.add_argument("--seed", type=int, default=1, help="seeds the rigs (default 1)")
    parser.add_argument(
        "--quick", action="store_true", help="3 goals per map, 5 drift trials: a smoke run"
    )
    args = parser.parse_args(argv)
    if args.quick:
        args.goals, args.drift_trials = 3, 5
    if args.goals < 1 or args.drift_trials < 0 or args.speed <= 0 or args.rtt < 0:
        parser.error("--goals >= 1, --drift-trials >= 0, --speed > 0 and --rtt >= 0")
    maps = [m for m in args.maps.split(",") if m]
    t0 = time.monotonic()
    with gate_process({}, pool="thread", workers=2) as gate:
        url = f"http://{gate.address[0]}:{gate.address[1]}"
        print(f"planning: {args.goals} goals on {', '.join(maps)}", file=sys.stderr)
        results = planning(url, maps, args.goals, args.colliding)
        print(planning_table(results), end="\n\n", flush=True)
        if not args.no_missions:
            print(f"missions at speed {args.speed:g}", file=sys.stderr)
            pairs = missions(url, results, args.speed, args.rtt, args.seed)
            planned = {name: len(r.trials) for name, r in results.items()}
            print(mission_table(pairs, planned, args.rtt), end="\n\n", flush=True)
        if args.drift_trials:
            print(f"drift: {args.drift_trials} slip trials", file=sys.stderr)
            ground, rover = drift_trials(url, args.drift_trials, args.speed, args.rtt)
            rtt = pty_round_trip(2000)
            rows = [
                ("drift detection -> STOP handed to the ROS port (ground)", summary(ground)),
                ("STOP frame at the controller -> wheel targets zero (rover)", summary(rover)),
                ("pty round trip, 15 bytes (same run)", summary(rtt)),
            ]
            note = (
                f"Thesis: {THESIS_DRIFT_STOP_MS} ms detection to STOP. Between the two rows the "
                f"STOP crosses the link (half the {args.rtt:g} s round trip) and the bridge; "
                "bench_bridge measures the bridge's part."
            )
            print(table("Drift STOP latency", rows, note), flush=True)
    print(f"\n(wall time {time.monotonic() - t0:.0f} s)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
