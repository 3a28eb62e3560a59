"""``rover sim``: the wire simulator (docs/sim.md): one scenario from its seed, a range
of seeds, or a soak for as long as asked."""

from __future__ import annotations

import argparse
import logging
import sys
from typing import Any

__all__ = ["add_arguments", "main", "register", "run"]

_DESCRIPTION = (
    "The wire simulator (docs/sim.md): the bridge's protocol core, a controller (the Python "
    "model or the C firmware core) over its twin, and a serial line or a CAN bus between "
    "them, in virtual time, with seeded faults (line cuts, corruption, drops, delays, lost "
    "frames of one kind, duplicated CAN frames, controller reboots, the host or the "
    "controller frozen, stopping faults, the device unplugged) and the operator's steps, "
    "STOPs and clears. After every scenario the invariants are checked (no step runs twice, "
    "every step ends once, no false 'completed', STOP zeroes the wheel targets, no automatic "
    "clear of a latch with a STOP or a fault in it, continuous odometry, a new step "
    "completes after the faults, counters that tell the truth). A failure prints the one "
    "command line that plays it again, exactly. Exit status: 0 when every scenario passed, "
    "1 when any failed, 2 on a usage error."
)


def _seeds(text: str) -> range:
    """``N`` or ``A..B`` (inclusive)."""
    try:
        if ".." in text:
            first, last = (int(p) for p in text.split("..", 1))
        else:
            first = last = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected N or A..B, got {text!r}") from None
    if first < 0 or last < first:
        raise argparse.ArgumentTypeError(f"expected 0 <= A <= B, got {text!r}")
    return range(first, last + 1)


def _budget(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected seconds, got {text!r}") from None
    if not value > 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {text!r}")
    return value


def _tick_ms(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected milliseconds, got {text!r}") from None
    if not 1.0 <= value <= 20.0 or value * 1000 != int(value * 1000):
        raise argparse.ArgumentTypeError(f"must be 1..20 ms in whole microseconds, got {text!r}")
    return value


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The options of ``rover sim``."""
    from sim.linkmutants import MUTANTS
    from sim.scenario import CONTROLLERS, MEDIA

    what = p.add_mutually_exclusive_group()
    what.add_argument("--seed", type=int, metavar="N", help="play scenario N and show it")
    what.add_argument(
        "--seeds", type=_seeds, metavar="A..B", help="play scenarios A to B (inclusive)"
    )
    what.add_argument(
        "--budget",
        type=_budget,
        metavar="SECONDS",
        help="play scenarios from --start on until SECONDS of wall time have passed",
    )
    p.add_argument(
        "--start", type=int, default=None, metavar="N", help="the first seed of --budget"
    )
    p.add_argument(
        "--controller",
        choices=(*CONTROLLERS, "both"),
        default=None,
        help="the controller (default: python for --seed, both otherwise)",
    )
    p.add_argument(
        "--medium",
        choices=(*MEDIA, "both"),
        default=None,
        help="the medium (default: serial for --seed, both otherwise)",
    )
    p.add_argument(
        "--mutant",
        action="append",
        default=[],
        choices=sorted(MUTANTS),
        help="undo one fix of the host's core, to see the simulator find its bug (repeatable)",
    )
    p.add_argument(
        "--controller-mutant",
        default=None,
        metavar="NAME",
        help="play the Python controller with one rule broken (rover emulate --mutant's names)",
    )
    p.add_argument(
        "--leak-samples",
        action="store_true",
        help="the controller also sends sensor samples before a session (a protocol v2 one)",
    )
    p.add_argument(
        "--zero-steps",
        action="store_true",
        help="the operator also sends steps with speed 0 or distance 0 (docs/sim.md)",
    )
    p.add_argument(
        "--tick-ms",
        type=_tick_ms,
        default=None,
        metavar="MS",
        help="the controller's control period in the simulator (default 10)",
    )
    p.add_argument(
        "--mission",
        action="store_true",
        help="play onboard missions instead (docs/sim.md, 'Missions'): the rover's "
        "sequencer and guard over the wire, a ground across a lossy 3 s link, slip, POSE "
        "silence, bad and replayed uplinks, ground STOPs, reboots",
    )
    p.add_argument(
        "--world",
        metavar="NAME",
        default=None,
        help="play a named mission of the whole stack in virtual time instead (the gate, the "
        "executor, the link relay, the bridge node, the controller and its twin in one "
        "process; docs/sim.md, 'Whole missions in virtual time'): one of "
        + ", ".join(_world_names()),
    )
    p.add_argument("--map", default="lab", help="with --world: the map (default lab)")
    p.add_argument(
        "--rtt", type=float, default=3.0, metavar="S", help="with --world: the round trip"
    )
    p.add_argument("--jitter", type=float, default=0.0, metavar="S", help="with --world")
    p.add_argument(
        "--loss", type=float, default=0.0, metavar="RATIO", help="with --world: relay loss"
    )
    p.add_argument(
        "--fault",
        action="append",
        default=[],
        metavar="FAULT",
        help="with --world: a controller fault from the start (repeatable; docs/emulator.md)",
    )
    p.add_argument(
        "--unrelayed",
        action="append",
        default=[],
        metavar="TOPIC",
        help="with --world: a topic the link does not carry (repeatable)",
    )
    p.add_argument(
        "--executor",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="with --world: an executor setting (repeatable; docs/ground.md)",
    )
    p.add_argument("--trace", action="store_true", help="with --seed: print every event")
    p.add_argument(
        "--stop-on-failure", action="store_true", help="stop at the first failing scenario"
    )


def _world_names() -> list[str]:
    """The whole-stack missions' names, as :mod:`sim.worldmissions` lists them (kept here
    so that the parser does not import the whole stack)."""
    return [
        "approved", "slip", "rejected", "dark", "dead", "replan", "replan-fails", "cancel",
        "demo",
    ]  # fmt: skip


def _setting(text: str) -> tuple[str, Any]:
    """``NAME=VALUE`` of ``--executor``: the value as a Python literal, else the text."""
    import ast

    name, _, value = text.partition("=")
    try:
        return name, ast.literal_eval(value)
    except (ValueError, SyntaxError):
        return name, value


def _run_world(args: argparse.Namespace, tick_s: float | None) -> int:
    """``--world``: each seed on each controller and medium asked for; the exit status."""
    from sim.world import CONTROLLERS, MEDIA, WorldConfig
    from sim.worldmissions import MISSIONS, play, start_gate

    if args.world not in MISSIONS:
        known = ", ".join(MISSIONS)
        print(f"rover sim: error: unknown --world {args.world!r}; known: {known}", file=sys.stderr)
        return 2
    seeds = args.seeds if args.seeds is not None else [args.seed or 0]
    controllers = CONTROLLERS if args.controller == "both" else (args.controller or "python",)
    media = MEDIA if args.medium == "both" else (args.medium or "serial",)
    failed = 0
    gate = start_gate()
    try:
        for seed in seeds:
            for controller in controllers:
                for medium in media:
                    config = WorldConfig(
                        map_name=args.map,
                        controller=controller,
                        medium=medium,
                        seed=seed,
                        rtt_s=args.rtt,
                        jitter_s=args.jitter,
                        loss=args.loss,
                    )
                    config = config.with_(
                        faults=tuple(args.fault),
                        unrelayed=tuple(args.unrelayed),
                        executor=tuple(_setting(text) for text in args.executor),
                    )
                    if tick_s is not None:
                        config = config.with_(tick_s=tick_s)
                    outcome = play(args.world, config, gate_url=gate.url)
                    print(outcome.report(), flush=True)
                    if args.trace or (args.seed is not None and not outcome.ok):
                        print("\n".join(f"  | {line}" for line in outcome.lines))
                    failed += not outcome.ok
    finally:
        gate.close()
    return 1 if failed else 0


def register(subparsers: Any) -> None:
    """Add ``rover sim``."""
    p = subparsers.add_parser(
        "sim",
        help="the wire simulator: seeded faults in virtual time, invariants, reproducers",
        description=_DESCRIPTION,
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=(
            "examples:\n"
            "  rover sim --seeds 0..999                  # 1000 scenarios, both controllers\n"
            "  rover sim --budget 600                    # soak for ten minutes\n"
            "  rover sim --seed 4711 --controller c --medium can --trace\n"
            "  rover sim --seeds 0..2999 --mutant auto-clear-survives --stop-on-failure\n"
            "  rover sim --world demo --seed 1 --controller c --medium can\n"
        ),
    )
    add_arguments(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run the simulator as the options say; the exit status (see the description)."""
    import itertools
    import random

    from sim.rig import run_scenario
    from sim.scenario import CONTROLLERS, DEFAULT_TICK_S, MEDIA, make_scenario
    from sim.soak import soak

    if args.world is not None:
        if args.verbose <= 0:
            for name in ("bridge", "emulator", "planner", "gate"):
                logging.getLogger(name).setLevel(logging.ERROR)
        return _run_world(args, args.tick_ms / 1000.0 if args.tick_ms is not None else None)
    tick_s = args.tick_ms / 1000.0 if args.tick_ms is not None else DEFAULT_TICK_S
    options: dict[str, Any] = {
        "mutants": tuple(args.mutant),
        "controller_mutant": args.controller_mutant or "",
        "leak_samples": args.leak_samples,
        "zero_steps": args.zero_steps,
        "tick_s": tick_s,
    }
    if args.verbose <= 0:
        # Every fault makes the link and the controller log a warning; the summary says
        # what matters (-v brings them back).
        for name in ("bridge", "emulator"):
            logging.getLogger(name).setLevel(logging.ERROR)
    if args.mission:
        return _missions(args)
    if args.seed is not None:
        if "both" in (args.controller, args.medium):
            print("rover sim: error: --seed plays one controller on one medium", file=sys.stderr)
            return 2
        scenario = make_scenario(
            args.seed,
            controller=args.controller or "python",
            medium=args.medium or "serial",
            **options,
        )
        outcome = run_scenario(scenario, trace=args.trace)
        print("\n".join(scenario.describe()))
        if args.trace:
            print("\n".join(outcome.trace))
        verdict = "passed" if outcome.ok else "FAILED"
        print(
            f"{verdict}: {outcome.sim_s:.3f} s simulated, digest {outcome.digest}, "
            + ", ".join(f"{k} {v}" for k, v in sorted(outcome.counts.items()))
        )
        for v in outcome.violations:
            print(f"  {v.line()}")
        if not outcome.ok:
            print(f"reproduce: {scenario.reproducer}")
        return 0 if outcome.ok else 1
    controllers = CONTROLLERS if args.controller in (None, "both") else (args.controller,)
    media = MEDIA if args.medium in (None, "both") else (args.medium,)
    budget = args.budget
    if args.seeds is not None:
        seeds: Any = args.seeds
        print(f"rover sim: seeds {seeds.start}..{seeds.stop - 1}", flush=True)
    else:
        start = args.start if args.start is not None else random.SystemRandom().randrange(10**9)
        seeds = itertools.count(start)
        if budget is None:
            budget = 60.0
        print(f"rover sim: seeds from {start}, for {budget:g} s", flush=True)

    def said(outcome: Any) -> None:
        if not outcome.ok:
            print(f"FAIL {outcome.scenario.reproducer}", flush=True)

    report = soak(
        seeds,
        controllers=controllers,
        media=media,
        budget_s=budget,
        stop_on_failure=args.stop_on_failure,
        on_outcome=said,
        **options,
    )
    print("\n".join(report.lines()))
    return 1 if report.failures else 0


def _missions(args: argparse.Namespace) -> int:
    """``rover sim --mission``: one mission from its seed, or a range (a soak)."""
    import itertools
    import time

    from sim.mission import make_mission, run_mission
    from sim.scenario import CONTROLLERS, MEDIA
    from sim.soak import assignment

    if args.seed is not None:
        mission = make_mission(
            args.seed, controller=args.controller or "python", medium=args.medium or "serial"
        )
        outcome = run_mission(mission, trace=args.trace)
        print("\n".join(mission.describe()))
        if args.trace:
            print("\n".join(outcome.trace))
        verdict = "passed" if outcome.ok else "FAILED"
        truth = ", ".join(f"{k} {v:.3f}" for k, v in sorted(outcome.truth.items()))
        heard = "heard" if outcome.ground_heard else "did not hear"
        print(
            f"{verdict}: {outcome.sim_s:.3f} s simulated; the plan ended "
            f"{outcome.ended or 'never'}, the ground {heard} it; {truth}"
        )
        for v in outcome.violations:
            print(f"  {v.line()}")
        if not outcome.ok:
            print(f"reproduce: {mission.reproducer}")
        return 0 if outcome.ok else 1
    controllers = CONTROLLERS if args.controller in (None, "both") else (args.controller,)
    media = MEDIA if args.medium in (None, "both") else (args.medium,)
    seeds: Any = args.seeds if args.seeds is not None else itertools.count(args.start or 0)
    budget = args.budget if args.budget is not None else (None if args.seeds else 60.0)
    start = time.perf_counter()
    played = failed = 0
    sim_s = 0.0
    for seed in seeds:
        if budget is not None and time.perf_counter() - start >= budget:
            break
        controller, medium = assignment(seed, controllers, media)
        mission = make_mission(seed, controller=controller, medium=medium)
        outcome = run_mission(mission)
        played += 1
        sim_s += outcome.sim_s
        if not outcome.ok:
            failed += 1
            print(f"FAIL {mission.reproducer}: {outcome.violations[0].line()}", flush=True)
            if args.stop_on_failure:
                break
    wall = time.perf_counter() - start
    print(
        f"{played} missions, {failed} failed; {sim_s:.0f} s simulated in {wall:.1f} s "
        f"({sim_s / wall if wall else 0:.0f}x real time)"
    )
    return 1 if failed else 0


def main(argv: list[str] | None = None) -> int:
    """``python -m sim.cli_sim``: the same as ``rover sim``."""
    parser = argparse.ArgumentParser(prog="rover sim", description=_DESCRIPTION)
    parser.add_argument("-v", "--verbose", action="count", default=0)
    add_arguments(parser)
    return run(parser.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
