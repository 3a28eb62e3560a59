"""A wire simulator scenario: everything that will happen to the link, drawn from one seed.

:func:`make_scenario` turns a seed into a :class:`Scenario`: the faults (when each
starts, how long it lasts, how strong it is) and what the operator does (steps, STOP,
CLEAR) during an active phase of up to about two seconds. After the last fault ends the
simulator checks that the link recovers (docs/sim.md). The same seed and options always
give the same scenario, and :attr:`Scenario.reproducer` is the one command line that
plays it again.

The fault kinds are :data:`FAULT_KINDS` (docs/sim.md, "Faults", says what each does).
Three scenarios in ten add interleavings of a clear with a fault; one in five adds a
reboot crossing a HELLO or a bridge restarted on one controller boot. Each comes from a
generator of its own, so every other draw, and so every kept seed, plays as before.

Pure: no I/O, no clock; one ``random.Random(seed)``.
"""

from __future__ import annotations

import random
from dataclasses import dataclass

from firmware_proto.linkio.media import MEDIA
from firmware_proto.wire.messages import Command

__all__ = [
    "CONTROLLERS",
    "FAULT_KINDS",
    "MEDIA",
    "Action",
    "Scenario",
    "ScenarioFault",
    "make_scenario",
]

CONTROLLERS = ("python", "c")
"""The controllers a scenario can run against: the Python model, the C firmware core."""

FAULT_KINDS: dict[str, float] = {
    "cut": 3.0,
    "drop": 1.5,
    "corrupt": 1.0,
    "delay": 1.0,
    "kind-loss": 2.0,
    "dup": 1.0,
    "reboot": 1.5,
    "host-freeze": 1.5,
    "controller-freeze": 0.7,
    "encoder": 1.0,
    "stall": 0.5,
    "unplug": 0.7,
    "writer-stall": 0.0,
    "hello-reboot": 0.0,
    "host-restart": 0.0,
}
"""ScenarioFault kinds and their relative weights in a draw."""

_LOST_KINDS = (
    ("ACK", 4.0),
    ("STATUS", 2.0),
    ("PROGRESS", 1.0),
    ("IDENT", 1.5),
    ("STOP_ACK", 1.0),
    ("CLEAR_ACK", 1.5),
    ("HEARTBEAT", 1.0),
    ("FAULT", 1.0),
    ("MOTION", 1.0),
    ("CLEAR_STOP", 0.5),
    ("HELLO", 0.5),
)
"""Message kinds a ``kind-loss`` fault loses, and their weights."""

_HOST_BOUND = {"ACK", "STATUS", "PROGRESS", "IDENT", "STOP_ACK", "CLEAR_ACK", "HEARTBEAT", "FAULT"}


@dataclass(frozen=True)
class ScenarioFault:
    """One fault of a scenario.

    Attributes:
        kind: one of :data:`FAULT_KINDS`.
        start_s: when it starts (virtual time, s).
        duration_s: how long it lasts (0 for an instant one: ``reboot``).
        direction: ``both``, ``to_host`` or ``to_controller`` (faults of the medium).
        level: a probability, or the extra delay in seconds for ``delay``.
        kinds: the message names a ``kind-loss`` fault loses.
        side: ``left`` or ``right`` (``encoder``, ``stall``).
    """

    kind: str
    start_s: float
    duration_s: float
    direction: str = "both"
    level: float = 1.0
    kinds: tuple[str, ...] = ()
    side: str = "left"

    @property
    def end_s(self) -> float:
        """When it ends, s."""
        return self.start_s + self.duration_s

    def text(self) -> str:
        """One short line: ``cut to_host 0.412+0.350s``."""
        extra = ""
        if self.kind in ("drop", "corrupt", "dup", "kind-loss"):
            extra = f" p={self.level:.2f}"
        elif self.kind == "delay":
            extra = f" +{self.level * 1000:.0f}ms"
        if self.kinds:
            extra += " " + ",".join(self.kinds)
        if self.kind in ("encoder", "stall"):
            extra += f" {self.side}"
        return f"{self.kind} {self.direction} {self.start_s:.3f}+{self.duration_s:.3f}s{extra}"


@dataclass(frozen=True)
class Action:
    """What the operator does at ``at_s``: ``steps`` (submit these), ``stop``
    (emergency stop), ``stop-step`` (a MOTION with command STOP), ``clear``."""

    at_s: float
    kind: str
    steps: tuple[tuple[int, int, int], ...] = ()

    def text(self) -> str:
        """One short line."""
        more = f" x{len(self.steps)}" if self.steps else ""
        return f"{self.kind} at {self.at_s:.3f}s{more}"


@dataclass(frozen=True)
class Scenario:
    """Everything a run of the simulator needs; see the module docstring.

    Attributes:
        seed: the seed it was drawn from.
        controller: one of :data:`CONTROLLERS`.
        medium: one of :data:`MEDIA`.
        mutants: fixes of the host core undone (:data:`sim.linkmutants.MUTANTS`).
        controller_mutant: a rule of the controller broken (:data:`emulator.mutants.MUTANTS`;
            the Python model only), ``""`` for none.
        leak_samples: the controller also sends sensor samples before a session
            (protocol v2 allowed it; a v3 controller sends none).
        zero_steps: the operator also sends steps with speed 0 or distance 0 (off by
            default, so that every kept seed plays as it was found; docs/sim.md "Bugs
            found", 5).
        tick_s: the controller's control period (the twin's step), s.
        queue_depth: the controller's MOTION queue (the host assumes 8: fewer makes it
            answer QUEUE_FULL).
        faults: the faults, by start time.
        actions: the operator's actions, by time.
        quiet_s: when the last fault and the active phase have ended.
    """

    seed: int
    controller: str
    medium: str
    mutants: tuple[str, ...]
    leak_samples: bool
    zero_steps: bool
    tick_s: float
    queue_depth: int
    faults: tuple[ScenarioFault, ...]
    actions: tuple[Action, ...]
    quiet_s: float
    controller_mutant: str = ""

    @property
    def reproducer(self) -> str:
        """The one command line that plays this scenario again, exactly."""
        parts = [
            f"rover sim --seed {self.seed} --controller {self.controller}",
            f"--medium {self.medium}",
        ]
        if self.tick_s != DEFAULT_TICK_S:
            parts.append(f"--tick-ms {self.tick_s * 1000:g}")
        parts += [f"--mutant {m}" for m in self.mutants]
        if self.controller_mutant:
            parts.append(f"--controller-mutant {self.controller_mutant}")
        if self.leak_samples:
            parts.append("--leak-samples")
        if self.zero_steps:
            parts.append("--zero-steps")
        return " ".join(parts)

    def describe(self) -> list[str]:
        """The scenario in lines, for a report."""
        lines = [
            f"seed {self.seed}: {self.controller} controller on {self.medium}, "
            f"queue {self.queue_depth}, quiet from {self.quiet_s:.3f} s"
        ]
        lines += ["  fault " + f.text() for f in self.faults]
        lines += ["  operator " + a.text() for a in self.actions]
        return lines


DEFAULT_TICK_S = 0.01
"""The controller's control period in the simulator, s: coarser than the firmware's 1 ms so that an
hour of rover costs seconds; timeouts and rates are whole ticks (docs/sim.md, Fidelity)."""


def _duration(rng: random.Random) -> float:
    """A fault's length: mostly short, some longer than the link-lost time, a few long."""
    u = rng.random()
    if u < 0.5:
        return rng.uniform(0.002, 0.1)
    if u < 0.88:
        return rng.uniform(0.1, 0.6)
    return rng.uniform(0.6, 2.5)


def _steps(rng: random.Random, n: int, zero_steps: bool) -> tuple[tuple[int, int, int], ...]:
    out = []
    for _ in range(n):
        command = rng.choice((Command.FWD, Command.FWD, Command.REV, Command.LEFT, Command.RIGHT))
        speed = rng.choice((0, 15, 25, 40, 60)) if rng.random() < 0.1 else rng.randint(15, 60)
        distance = 0 if rng.random() < 0.05 else rng.randint(20, 700)
        if not zero_steps:  # the same draws either way: a seed keeps its other events
            speed, distance = speed or 10, distance or 20
        out.append((int(command), speed, distance))
    return tuple(out)


_OUTAGES = ("cut", "host-freeze", "unplug")


def _fault(rng: random.Random, kind: str, start: float, duration: float) -> ScenarioFault:
    """A fault of ``kind`` with its direction and level drawn."""
    direction = "both"
    level = 1.0
    lost: tuple[str, ...] = ()
    if kind in ("cut", "drop", "corrupt", "delay", "dup"):
        direction = rng.choice(("both", "both", "to_host", "to_controller"))
    if kind in ("drop", "corrupt", "dup"):
        level = rng.choice((0.02, 0.1, 0.3, 0.6))
    elif kind == "delay":
        level = rng.choice((0.005, 0.03, 0.12, 0.4))
    elif kind == "kind-loss":
        names, w = zip(*_LOST_KINDS, strict=True)
        lost = (rng.choices(names, w)[0],)
        direction = "to_host" if lost[0] in _HOST_BOUND else "to_controller"
        level = rng.choice((0.5, 1.0, 1.0))
    elif kind == "unplug":
        duration = min(duration, 2.5)
    return ScenarioFault(
        kind, start, duration, direction, level, lost, rng.choice(("left", "right"))
    )


def _pattern(rng: random.Random, active: float) -> list[ScenarioFault]:
    """One of the interleavings that matter most, now and then: faults that meet during
    a recovery. ``recovery``: an outage long enough to trip the controller's watchdog,
    a stopping fault as it ends and answers lost or delayed meanwhile (the automatic
    clear meets the fault); ``reboot``: the controller resets during an outage long
    enough for the host to lose the link (the new boot's first frames meet a host that
    knows neither the boot nor the session). Otherwise none."""
    u = rng.random()
    if u >= 0.25:
        return []
    outage = _fault(rng, rng.choice(_OUTAGES), rng.uniform(0.05, active), 0.0)
    if outage.kind == "cut":
        outage = ScenarioFault(
            "cut", outage.start_s, 0.0, rng.choice(("both", "to_host", "to_controller"))
        )
    if u < 0.13:
        out = [ScenarioFault(outage.kind, outage.start_s, rng.uniform(0.26, 0.9), outage.direction)]
        end = out[0].end_s
        kind = "encoder" if rng.random() < 0.8 else "stall"
        out.append(_fault(rng, kind, end + rng.uniform(0.0, 0.15), _duration(rng)))
        if rng.random() < 0.7:
            loss = rng.choice(("CLEAR_ACK", "CLEAR_ACK", "HEARTBEAT", "drop", "delay"))
            start, length = end - 0.02, rng.uniform(0.05, 0.4)
            if loss == "drop":
                out.append(ScenarioFault("drop", start, length, "to_host", rng.choice((0.3, 0.6))))
            elif loss == "delay":
                out.append(
                    ScenarioFault("delay", start, length, "to_controller", rng.uniform(0.01, 0.12))
                )
            else:
                out.append(ScenarioFault("kind-loss", start, length, "to_host", 1.0, (loss,)))
        return out
    length = rng.uniform(0.36, 1.2)
    direction = "to_host" if outage.direction == "to_controller" else outage.direction
    return [
        ScenarioFault(outage.kind, outage.start_s, length, direction),
        ScenarioFault("reboot", outage.start_s + rng.uniform(0.05, length - 0.02), 0.0),
    ]


def _issue_40(
    rng: random.Random, active: float, faults: list[ScenarioFault], actions: list[Action]
) -> None:
    """Add, to three scenarios in ten, one or two clear interleavings (see the module
    docstring), drawn from ``rng`` alone."""
    if rng.random() >= 0.3:
        return
    for _ in range(rng.choice((1, 1, 2))):
        kind = rng.choice(("glitch", "glitch", "writer-stall", "stop-clear", "clear-step"))
        at = rng.uniform(0.05, active)
        clears = [a.at_s for a in actions if a.kind == "clear"]
        outages = [f.end_s for f in faults if f.kind in ("cut", "host-freeze")]
        if kind == "glitch":
            # At a clear: the operator's, or the host's own as an outage ends.
            marks = clears + outages
            start = (rng.choice(marks) if marks else at) + rng.uniform(-0.01, 0.04)
            side = rng.choice(("left", "right"))
            faults.append(
                ScenarioFault("encoder", max(0.01, start), rng.uniform(0.005, 0.04), side=side)
            )
        elif kind == "writer-stall":
            start = (rng.choice(clears) if clears else at) + rng.uniform(-0.02, 0.01)
            faults.append(ScenarioFault("writer-stall", max(0.01, start), rng.uniform(0.1, 0.6)))
        elif kind == "stop-clear":
            actions.append(Action(at, "stop"))
            actions.append(Action(at + rng.uniform(0.0, 0.02), "clear"))
        else:
            actions.append(Action(at, "clear"))
            step = (int(Command.FWD), rng.randint(10, 60), rng.randint(100, 2000))
            actions.append(Action(at + rng.uniform(0.0, 0.004), "steps", (step,)))


def _wire(
    rng: random.Random, active: float, faults: list[ScenarioFault], actions: list[Action]
) -> None:
    """Add, to one scenario in five, a reboot crossing a HELLO or a bridge restarted on
    one controller boot (see the module docstring), drawn from ``rng`` alone."""
    if rng.random() >= 0.2:
        return
    at = rng.uniform(0.05, active)
    if rng.random() < 0.5:
        # The link lost (the controller's heartbeats miss for 0.35 s), so the host says
        # HELLO again after the outage: the controller reboots right after answering it.
        kind = rng.choice(("cut", "cut", "host-freeze", "unplug"))
        direction = rng.choice(("both", "to_host")) if kind == "cut" else "both"
        outage = ScenarioFault(kind, at, rng.uniform(0.4, 1.0), direction)
        faults += [outage, ScenarioFault("hello-reboot", outage.end_s, 0.0)]
        return
    if rng.random() < 0.6:
        actions.append(Action(max(0.0, at - rng.uniform(0.005, 0.2)), "stop"))
    faults.append(ScenarioFault("host-restart", at, rng.uniform(0.05, 1.5)))


def make_scenario(
    seed: int,
    *,
    controller: str = "python",
    medium: str = "serial",
    mutants: tuple[str, ...] = (),
    controller_mutant: str = "",
    leak_samples: bool = False,
    zero_steps: bool = False,
    tick_s: float = DEFAULT_TICK_S,
) -> Scenario:
    """The scenario of ``seed`` with these options (see the module docstring).

    Raises:
        ValueError: an unknown controller or medium (the message lists the known ones).
    """
    if controller not in CONTROLLERS:
        raise ValueError(f"unknown controller {controller!r}; known: {', '.join(CONTROLLERS)}")
    if medium not in MEDIA:
        raise ValueError(f"unknown medium {medium!r}; known: {', '.join(MEDIA)}")
    rng = random.Random(seed)
    active = rng.uniform(0.15, 0.8)
    kinds = [k for k, w in FAULT_KINDS.items() if w > 0 and (medium == "can" or k != "dup")]
    faults = _pattern(rng, active)
    # Swarm testing: the other faults of a scenario are drawn from a few kinds only, so
    # that the ones it has come often enough to meet, and half of them start inside
    # another fault or as it ends (during its recovery).
    weights = [FAULT_KINDS[k] for k in kinds]
    swarm = sorted(set(rng.choices(kinds, weights, k=rng.randint(1, 4))), key=kinds.index)
    swarm_weights = [FAULT_KINDS[k] for k in swarm]
    for _ in range(rng.choice((0, 1, 1, 2, 2, 3, 3, 4, 5) if not faults else (0, 0, 1, 2))):
        kind = rng.choices(swarm, swarm_weights)[0]
        duration = 0.0 if kind == "reboot" else _duration(rng)
        if faults and rng.random() < 0.5:
            other = rng.choice(faults)
            if rng.random() < 0.5:
                start = other.start_s + rng.uniform(0.0, max(other.duration_s, 0.01))
            else:
                start = other.end_s + rng.uniform(-0.02, 0.15)
            start = max(0.01, start)
        else:
            start = rng.uniform(0.05, active)
        faults.append(_fault(rng, kind, start, duration))
    actions: list[Action] = []
    for _ in range(rng.randint(1, 4)):
        steps = _steps(rng, rng.randint(1, 3), zero_steps)
        actions.append(Action(rng.uniform(0.0, active), "steps", steps))
    if rng.random() < 0.02:
        # More than the host holds (64 waiting, 8 in the controller): the rest are refused.
        tiny = tuple((int(Command.FWD), 60, rng.randint(1, 10)) for _ in range(80))
        actions.append(Action(rng.uniform(0.0, active), "steps", tiny))
    if rng.random() < 0.3:
        actions.append(Action(rng.uniform(0.0, active), "stop"))
    if rng.random() < 0.05:
        actions.append(Action(rng.uniform(0.0, active), "stop-step"))
    if rng.random() < 0.35:
        actions.append(Action(rng.uniform(0.0, active + 0.3), "clear"))
    _issue_40(random.Random(seed * 7919 + 40), active, faults, actions)
    _wire(random.Random(seed * 7919 + 41), active, faults, actions)
    faults.sort(key=lambda f: f.start_s)
    actions.sort(key=lambda a: a.at_s)
    quiet = max([active, *(f.end_s for f in faults), *(a.at_s for a in actions)])
    return Scenario(
        seed=seed,
        controller=controller,
        medium=medium,
        mutants=tuple(sorted(mutants)),
        leak_samples=leak_samples,
        zero_steps=zero_steps,
        tick_s=tick_s,
        queue_depth=2 if rng.random() < 0.1 else 8,
        faults=tuple(faults),
        actions=tuple(actions),
        quiet_s=quiet,
        controller_mutant=controller_mutant,
    )
