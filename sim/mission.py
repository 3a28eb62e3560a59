"""The onboard mission in virtual time (docs/sim.md, "Missions").

The rover's sequencer and guard (:class:`bridge.onboard.core.OnboardCore`) with its
estimate (:class:`bridge.onboard.ekf.PoseEkf`) on the wire simulator's rig
(:class:`sim.rig.Rig`), and a ground station across a delayed, jittery, lossy link that
uplinks an approved plan, retransmits it until acknowledged, and keeps STOP authority.

:func:`make_mission` draws a :class:`MissionScenario` (a plan of one to five steps, its
prediction, the link and the faults its attributes list) from one seed;
:class:`MissionRig` plays it; the ROS hops on the rover take :data:`ROS_HOP_S` each. The
onboard program has been up for a while when a mission starts: the ground holds its boot
id and signs for it; after a restart it learns the new one from the reports.

Invariants (:class:`MissionOutcome` lists the violations, ``rule: text``; docs/sim.md,
"Missions", states each):

- ``once`` and the wire's rules: the wire simulator's own;
- ``step-once``, ``plan-once``: each step of a plan is sent at most once; a plan id
  starts at most once, across restarts of the onboard program;
- ``genuine``: every step sent is the step the ground signed, at its index;
- ``refused-inert``: nothing is driven for a plan refused or never sent;
- ``guard-bound``: true drift past the limits by :data:`TRUTH_MARGIN_M` or
  :data:`TRUTH_MARGIN_DEG`, POSE live: a STOP within :data:`GUARD_BOUND_S`;
- ``false-stop``: no guard STOP while the true drift is that margin inside the limits;
- ``ground-stop``: no step goes out once the ground's STOP reached the rover;
- ``stop-reached``: a lost onboard STOP is followed by one arriving within :data:`STOP_REACH_S`;
- ``delivered``: without slip, ground STOP, controller fault or a POSE silence over
  :data:`POSE_GAP_HARMLESS_S`, the plan completes exactly once and the ground hears it;
- ``rest``: after every end a rest report (or that it gave up waiting) reaches the ground.
"""

from __future__ import annotations

import json
import math
import random
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial

from bridge.link.linktypes import StatusEvent, StepRequest
from bridge.link.odometry import ground_pose
from bridge.onboard.core import (
    OnboardConfig,
    OnboardCore,
    SayStatus,
    SendAck,
    SendReport,
    SendStep,
    SendStop,
)
from bridge.onboard.ekf import PoseEkf
from bridge.ros.rosport.contract import ACCEPTED, CLEARED, STOPPED
from emulator.drive import turn_units_for_yaw
from emulator.playback import PlaybackResult, play
from emulator.twin import Pose2D, Twin
from firmware_proto.model.downlink import OnboardReport, decode_report
from firmware_proto.model.pose import Pose
from firmware_proto.model.rover import RoverDescription
from firmware_proto.model.uplink import (
    BOOT_HEX_DIGITS,
    REFUSED_FOR_NOW,
    CancelUplink,
    DriftLimits,
    PlanUplink,
    PredictedSample,
    decode_ack,
)
from firmware_proto.model.worldmap import WorldMap
from firmware_proto.wire.message import Message
from firmware_proto.wire.messages import Command, Encoders, FaultCode, PoseMsg, StopSource
from sim.checks import Violation
from sim.rig import _ACTION, Rig, _packaged_rover
from sim.scenario import DEFAULT_TICK_S, Scenario, ScenarioFault

__all__ = [
    "GUARD_BOUND_S",
    "ROS_HOP_S",
    "TRUTH_MARGIN_DEG",
    "TRUTH_MARGIN_M",
    "MissionOutcome",
    "MissionRig",
    "MissionScenario",
    "make_mission",
    "predict",
    "run_mission",
]

ROS_HOP_S = 0.001
"""One ROS 2 hop on the rover (onboard program <-> bridge), virtual s."""
GUARD_BOUND_S = 0.5
"""The guard's STOP follows the true crossing within this, virtual s: a POSE period and
its latency (0.1 s each), the filter's and the guard's persistence, with room."""
TRUTH_MARGIN_M = 0.05
TRUTH_MARGIN_DEG = 3.0
"""How far past (or short of) the limits the true drift must be, deg, for ``guard-bound`` (or
``false-stop``) to hold: the guard sees a noisy, filtered POSE, not the truth."""
POSE_GAP_HARMLESS_S = 1.0
"""A POSE silence this short never stops a plan: the rover drives less than the linear
limit (0.25 m) in it at the plan's top speed (0.21 m/s), and the time bound is 2 s."""
POSE_FRESH_S = 0.3
"""POSE counts as live while its last fix is younger than this, virtual s."""
UPLINK_AT_S = 0.5
"""When the ground sends its first uplink, virtual s (the link is up by then)."""
STOP_REPEAT_S = 0.5
"""The ground repeats STOP this often until it hears ``stopped``, s."""
STOP_REACH_S = 1.0
"""A lost STOP of the onboard program: another copy reaches the bridge within this, virtual s."""
TOKEN = "sim-token"
REFUSED_FOR_GOOD = frozenset(
    {
        "stale",
        "cancelled",
        "prediction_mismatch",
        "out_of_range",
        "other_boot",
        "start_mismatch",
    }
)
"""Refusals of a plan id for good (``refused-inert``); the others refuse one tampered or malformed
copy or refuse for now (:data:`~firmware_proto.model.uplink.REFUSED_FOR_NOW`)."""


def _tagged(result: PlaybackResult) -> list[PredictedSample]:
    """The playback's samples tagged with their step, as :mod:`gate.trajectory` tags them."""
    dt = result.dt_s

    def tick(t: float) -> int:
        return round(t / dt)

    out: list[PredictedSample] = []
    samples = result.samples
    ticks = [tick(s.time_s) for s in samples]
    cursor = 0
    previous = samples[0].pose
    for step in result.steps:
        start_k, end_k = tick(step.start_time_s), tick(step.end_time_s)
        out.append(PredictedSample(step.index, 0.0, previous.x_m, previous.y_m, previous.yaw_deg))
        while cursor < len(samples) and ticks[cursor] <= end_k:
            k = ticks[cursor]
            if start_k < k < end_k:
                p = samples[cursor].pose
                out.append(PredictedSample(step.index, (k - start_k) * dt, p.x_m, p.y_m, p.yaw_deg))
            cursor += 1
        e = step.end_pose
        out.append(PredictedSample(step.index, (end_k - start_k) * dt, e.x_m, e.y_m, e.yaw_deg))
        previous = e
    last = result.steps[-1]
    last_start = tick(last.start_time_s)
    for k, settled in zip(ticks[cursor:], samples[cursor:], strict=True):
        p = settled.pose
        out.append(PredictedSample(last.index, (k - last_start) * dt, p.x_m, p.y_m, p.yaw_deg))
    return out


def predict(
    rover: RoverDescription,
    plan_id: int,
    steps: tuple[tuple[int, int, int], ...],
    tick_s: float = DEFAULT_TICK_S,
    *,
    world: WorldMap | None = None,
    start: Pose2D | None = None,
    boot: str = "",
) -> PlanUplink:
    """The uplink of ``steps`` with their prediction, played on a twin of ``rover`` as
    the gate plays a plan: by default on an open plane from the origin (where the
    simulator's controller starts), else on ``world`` from ``start``; signed for the
    onboard program's ``boot``."""
    result = play(Twin(rover, world, dt_s=tick_s, start=start), steps)
    samples = _tagged(result)
    durations = tuple(s.end_time_s - s.start_time_s for s in result.steps)
    first = samples[0]
    goal = samples[-1]
    return PlanUplink(
        plan_id,
        steps,
        durations,
        tuple(samples),
        Pose(first.x, first.y, first.yaw_deg),
        Pose(goal.x, goal.y, goal.yaw_deg),
        DriftLimits.of(rover),
        f"{plan_id:064x}"[-64:],
        boot,
    )


@dataclass(frozen=True)
class MissionScenario:
    """One onboard mission, drawn from a seed (:func:`make_mission`).

    Attributes:
        seed, controller, medium, tick_s: as the wire simulator's scenario.
        steps: the plan.
        one_way_s, jitter_s, loss: the ground link, each way (virtual s, ratio).
        token: uplinks are signed and the rover checks them.
        slip: ``(step, fraction of its predicted duration, side, traction scale)``.
        pose_silent: ``(start_s, duration_s)`` of a POSE dropout (with ``fault:pose``).
        ground_stop_s: when the ground presses STOP (``None``: never).
        uplink_faults: what happens to the uplink besides loss: ``dup`` (every copy sent
            twice), ``late`` (the first copy arrives 2 s late), ``supersede`` (a plan
            sent first, cancelled, then the real one, the three reordered),
            ``replay`` (an older signed plan, and the plan itself, replayed after it
            ended), ``tamper`` (a copy with a changed step under the old tag),
            ``malformed`` (garbage), ``misfit`` (a signed plan whose prediction is
            another plan's).
        wire_faults: faults of the wire simulator (``reboot``, ``cut``) mid-plan.
        onboard_restart_s: when the onboard program restarts (``None``: never): a new
            boot id, a fresh core and estimate; the ground's copies of its plan, and with
            ``replay`` the replay, come again after it.
        lost_stops: the onboard program's first STOPs lost on the ROS hop to the bridge
            (its copies must stop the rover).
        ros_jitter_s: each ROS hop between the onboard program and the bridge (steps,
            STOPs, statuses) takes up to this much longer, in order per direction (a
            busy rover computer runs a callback late).
    """

    seed: int
    controller: str
    medium: str
    tick_s: float
    steps: tuple[tuple[int, int, int], ...]
    one_way_s: float
    jitter_s: float
    loss: float
    token: bool
    slip: tuple[int, float, str, float] | None
    pose_silent: tuple[float, float] | None
    ground_stop_s: float | None
    uplink_faults: tuple[str, ...]
    wire_faults: tuple[ScenarioFault, ...]
    onboard_restart_s: float | None = None
    lost_stops: int = 0
    ros_jitter_s: float = 0.0

    @property
    def reproducer(self) -> str:
        """The one command line that plays it again."""
        return (
            f"rover sim --mission --seed {self.seed} --controller {self.controller} "
            f"--medium {self.medium}"
        )

    @property
    def healthy(self) -> bool:
        """Nothing but the link's faults and a short POSE silence: the plan must
        complete. (A longer silence may stop it ``blind``: drift control needs a sensor
        that sees the ground.)"""
        return (
            (self.pose_silent is None or self.pose_silent[1] <= POSE_GAP_HARMLESS_S)
            and self.slip is None
            and self.ground_stop_s is None
            and not self.wire_faults
            and self.onboard_restart_s is None
        )

    def describe(self) -> list[str]:
        """The scenario in lines."""
        lines = [
            f"mission seed {self.seed}: {self.controller} controller on {self.medium}; "
            f"link {self.one_way_s:g} s one way, jitter {self.jitter_s:.2f} s, "
            f"loss {self.loss:g}; {'signed' if self.token else 'unsigned'} uplinks",
            "  plan " + " ".join(f"{Command(c).name}:{s}:{d}" for c, s, d in self.steps),
        ]
        if self.slip is not None:
            step, frac, side, scale = self.slip
            lines.append(f"  slip {side}={scale:.2f} from {frac:.0%} of step {step + 1}")
        if self.pose_silent is not None:
            lines.append(f"  POSE silent {self.pose_silent[0]:.2f}+{self.pose_silent[1]:.2f}s")
        if self.ground_stop_s is not None:
            lines.append(f"  ground STOP at {self.ground_stop_s:.2f}s")
        lines += [f"  uplink {u}" for u in self.uplink_faults]
        lines += ["  fault " + f.text() for f in self.wire_faults]
        if self.onboard_restart_s is not None:
            lines.append(f"  onboard program restarts at {self.onboard_restart_s:.2f}s")
        if self.lost_stops:
            lines.append(f"  the onboard program's first {self.lost_stops} STOP(s) lost")
        if self.ros_jitter_s:
            lines.append(f"  ROS hops on the rover up to {self.ros_jitter_s:g} s late")
        return lines


def _plan_steps(rng: random.Random, rover: RoverDescription) -> tuple[tuple[int, int, int], ...]:
    steps = []
    for _ in range(rng.randint(1, 5)):
        kind = rng.choices(("drive", "turn", "back"), (5, 3, 1))[0]
        speed = rng.randint(20, 45)
        if kind == "turn":
            command = rng.choice((Command.LEFT, Command.RIGHT))
            distance = turn_units_for_yaw(rover, math.radians(rng.uniform(20, 100)))
        else:
            command = Command.FWD if kind == "drive" else Command.REV
            distance = rover.m_to_units(rng.uniform(0.3, 1.2))
        steps.append((int(command), speed, min(30000, distance)))
    return tuple(steps)


def make_mission(
    seed: int, *, controller: str = "python", medium: str = "serial", tick_s: float = DEFAULT_TICK_S
) -> MissionScenario:
    """The mission of ``seed`` (see the module docstring)."""
    rng = random.Random(f"mission:{seed}")
    rover = _packaged_rover()
    steps = _plan_steps(rng, rover)
    duration = sum(rover.step_duration_s(s, d) for _, s, d in steps)
    arrive = UPLINK_AT_S + 1.5
    loss = rng.choice((0.0, 0.0, 0.1, 0.3, 0.3))
    jitter = rng.choice((0.0, 0.05, 0.2))
    slip = None
    if rng.random() < 0.4:
        step = rng.randrange(len(steps))
        side = rng.choice(("left", "right"))
        slip = (step, rng.uniform(0.0, 0.8), side, rng.uniform(0.02, 0.2))
    pose_silent = None
    if rng.random() < 0.25:
        pose_silent = (arrive + rng.uniform(0.0, duration), rng.uniform(0.3, 3.0))
    ground_stop = None
    if rng.random() < 0.15:
        ground_stop = UPLINK_AT_S + rng.uniform(0.0, duration + 3.0)
    kinds = ("dup", "late", "supersede", "replay", "tamper", "malformed", "misfit")
    uplink = tuple(k for k in kinds if rng.random() < 0.12)
    token = rng.random() < 0.7 or "tamper" in uplink
    wire: list[ScenarioFault] = []
    if rng.random() < 0.1:
        wire.append(ScenarioFault("reboot", arrive + rng.uniform(0.0, duration), 0.0))
    if rng.random() < 0.1:
        wire.append(
            ScenarioFault("cut", arrive + rng.uniform(0.0, duration), rng.uniform(0.4, 1.0))
        )
    restart = arrive + rng.uniform(-1.0, duration) if rng.random() < 0.08 else None
    lost_stops = rng.choice((1, 2)) if rng.random() < 0.15 else 0
    ros_jitter = 0.3 if rng.random() < 0.2 else 0.0
    return MissionScenario(
        seed,
        controller,
        medium,
        tick_s,
        steps,
        1.5,
        jitter,
        loss,
        token,
        slip,
        pose_silent,
        ground_stop,
        uplink,
        tuple(wire),
        restart,
        lost_stops,
        ros_jitter,
    )


@dataclass
class MissionOutcome:
    """What one mission did and whether every invariant held.

    Attributes:
        scenario: what was played.
        violations: the invariants broken (empty: passed).
        sim_s: virtual time simulated, s.
        ended: how the plan ended on board (``completed``, ``guard``, ...; ``""``: never).
        ground_heard: the ground heard that end with the rover's rest report.
        counts: what happened, by name.
        truth: physical figures from the twin (``overshoot_m`` past the true crossing to
            rest, ``time_to_rest_s``, ``rest_off_m``: the rest pose's true distance from
            the prediction at the crossing), when the guard stopped a drift.
        trace: events in words.
    """

    scenario: MissionScenario
    violations: list[Violation]
    sim_s: float
    ended: str
    ground_heard: bool
    counts: dict[str, int] = field(default_factory=dict)
    truth: dict[str, float] = field(default_factory=dict)
    trace: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        """Every invariant held."""
        return not self.violations


class _Channel:
    """One direction of the ground link for one kind of message: delay, jitter, loss,
    order kept (as ``rover link`` relays a topic)."""

    def __init__(self, rig: MissionRig, name: str, uplink: bool) -> None:
        sc = rig.mission
        self.rig = rig
        self.rng = random.Random(f"{sc.seed}:{name}")
        self.last_due = 0.0
        self.sent = 0
        self.lost = 0

    def send(self, fn: Callable[[], None], extra_s: float = 0.0, *, in_order: bool = True) -> None:
        sc = self.rig.mission
        self.sent += 1
        if sc.loss and self.rng.random() < sc.loss:
            self.lost += 1
            return
        delay = sc.one_way_s + (self.rng.uniform(0.0, sc.jitter_s) if sc.jitter_s else 0.0)
        due = self.rig.now + delay + extra_s
        if in_order:
            due = max(due, self.last_due)
            self.last_due = due
        self.rig._at(due, _ACTION, fn)


class MissionRig(Rig):
    """One mission, ready to :meth:`play`; see the module docstring."""

    def __init__(self, mission: MissionScenario, *, trace: bool = False) -> None:
        self.mission = mission
        rover = _packaged_rover()
        self._boots = random.Random(f"boot:{mission.seed}")
        boot = self._new_boot()
        self.uplink = predict(
            rover, 1000 + mission.seed % 1000, mission.steps, mission.tick_s, boot=boot
        )
        end = UPLINK_AT_S + 4.0 + 2.5 * self.uplink.expected_duration_s + 12.0
        base = Scenario(
            seed=mission.seed,
            controller=mission.controller,
            medium=mission.medium,
            mutants=(),
            leak_samples=False,
            zero_steps=False,
            tick_s=mission.tick_s,
            queue_depth=8,
            faults=mission.wire_faults,
            actions=(),
            quiet_s=end,
        )
        super().__init__(base, rover, trace=trace)
        self.end_s = end + 10.0
        token = TOKEN if mission.token else None
        self.token = token
        self.onboard = OnboardCore(rover, OnboardConfig(token=token, boot=boot))
        self.ekf = PoseEkf()
        self.cores = [self.onboard]
        """Every run of the onboard program, the first first (a restart adds one)."""
        self.ground_boot = boot
        """The boot id the ground signs for: the latest report's."""
        self._core_at = math.inf
        self.status_listeners.append(self._on_link_status)
        self.sample_listeners.append(self._on_sample)
        self.up = {n: _Channel(self, n, True) for n in ("plan", "stop")}
        self.down = {n: _Channel(self, n, False) for n in ("ack", "status", "report")}
        # what happened
        self.sent_steps: Counter[tuple[int, int]] = Counter()
        self.started: Counter[int] = Counter()
        self.refused: set[int] = set()
        self.stop_reached_s: float | None = None
        self.ground_taken: set[int] = set()
        self.ground_reports: dict[int, OnboardReport] = {}
        self.ground_stopped = False
        self.pending: dict[int, str] = {}
        """Envelopes the ground retransmits until taken, by plan id (a cancel by -upto)."""
        self.guard_stops: list[float] = []
        self.stops: list[float] = []
        self.crossing: tuple[float, float, float] | None = None
        """When the true drift first went past the limits by the margin, and where."""
        self.last_fix_s = -math.inf
        self.pose_fix_gaps: list[tuple[float, float]] = []
        self._slipped = False
        self.superseded: PlanUplink | None = None
        self.resend_s = 1.0
        self._true_drift = (0.0, 0.0)
        self.worst_true = (0.0, 0.0)
        self.first_over: tuple[float, float, float] | None = None
        """When and where the true drift first passed the limits (start of the physical figures)."""
        self._replayed = False
        self._clearing = False
        self.refusals: Counter[str] = Counter()
        """The rover's refusals, by reason."""
        self._stops_to_lose = mission.lost_stops
        self._ending = False
        self._hop_rng = random.Random(f"{mission.seed}:ros-hops")
        self._hop_due: dict[str, float] = {}
        self._submitted: tuple[int, int] | None = None
        self.true_starts: dict[tuple[int, int], float] = {}
        """When the controller took each step (``accepted``), by (plan, index): true alignment."""
        self.bridge_stops: list[float] = []
        """When a STOP reached the bridge (the onboard program's or the ground's)."""

    def _plan_report(self) -> OnboardReport | None:
        """The last report of the mission's plan, from the latest onboard run that took it."""
        plan = self.uplink.plan_id
        for core in reversed(self.cores):
            last = core.last_report
            if last is not None and last.plan_id == plan:
                return last
        return None

    def _new_boot(self) -> str:
        return f"{self._boots.getrandbits(4 * BOOT_HEX_DIGITS):0{BOOT_HEX_DIGITS}x}"

    # -- the run ---------------------------------------------------------------------------
    def play(self) -> MissionOutcome:
        """Play the mission to its end; the outcome with every violation found."""
        sc = self.mission
        self._at(UPLINK_AT_S, _ACTION, self._ground_start)
        if sc.pose_silent is not None:
            start, length = sc.pose_silent
            self._at(start, _ACTION, partial(self._pose_dropout, True))
            self._at(start + length, _ACTION, partial(self._pose_dropout, False))
        if sc.ground_stop_s is not None:
            self._at(sc.ground_stop_s, _ACTION, self._ground_stop)
        if sc.onboard_restart_s is not None:
            self._at(sc.onboard_restart_s, _ACTION, self._restart_onboard)
        self._schedule_core()
        outcome = self.run()
        violations = [v for v in outcome.violations if v.rule != "never-stuck"]
        violations += self._final()
        plan = self.uplink.plan_id
        report = self.ground_reports.get(plan)
        ended = ""
        last = self._plan_report()
        if last is not None and last.outcome:
            ended = last.outcome
        onboard: Counter[str] = Counter()
        for core in self.cores:
            onboard.update(core.counts)
        counts = {**outcome.counts, **{f"onboard_{k}": v for k, v in onboard.items()}}
        counts["uplink_copies"] = self.up["plan"].sent
        counts["uplink_lost"] = self.up["plan"].lost
        counts["ekf_inflations"] = self.ekf.inflations
        counts["ekf_too_old"] = self.ekf.too_old
        counts.update({f"refused:{k}": v for k, v in self.refusals.items()})
        return MissionOutcome(
            sc,
            violations,
            outcome.sim_s,
            ended,
            report is not None and report.ended and report.rest is not None,
            counts,
            self._truth(),
            outcome.trace,
        )

    def _recover(self) -> None:
        """The wire simulator's recovery probe is not part of a mission."""

    # -- the rover's onboard program --------------------------------------------------------
    def _schedule_core(self) -> None:
        due = self.onboard.next_deadline(self.now)
        if due < self._core_at:
            self._core_at = due
            self._at(due, _ACTION, self._core_tick)

    def _core_tick(self) -> None:
        if self.now != self._core_at:
            return
        self._core_at = math.inf
        self.onboard.tick(self.now)
        self._core_after()

    def _core_after(self) -> None:
        for action in self.onboard.take_actions():
            if isinstance(action, SendStop):
                self.stops.append(self.now)
                if action.reason.startswith("drift") and "(again" not in action.reason:
                    self.guard_stops.append(self.now)
                    self._false_stop_check()
                if self._stops_to_lose > 0 and not self._ending:
                    self._stops_to_lose -= 1
                    self._note(f"onboard STOP lost on the way: {action.reason}")
                    self._at(self.now + STOP_REACH_S, _ACTION, partial(self._stop_due, self.now))
                    continue
                self._note(f"onboard STOP: {action.reason}")
                self._at(self._hop("down"), _ACTION, partial(self._bridge_stop, False))
            elif isinstance(action, SendStep):
                self._note(f"onboard step {action.plan_id}/{action.index} {action.step}")
                self._check_step(action)
                self._at(self._hop("down"), _ACTION, partial(self._bridge_step, action))
            elif isinstance(action, SendAck):
                ack = action.ack
                self._note(f"onboard ack {ack.plan_id} {ack.result} {ack.reason}")
                if ack.result == "refused":
                    self.refusals[ack.reason] += 1
                if ack.result == "refused" and ack.reason in REFUSED_FOR_GOOD:
                    self.refused.add(ack.plan_id)
                text = ack.to_json()
                self.down["ack"].send(partial(self._ground_ack, text))
            elif isinstance(action, SayStatus):
                self._note(f"onboard says {action.text}")
                self.down["status"].send(partial(self._ground_status, action.text))
            elif isinstance(action, SendReport):
                text = action.report.to_json()
                self.down["report"].send(partial(self._ground_report, text))
        self._schedule_core()

    def _check_step(self, action: SendStep) -> None:
        key = (action.plan_id, action.index)
        self.sent_steps[key] += 1
        if self.sent_steps[key] > 1:
            self.violate("step-once", f"step {action.index} of plan {action.plan_id} sent again")
        if action.index == 0:
            self.started[action.plan_id] += 1
            if self.started[action.plan_id] > 1:
                self.violate("plan-once", f"plan {action.plan_id} started again")
        if action.plan_id in self.refused:
            self.violate("refused-inert", f"plan {action.plan_id} was refused and drives")
        genuine = self.uplink if action.plan_id == self.uplink.plan_id else self.superseded
        if genuine is None or genuine.plan_id != action.plan_id:
            self.violate("refused-inert", f"plan {action.plan_id} was never sent by the ground")
        elif genuine.steps[action.index] != action.step:
            self.violate("genuine", f"step {action.index} is {action.step}, signed otherwise")
        if self.stop_reached_s is not None and action.plan_id == self.uplink.plan_id:
            self.violate("ground-stop", f"step {action.index} sent after the ground's STOP")
        sc = self.mission
        if sc.slip is not None and not self._slipped and action.index == sc.slip[0]:
            step, frac, side, scale = sc.slip
            at = self.now + frac * self.uplink.durations_s[step]
            self._slipped = True
            self._at(at, _ACTION, partial(self._slip, side, scale))

    def _bridge_step(self, action: SendStep) -> None:
        self._submitted = (action.plan_id, action.index)
        self.ledger.submitted += 1
        self.core.submit_step(StepRequest(*action.step), self.now)
        self._host_after()

    def _stop_due(self, lost_s: float) -> None:
        """An onboard STOP was lost at ``lost_s``: one must have reached the bridge since."""
        if self.bridge_stops and self.bridge_stops[-1] >= lost_s:
            return
        self.violate(
            "stop-reached",
            f"the onboard program's STOP was lost at {lost_s:.3f} s and none reached the "
            f"bridge by {self.now:.3f} s",
        )

    def _bridge_stop(self, from_ground: bool) -> None:
        """``true`` on ``emergency_stop``: the bridge stops, the onboard program hears it."""
        self.bridge_stops.append(self.now)
        core = self.core
        core.emergency_stop(StopSource.OPERATOR, self.now)
        for stop in core.take_stops():
            self._host_send(stop)
            core.stop_written(stop.stop_id, self.now, True)
        self._host_after()
        if from_ground and self.stop_reached_s is None:
            self.stop_reached_s = self.now
        self._at(self.now + ROS_HOP_S, _ACTION, self._onboard_hears_stop)

    def _onboard_hears_stop(self) -> None:
        self.onboard.on_ground_stop(self.now)
        self._core_after()

    def _hop(self, direction: str) -> float:
        """When a message published now on the rover's ROS hop ``direction`` (``down``:
        onboard program to bridge; ``up``: back) arrives: :data:`ROS_HOP_S`, plus the
        scenario's jitter, in order."""
        jitter = self.mission.ros_jitter_s
        due = self.now + ROS_HOP_S + (self._hop_rng.uniform(0.0, jitter) if jitter else 0.0)
        due = max(due, self._hop_due.get(direction, 0.0))
        self._hop_due[direction] = due
        return due

    def _on_link_status(self, event: StatusEvent) -> None:
        text = event.text
        if text == ACCEPTED and self._submitted is not None:
            self.true_starts[self._submitted] = self.now  # the controller took it
        self._at(self._hop("up"), _ACTION, partial(self._onboard_status, text))
        self.down["status"].send(partial(self._ground_status, text))

    def _onboard_status(self, text: str) -> None:
        self.onboard.on_status(text, self.now)
        self._core_after()

    def _on_sample(self, msg: Message) -> None:
        ekf = self.ekf
        if isinstance(msg, Encoders):
            est = self.odometry.estimate()
            ekf.predict(self.now, est.x_m, est.y_m, est.yaw_rad, est.v_mps, est.yaw_rate_rad_s)
        elif isinstance(msg, PoseMsg):
            fix = ground_pose(msg)
            if fix is None:
                return
            var = fix.sigma_m**2
            stamp = self.now - fix.age_s
            self.last_fix_s = max(self.last_fix_s, stamp)
            cov = [var, 0.0, 0.0, 0.0, var, 0.0, 0.0, 0.0, max(var / 0.25, 1e-4)]
            ekf.correct(stamp, fix.x_m, fix.y_m, fix.yaw_rad, cov)  # type: ignore[arg-type]
        else:
            return
        estimate = ekf.take_estimate()
        if estimate is not None:
            self._at(self.now + ROS_HOP_S, _ACTION, partial(self._onboard_estimate, estimate))

    def _onboard_estimate(self, estimate: object) -> None:
        self.onboard.on_estimate(estimate, self.now)  # type: ignore[arg-type]
        self._core_after()

    def _onboard_uplink(self, text: str) -> None:
        self._note("uplink arrives")
        self.onboard.on_uplink(text, self.now)
        self._core_after()

    def _restart_onboard(self) -> None:
        """The onboard program ends (a plan running is stopped, as ``rover onboard``
        does on SIGTERM) and starts again: a new boot id, a new core, a fresh estimate;
        an operator releases the latch its STOP left. The ground's copies of its plan
        come again (a replay across the restart)."""
        self._note("onboard program restarts")
        self.onboard.shutdown("the onboard program is ending", self.now)
        # (not lost: the ending program repeats it until answered, at most 1 s:
        # OnboardNode.stop_now; the rig drops the old core at once)
        self._ending = True
        self._core_after()
        self._ending = False
        token = self.token
        self.onboard = OnboardCore(self.rover, OnboardConfig(token=token, boot=self._new_boot()))
        self.cores.append(self.onboard)
        self.ekf = PoseEkf()
        self._core_at = math.inf
        self._schedule_core()
        self._at(self.now + 0.5, _ACTION, self._bridge_clear)
        text = self._envelope(self.uplink)
        self._uplink(text, extra_s=0.2)
        self._uplink(text, extra_s=1.0)

    # -- the world ---------------------------------------------------------------------------
    def _slip(self, side: str, scale: float) -> None:
        self._note(f"slip {side}={scale:.2f}")
        left, right = (scale, 1.0) if side == "left" else (1.0, scale)
        self.ctl.twin.set_traction_scale(left, right)

    def _pose_dropout(self, on: bool) -> None:
        self._note(f"POSE {'silent' if on else 'back'}")
        ctl = self.ctl
        ctl.pose_sensor.dropout = on
        out = (
            ctl.raise_fault(FaultCode.POSE, condition=True)
            if on
            else ctl.clear_fault_condition(FaultCode.POSE)
        )
        if out:
            self._ctl_send(out)

    def _tick(self) -> None:
        super()._tick()
        self._truth_check()

    def _truth_check(self) -> None:
        aligned = self.onboard.predicted_at(self.now)
        if aligned is None:
            return
        pid, step, predicted = aligned
        started = self.true_starts.get((pid, step))
        if started is not None and pid == self.uplink.plan_id:
            # The prediction at the step's true start (the guard's own alignment may be
            # wrong: that is what false-stop is to catch).
            predicted = self.uplink.pose_at(step, self.now - started)
        pose = self.ctl.twin.pose
        linear = math.hypot(pose.x_m - predicted.x, pose.y_m - predicted.y)
        angular = abs(math.degrees(math.remainder(pose.yaw_rad - predicted.yaw_rad, math.tau)))
        limits = self.uplink.limits
        fresh = self.now - self.last_fix_s <= POSE_FRESH_S
        over = linear > limits.linear_m or angular > limits.angular_deg
        if over and self.first_over is None:
            self.first_over = (self.now, pose.x_m, pose.y_m)
        self.worst_true = (max(self.worst_true[0], linear), max(self.worst_true[1], angular))
        if (
            self.crossing is None
            and fresh
            and (
                linear > limits.linear_m + TRUTH_MARGIN_M
                or angular > limits.angular_deg + TRUTH_MARGIN_DEG
            )
        ):
            self.crossing = (self.now, pose.x_m, pose.y_m)
            self._at(self.now + GUARD_BOUND_S, _ACTION, partial(self._guard_due, self.now))
        self._true_drift = (linear, angular)

    def _false_stop_check(self) -> None:
        linear, angular = self._true_drift
        limits = self.uplink.limits
        if (
            linear < limits.linear_m - TRUTH_MARGIN_M
            and angular < limits.angular_deg - TRUTH_MARGIN_DEG
        ):
            self.violate(
                "false-stop",
                f"the guard stopped a rover {linear:.3f} m, {angular:.1f} deg off its "
                "prediction (truly within the limits)",
            )

    def _guard_due(self, crossed: float) -> None:
        if any(crossed - 0.05 <= t <= self.now for t in self.stops):
            return
        if self.onboard.predicted_at(self.now) is None and any(t <= self.now for t in self.stops):
            return  # the plan had ended another way meanwhile, with STOP
        if self.now - self.last_fix_s > POSE_FRESH_S:
            return  # POSE went quiet meanwhile: the estimate alone cannot see a slip
        self.violate(
            "guard-bound",
            f"true drift past the limits at {crossed:.3f} s and no STOP by {self.now:.3f} s",
        )

    # -- the ground ---------------------------------------------------------------------------
    def _envelope(self, message: PlanUplink | CancelUplink) -> str:
        return message.envelope(self.token)

    def _ground_start(self) -> None:
        sc = self.mission
        uplink = self.uplink
        if "supersede" in sc.uplink_faults:
            old = predict(
                self.rover,
                uplink.plan_id - 1,
                ((int(Command.FWD), 10, 50),),
                sc.tick_s,
                boot=self.ground_boot,
            )
            self.superseded = old
            # sent, then cancelled, then the real plan: jitter may reorder them all
            self._uplink(self._envelope(old), in_order=False)
            cancel = CancelUplink(old.plan_id)
            self.pending[-old.plan_id] = self._envelope(cancel)
            self._uplink(self.pending[-old.plan_id], extra_s=0.05, in_order=False)
        text = self._envelope(uplink)
        self.pending[uplink.plan_id] = text
        late = 2.0 if "late" in sc.uplink_faults else 0.0
        self._uplink(text, extra_s=late, in_order="supersede" not in sc.uplink_faults)
        for kind in ("tamper", "malformed", "misfit"):
            if kind in sc.uplink_faults:
                self._uplink(self._bad(kind), extra_s=0.1)
        self._at(self.now + self.resend_s, _ACTION, self._ground_resend)

    def _bad(self, kind: str) -> str:
        if kind == "malformed":
            return '{"body": "{not json", "tag": null}'
        if kind == "tamper":
            env = json.loads(self._envelope(self.uplink))
            body = json.loads(env["body"])
            body["steps"][0][2] = max(1, body["steps"][0][2] // 2)
            env["body"] = json.dumps(body, separators=(",", ":"))
            return json.dumps(env)
        # misfit: a newer id with another plan's prediction (a mix-up), properly signed
        other = predict(
            self.rover,
            self.uplink.plan_id + 1,
            ((int(Command.FWD), 30, 4600),),
            boot=self.ground_boot,
        )
        mixed = PlanUplink(
            other.plan_id,
            ((int(Command.LEFT), 30, 6000),),
            other.durations_s,
            other.prediction,
            other.start,
            other.goal,
            other.limits,
            other.verdict,
            other.boot,
        )
        return self._envelope(mixed)

    def _uplink(self, text: str, extra_s: float = 0.0, *, in_order: bool = True) -> None:
        copies = 2 if "dup" in self.mission.uplink_faults else 1
        for _ in range(copies):
            self.up["plan"].send(partial(self._onboard_uplink, text), extra_s, in_order=in_order)

    def _ground_resend(self) -> None:
        if not self.pending or self._probe_done:
            return
        for key in sorted(self.pending):
            self._uplink(self.pending[key], in_order="supersede" not in self.mission.uplink_faults)
        self._at(self.now + self.resend_s, _ACTION, self._ground_resend)

    def _ground_ack(self, text: str) -> None:
        ack = decode_ack(text)
        if ack.result == "cancelled":
            self.pending.pop(-ack.plan_id, None)
            if ack.state == "stopped":
                self._ground_clear()
        elif ack.taken:
            self.ground_taken.add(ack.plan_id)
            self.pending.pop(ack.plan_id, None)
        elif ack.result == "refused" and ack.reason not in REFUSED_FOR_NOW:
            self.pending.pop(ack.plan_id, None)

    def _ground_status(self, text: str) -> None:
        if text == STOPPED:
            self.ground_stopped = True
        elif text == CLEARED:
            self._clearing = False

    def _ground_clear(self) -> None:
        """Release the latch the cancel's STOP left, repeated until ``cleared``."""
        if self._clearing or self._probe_done:
            return
        self._clearing = True
        self._clear_copy()

    def _clear_copy(self) -> None:
        if not self._clearing or self._probe_done:
            return
        self.up["stop"].send(self._bridge_clear)
        self._at(self.now + STOP_REPEAT_S * 2, _ACTION, self._clear_copy)

    def _bridge_clear(self) -> None:
        self._note("ground clear")
        self.operator_clear()
        self._host_after()

    def _ground_report(self, text: str) -> None:
        report = decode_report(text)
        if report.boot:
            self.ground_boot = report.boot
        if report.plan_id == 0:
            return
        known = self.ground_reports.get(report.plan_id)
        if known is None or report.seq > known.seq or report.boot != known.boot:
            self.ground_reports[report.plan_id] = report
        mine = self.ground_reports.get(self.uplink.plan_id)
        if mine is not None and mine.ended and mine.rest is not None:
            # The ground knows how it ended and where the rover rests: the mission is over
            # once nothing the ground sent can still drive (stragglers, replays).
            wait = 1.0
            if "replay" in self.mission.uplink_faults and not self._replayed:
                self._replayed = True
                old = predict(
                    self.rover,
                    self.uplink.plan_id - 5,
                    ((int(Command.FWD), 30, 9000),),
                    boot=self.ground_boot,
                )
                self._uplink(self._envelope(old))
                self._uplink(self._envelope(self.uplink))
                wait = 2.5
            self._at(self.now + wait, _ACTION, self._finish)

    def _finish(self) -> None:
        self.pending.clear()
        self._probe_done = True

    def _ground_stop(self) -> None:
        if self.ground_stopped or self._probe_done:
            return
        self._note("ground STOP")
        self.up["stop"].send(partial(self._bridge_stop, True))
        self._at(self.now + STOP_REPEAT_S, _ACTION, self._ground_stop)

    # -- the end --------------------------------------------------------------------------------
    def _final(self) -> list[Violation]:
        out: list[Violation] = []
        sc = self.mission
        plan = self.uplink.plan_id
        last = self._plan_report()
        ended = last.outcome if last is not None else ""
        heard = self.ground_reports.get(plan)
        if sc.healthy:
            if ended != "completed" or self.started[plan] != 1:
                out.append(
                    Violation(
                        "delivered",
                        self.now,
                        f"a healthy plan ended {ended or 'never'} (started "
                        f"{self.started[plan]} times)",
                    )
                )
            elif heard is None or heard.outcome != "completed":
                out.append(Violation("delivered", self.now, "the ground never heard it complete"))
        restarted = sc.onboard_restart_s is not None
        if self.started[plan] and ended and not restarted and (heard is None or heard.rest is None):
            out.append(
                Violation(
                    "rest", self.now, f"plan ended {ended}; no rest report reached the ground"
                )
            )
        if self.superseded is not None and self.started[self.superseded.plan_id]:
            pass  # it may run until its cancel arrives: step-once and ground rules still hold
        return out

    def _truth(self) -> dict[str, float]:
        out = {"worst_linear_m": self.worst_true[0], "worst_angular_deg": self.worst_true[1]}
        if self.first_over is None or not self.guard_stops:
            return out
        t, x, y = self.first_over
        last = self.onboard.last_report
        rest = last.rest if last is not None else None
        if rest is None:
            return out
        pose = self.ctl.twin.pose
        out.update(
            stop_after_crossing_s=self.guard_stops[0] - t,
            overshoot_m=math.hypot(pose.x_m - x, pose.y_m - y),
            time_to_rest_s=rest.stamp_s - t,
        )
        return out


def run_mission(mission: MissionScenario, *, trace: bool = False) -> MissionOutcome:
    """Play ``mission`` once; see :class:`MissionRig`."""
    return MissionRig(mission, trace=trace).play()
