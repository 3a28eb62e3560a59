"""Plans run on board beside the step-by-step executor and move-and-wait, in virtual time.

Run: ``.venv/bin/python -m benchmarks.bench_onboard [--trials N] [--goals N]``.

All three in one run on the wire simulator's mission rig (``sim/mission.py``: the
bridge's ``LinkCore``, the Python controller model over its twin and a serial line, a 3 s
round trip with jitter and loss on every message); only the ground differs: the plan
uplinked once to the rover's sequencer and guard (``bridge/onboard``), the step-by-step
executor, or move-and-wait (``benchmarks/onboard_sim.py``). Plans: the planner's routes
on the lab map and scn01-03, predicted as the gate plays them, each leg on an open plane
(docs/performance.md).

1. **Overshoot** (slip on the left side, traction 3 %, from 30 % into the first drive of
   at least 0.5 m), from the rover's stamped ``odom_ground``: distance and time from
   drift confirmed to rest; the same from the first pose 0.25 m off the approved path;
   the distance off the path at rest. Medians over ``--trials`` seeds.
2. **Mission time** at a 3 s round trip, per scene, ``--goals`` goals: the sum over its
   legs of first send to the ground knowing the leg completed.
3. **Loss** 0, 0.1, 0.3 each way, jitter 0.2 s, 10 missions per mode: reached, plans or
   steps run more than once, and ground-STOP delivery p50/p99 (first STOP sent to the
   rover's bridge taking it).
"""

from __future__ import annotations

import argparse
import logging
import math
import random
import statistics
import time

from benchmarks.onboard_sim import GroundRig, RunFigures, run_onboard
from firmware_proto.model.rover import load_rover
from firmware_proto.model.worldmap import load_map
from firmware_proto.wire.messages import Command
from planner.ground.overshoot import overshoot
from planner.plan.experiment import trial_goals
from planner.plan.planner import HeuristicLowLevelPlanner
from sim.mission import MissionScenario, predict

ROVER = load_rover(None)
MODES = ("step-by-step", "onboard")
SCENES = ("lab", "scn01", "scn02", "scn03")


def _mission(
    seed: int,
    steps: tuple[tuple[int, int, int], ...],
    *,
    loss: float = 0.0,
    jitter: float = 0.0,
    slip: tuple[int, float, str, float] | None = None,
    ground_stop: float | None = None,
) -> MissionScenario:
    return MissionScenario(
        seed=seed,
        controller="python",
        medium="serial",
        tick_s=0.01,
        steps=steps,
        one_way_s=1.5,
        jitter_s=jitter,
        loss=loss,
        token=True,
        slip=slip,
        pose_silent=None,
        ground_stop_s=ground_stop,
        uplink_faults=(),
        wire_faults=(),
    )


def _run(mode: str, mission: MissionScenario) -> RunFigures:
    if mode == "onboard":
        return run_onboard(mission)
    return GroundRig(mission, mode).run_ground()


def _legs(scene: str, n_goals: int) -> list[list[tuple[tuple[int, int, int], ...]]]:
    """Each goal's legs, each as its steps."""
    world = load_map(scene)
    planner = HeuristicLowLevelPlanner(ROVER, world=world)
    out = []
    for _, goal in trial_goals(world, planner, n_goals, seed=0):
        legs = planner.plan_mission(world.start, goal)
        out.append([tuple(leg.plan.to_wire()) for leg in legs])
    return out


def _slip_step(steps: tuple[tuple[int, int, int], ...]) -> int | None:
    for i, (c, _, d) in enumerate(steps):
        if c in (Command.FWD, Command.REV) and d >= ROVER.m_to_units(0.5):
            return i
    return None


def overshoot_table(trials: int, scenes: tuple[str, ...] = SCENES) -> list[str]:
    lines = [
        "| scene | mode | drift stops | after detection: driven m / at rest s | "
        "after 0.25 m off the path: driven m / at rest s | off the path at rest m | "
        "twin: after detection m / s |",
        "|---|---|---:|---|---|---:|---|",
    ]
    for scene in scenes:
        legs = _legs(scene, 1)[0]
        steps = next(leg for leg in legs if _slip_step(leg) is not None)
        k = _slip_step(steps)
        assert k is not None
        path = [(s.x, s.y) for s in predict(ROVER, 1, steps).prediction]
        for mode in MODES:
            det, crossed, rest_off, true, stops = [], [], [], [], 0
            for seed in range(trials):
                fig = _run(mode, _mission(seed, steps, slip=(k, 0.3, "left", 0.03)))
                if fig.detected_s is None:
                    continue
                stops += 1
                a = overshoot(path, fig.fixes, crossing_s=fig.detected_s)
                b = overshoot(path, fig.fixes)
                if a is not None:
                    det.append((a.past_limit_m, a.time_to_rest_s))
                    rest_off.append(a.rest_off_path_m)
                if b is not None and b.crossed:
                    crossed.append((b.past_limit_m, b.time_to_rest_s))
                c = overshoot(path, fig.truth, crossing_s=fig.detected_s, rest_move_m=0.002)
                if c is not None:
                    true.append((c.past_limit_m, c.time_to_rest_s))

            def med(xs: list[tuple[float, float]]) -> str:
                if not xs:
                    return "never"
                return (
                    f"{statistics.median(x[0] for x in xs):.3f} / "
                    f"{statistics.median(x[1] for x in xs):.2f}"
                )

            off = f"{statistics.median(rest_off):.3f}" if rest_off else "n/a"
            crossed_txt = med(crossed) + (f" ({len(crossed)} of {stops})" if stops else "")
            lines.append(
                f"| {scene} | {mode} | {stops}/{trials} | {med(det)} | {crossed_txt} | {off} "
                f"| {med(true)} |"
            )
    return lines


def mission_time_table(goals: int, scenes: tuple[str, ...] = SCENES[1:]) -> list[str]:
    lines = [
        "| scene | goals | move-and-wait s | step-by-step s | on board s | step-by-step vs m&w | on board vs m&w |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for scene in scenes:
        times: dict[str, list[float]] = {m: [] for m in ("move-and-wait", *MODES)}
        for g, legs in enumerate(_legs(scene, goals)):
            for mode, spent in times.items():
                total = 0.0
                for i, steps in enumerate(legs):
                    fig = _run(mode, _mission(1000 * g + i, steps))
                    total += fig.mission_s if fig.reached else math.nan
                spent.append(total)
        mean = {m: statistics.fmean(t) for m, t in times.items()}
        mw = mean["move-and-wait"]
        lines.append(
            f"| {scene} | {goals} | {mw:.1f} | {mean['step-by-step']:.1f} | {mean['onboard']:.1f} "
            f"| {100 * (mean['step-by-step'] / mw - 1):+.1f} % | {100 * (mean['onboard'] / mw - 1):+.1f} % |"
        )
    return lines


def loss_table(losses: tuple[float, ...] = (0.0, 0.1, 0.3), missions: int = 10) -> list[str]:
    steps = _legs("lab", 1)[0][0]
    duration = sum(ROVER.step_duration_s(s, d) for _, s, d in steps)
    lines = [
        "| loss each way | mode | reached | plans/steps run twice | ground STOP delivery p50 / p99 s |",
        "|---:|---|---:|---:|---|",
    ]
    for loss in losses:
        for mode in MODES:
            reached = twice = 0
            for seed in range(missions):
                fig = _run(mode, _mission(seed, steps, loss=loss, jitter=0.2))
                reached += fig.reached
                twice += fig.steps_twice + fig.plans_twice
            delays = []
            rng = random.Random(f"stop:{loss}")
            for seed in range(missions):
                at = 0.5 + rng.uniform(2.0, 2.0 + duration)
                fig = _run(mode, _mission(100 + seed, steps, loss=loss, jitter=0.2, ground_stop=at))
                if fig.stop_sent_s is not None and fig.stop_reached_s is not None:
                    delays.append(fig.stop_reached_s - fig.stop_sent_s)
            delays.sort()
            p50 = statistics.median(delays) if delays else math.nan
            p99 = (
                delays[min(len(delays) - 1, math.ceil(0.99 * len(delays)) - 1)]
                if delays
                else math.nan
            )
            lines.append(
                f"| {loss:g} | {mode} | {reached}/{missions} | {twice} | {p50:.2f} / {p99:.2f} ({len(delays)} STOPs) |"
            )
    return lines


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--trials", type=int, default=5, help="seeds per overshoot case (default 5)")
    p.add_argument("--goals", type=int, default=3, help="goals per scene for mission time")
    p.add_argument("--skip", action="append", default=[], choices=("overshoot", "time", "loss"))
    p.add_argument(
        "--quick",
        action="store_true",
        help="a smoke run: the lab's overshoot once, one scn01 goal, loss 0.3 once per mode",
    )
    args = p.parse_args()
    scenes: tuple[str, ...] = SCENES
    time_scenes: tuple[str, ...] = SCENES[1:]
    losses: tuple[float, ...] = (0.0, 0.1, 0.3)
    missions = 10
    if args.quick:
        args.trials, args.goals = 1, 1
        scenes, time_scenes, losses, missions = ("lab",), ("scn01",), (0.3,), 1
    for name in ("bridge", "emulator", "sim"):
        logging.getLogger(name).setLevel(logging.ERROR)
    t0 = time.perf_counter()
    print("## Overshoot: slip (left traction 3 %) from 30 % into the first drive of >= 0.5 m")
    if "overshoot" not in args.skip:
        print("\n".join(overshoot_table(args.trials, scenes)), flush=True)
    print(f"\n## Mission time at a 3 s round trip ({time.perf_counter() - t0:.0f} s so far)")
    if "time" not in args.skip:
        print("\n".join(mission_time_table(args.goals, time_scenes)), flush=True)
    print(f"\n## Loss, jitter 0.2 s each way ({time.perf_counter() - t0:.0f} s so far)")
    if "loss" not in args.skip:
        print("\n".join(loss_table(losses, missions)), flush=True)
    print(f"\n(wall {time.perf_counter() - t0:.0f} s; virtual time, Python controller, serial)")


if __name__ == "__main__":
    main()
