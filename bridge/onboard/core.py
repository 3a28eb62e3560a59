"""The rover's sequencer and drift guard as a state machine with no thread, no clock and
no I/O (docs/onboard.md): the approved plan comes up once, runs here step after step, and
drift stops the wheels where they are, not a round trip later.

:class:`OnboardCore` is driven by events, each with the time it happened, s, on the
clock the estimates' stamps are on too (the program's monotonic clock: bridge/onboard/node.py):

- :meth:`~OnboardCore.on_uplink`: an uplink envelope (a plan or a cancel) as received;
- :meth:`~OnboardCore.on_status`: a ``/command_status`` string of the bridge;
- :meth:`~OnboardCore.on_estimate`: the pose estimate (:class:`~bridge.onboard.ekf.Estimate`),
  at every ``odom`` and POSE;
- :meth:`~OnboardCore.on_ground_stop`: an emergency stop heard on ``emergency_stop``
  (the ground's; the core's own comes back too and finds nothing to stop);
- :meth:`~OnboardCore.tick`: the passing of time, due at :meth:`~OnboardCore.next_deadline`.

What it decides comes out of :meth:`~OnboardCore.take_actions`, in order:
:class:`SendStop` (always first of a batch: a STOP waits for nothing), :class:`SendStep`,
:class:`SendAck`, :class:`SayStatus` and :class:`SendReport`.

**Uplinks** (the refusal reasons: docs/onboard.md, "The uplink"). A refused plan is
answered on the ack and as ``plan_refused:<reason>`` on ``/command_status``, and nothing
is driven. ``busy``, ``latched`` and ``no_fix`` hold for now (the ground resends); the
others for good. :attr:`OnboardCore.boot` is random at each start and a plan must be
signed for it, so nothing signed before a restart runs after it. A copy of a plan
already taken is answered ``duplicate`` and runs nothing again: each id runs at most
once.

**Running.** A plan taken while the latch is held by the core's own STOP waits ``armed``
until ``cleared`` (the guard never releases the latch), at most ``arm_timeout_s``. Any
STOP the core did not send (heard on ``emergency_stop``, or a ``stopped`` /
``aborted:stop`` no STOP of its own explains) ends a running plan, drops an armed one,
and raises the cancel floor to the newest id taken, so nothing taken before that STOP
ever starts after it.

Steps go out one at a time, each as soon as the one before it is ``completed``: every
status is the fate of the one step outstanding (``/command_status`` names no step). For
the guard's prediction a step starts when its wheels begin to move, not when its
``accepted`` callback runs (a busy computer runs it late). Any other end of a step
(``rejected:``, ``aborted:``, a fault but a lost sensor's, no ``completed`` within 1.5
times its predicted duration plus ``step_margin_s``) ends the plan with STOP; so does a
status that cannot be the fate of the step outstanding (``foreign_step``).

**The guard.** Each estimate is compared with the prediction for the same moment of the
same step; ``persistence`` consecutive estimates beyond the uplink's limits and the core
sends STOP at once, drops the rest of the plan and reports where. Drift control needs a
sensor that sees the ground, so a plan also stops (outcome ``blind``) when the POSE fix
is too old for the motion since it (:meth:`OnboardCore._sees_ground`), when no estimate
came for ``blind_s`` while a step runs, or when an estimate is not finite.

**Its STOP is confirmed.** Every STOP of the core's goes out again every
``stop_repeat_s`` until the bridge answers ``stopped`` (at most ``stop_repeats`` more
copies); ``cleared`` ends the wait. Its copies heard back on ``emergency_stop`` within
``echo_window_s`` are its own; any other STOP is someone else's.

**After any end** the core waits for the rover to stand (at most ``rest_timeout_s``) and
reports the estimate there with its covariance, how far the rover moved from where the
plan ended and how long it took.

Every event ends with a snapshot report of the plan
(:class:`~firmware_proto.model.downlink.OnboardReport`), and the latest goes out again every
``report_period_s`` so that a lossy downlink still delivers the end; before any plan, an
``idle`` report, so that the ground learns the boot id to sign for.

Not thread-safe: one caller at a time (the program holds a lock around every call).
"""

from __future__ import annotations

import enum
import logging
import math
import secrets
from collections import deque
from dataclasses import dataclass, field

from bridge.onboard.ekf import Estimate
from bridge.ros.rosport.contract import (
    ACCEPTED,
    CLEARED,
    COMPLETED,
    STOPPED,
    Outcome,
    parse_status,
    plan_refused,
)
from firmware_proto.errors import UplinkError
from firmware_proto.model.downlink import GuardStop, OnboardReport, RestReport
from firmware_proto.model.geometry import wrap_deg
from firmware_proto.model.pose import Pose
from firmware_proto.model.rover import RoverDescription
from firmware_proto.model.uplink import (
    BOOT_HEX_DIGITS,
    CancelUplink,
    PlanUplink,
    UplinkAck,
    decode_body,
    is_boot_id,
    open_envelope,
    peek_body,
)
from firmware_proto.wire.messages import Command

__all__ = [
    "Action",
    "OnboardConfig",
    "OnboardCore",
    "PlanState",
    "SayStatus",
    "Screened",
    "SendAck",
    "SendReport",
    "SendStep",
    "SendStop",
    "decode_screened",
    "screen_uplink",
]

logger = logging.getLogger(__name__)

REFUSAL_LOG_PERIOD_S = 1.0
"""Refusals of one reason are logged at most this often (the rest are counted)."""
REPORTING_FAULTS = frozenset({"pose", "imu"})
"""``fault:<reason>`` of a lost sensor: the controller and the plan keep going (the guard copes)."""


_DIRECTION: dict[int, float] = {
    Command.FWD: 1.0,
    Command.REV: -1.0,
    Command.LEFT: 1.0,
    Command.RIGHT: -1.0,
}
"""The sign of the speed (drives) or turn rate (turns) each command moves with."""


class PlanState(str, enum.Enum):
    """Where a plan is on board (:data:`firmware_proto.model.downlink.STATES`)."""

    ARMED = "armed"
    RUNNING = "running"
    COMPLETED = "completed"
    STOPPED = "stopped"
    FAILED = "failed"
    CANCELLED = "cancelled"


_ENDS = {
    "completed": PlanState.COMPLETED,
    "guard": PlanState.STOPPED,
    "ground_stop": PlanState.STOPPED,
    "blind": PlanState.STOPPED,
    "cancelled": PlanState.CANCELLED,
    "failed": PlanState.FAILED,
}


@dataclass(frozen=True)
class OnboardConfig:
    """How the sequencer and guard behave (times in the rover's seconds).

    Attributes:
        token: the uplink token: uplinks must carry its tag (``None``: not checked).
        boot: this run's boot id (:data:`~firmware_proto.model.uplink.BOOT_HEX_DIGITS`
            lower-case hex digits; ``""``: the core draws a random one). A plan must be
            signed for it.
        min_plan_id: plan ids below this are stale.
        time_scale: twin seconds per rover second (the emulator runs faster in a demo).
        persistence: consecutive estimates beyond a limit before the guard stops.
        blind_s: no estimate this long while a step runs: STOP (outcome ``blind``).
        step_margin_s: added to 1.5 x a step's predicted duration for its timeout.
        arm_timeout_s: longest an armed plan waits for the latch to be released.
        rest_speed_mps, rest_yaw_rate_rad_s, rest_hold_s: at rest when the wheels are
            below both for this long.
        rest_timeout_s: report the estimate after an end at the latest this much later.
        report_period_s: the latest report goes out again this often.
        remember: plan ids kept to answer copies as duplicates.
        fix_fresh_s: a plan starts only when the estimate holds a POSE fix younger than
            this (``no_fix`` otherwise).
        stop_repeat_s, stop_repeats: the core's STOP goes out again this often, at most
            this many more times, until the bridge answers ``stopped``.
        echo_window_s: the core's own STOP heard back on ``emergency_stop``, or a
            ``stopped`` that answers one of its copies, comes within this of the copy
            (later: someone else's STOP).
        pose_gap_s: while a step runs and the wheels move, the estimate's last POSE fix
            older than this: STOP (``blind``).
        unseen_grace_s: the linear limit driven unseen (:attr:`Estimate.unseen_m`) stops
            the plan when no POSE has brought it back below within this, s (after a
            stall, the POSE that covers the motion may be read just behind the odometry).
        start_speed_mps, start_yaw_rate_rad_s: a step has started, for the guard's
            prediction, once the estimate moves its way above these (above the rest
            thresholds; :meth:`OnboardCore._seen_start`).
    """

    token: str | None = None
    boot: str = ""
    min_plan_id: int = 1
    time_scale: float = 1.0
    persistence: int = 3
    blind_s: float = 0.5
    step_margin_s: float = 2.0
    arm_timeout_s: float = 30.0
    rest_speed_mps: float = 0.01
    rest_yaw_rate_rad_s: float = 0.01
    rest_hold_s: float = 0.2
    rest_timeout_s: float = 5.0
    report_period_s: float = 1.0
    remember: int = 256
    fix_fresh_s: float = 1.0
    stop_repeat_s: float = 0.25
    stop_repeats: int = 8
    echo_window_s: float = 1.0
    pose_gap_s: float = 2.0
    unseen_grace_s: float = 0.1
    start_speed_mps: float = 0.02
    start_yaw_rate_rad_s: float = 0.05

    def __post_init__(self) -> None:
        if self.boot and not is_boot_id(self.boot):
            raise ValueError(f"boot must be {BOOT_HEX_DIGITS} lower-case hex digits")
        for name in (
            "time_scale",
            "blind_s",
            "step_margin_s",
            "arm_timeout_s",
            "rest_hold_s",
            "rest_timeout_s",
            "report_period_s",
            "fix_fresh_s",
            "stop_repeat_s",
            "echo_window_s",
            "pose_gap_s",
            "unseen_grace_s",
        ):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be finite and > 0, got {value}")
        if self.persistence < 1:
            raise ValueError(f"persistence must be >= 1, got {self.persistence}")
        if self.stop_repeats < 0:
            raise ValueError(f"stop_repeats must be >= 0, got {self.stop_repeats}")


# -- actions ---------------------------------------------------------------------------------
@dataclass(frozen=True)
class SendStop:
    """Publish ``true`` on ``emergency_stop`` (the bridge's STOP lane) now."""

    reason: str


@dataclass(frozen=True)
class SendStep:
    """Publish one step on ``wheel_instructions``."""

    plan_id: int
    index: int
    step: tuple[int, int, int]


@dataclass(frozen=True)
class SendAck:
    """Answer an uplink on the ack topic."""

    ack: UplinkAck


@dataclass(frozen=True)
class SayStatus:
    """Publish one string on ``/command_status`` (a refusal)."""

    text: str


@dataclass(frozen=True)
class SendReport:
    """Publish a snapshot report on the report topic."""

    report: OnboardReport


Action = SendStop | SendStep | SendAck | SayStatus | SendReport


@dataclass
class _Plan:
    uplink: PlanUplink
    state: PlanState
    taken_s: float
    step: int = 0
    status: str = ""
    published_s: float = math.nan
    started: list[float] = field(default_factory=list)
    """When each step started (rover clock), in order."""
    accepted: bool = False
    outcome: str = ""
    reason: str = ""
    ended_s: float = math.nan
    end_pose: Pose | None = None
    guard: GuardStop | None = None
    rest: RestReport | None = None
    drift: tuple[float, float] | None = None
    worst: tuple[float, float] = (0.0, 0.0)
    over: int = 0
    still_since: float | None = None
    moved: bool = False
    """The step out was seen to start (an estimate in motion stamped after it went out)."""
    still_s: float = -math.inf
    """The stamp of the last estimate since the step went out not moving its way."""
    unseen_since: float | None = None
    """Since when the estimates have the linear limit driven unseen (core clock)."""


class OnboardCore:
    """The sequencer and guard; see the module docstring."""

    def __init__(self, rover: RoverDescription, config: OnboardConfig | None = None) -> None:
        self.rover = rover
        self.config = config or OnboardConfig()
        self.boot = self.config.boot or secrets.token_hex(BOOT_HEX_DIGITS // 2)
        """This run's boot id: plans must be signed for it; every report names it."""
        self._actions: list[Action] = []
        self._plan: _Plan | None = None
        """The plan armed, running, or the last one (ended)."""
        self._settling: _Plan | None = None
        """An ended plan whose rest is still to be reported."""
        self._states: dict[int, PlanState] = {}
        self._max_taken = 0
        self._cancel_floor = 0
        self._latched = False
        self._latch_own = False
        """The latch is held by the core's own STOPs only: only then does a plan wait armed."""
        self._stop_sent = False
        """The core's STOP is unanswered (resent until then): the next ``stopped`` is the core's."""
        self._stop_reason = ""
        self._stop_copies = 0
        """Copies of the unanswered STOP sent so far."""
        self._stop_last_s = -math.inf
        """When the core's latest STOP copy went out."""
        self._own_echoes: deque[float] = deque()
        """When each unechoed STOP copy went out (due within ``echo_window_s``, else expires)."""
        self._estimate: Estimate | None = None
        self._last_estimate_s = -math.inf
        self._seq = 0
        self._last_report: OnboardReport | None = None
        self._next_report_s = -math.inf
        self._refusal_log: dict[str, tuple[float, int]] = {}
        """Per refusal reason: when it was last logged and how many went unlogged since."""
        self.counts: dict[str, int] = {
            "uplinks": 0,
            "accepted": 0,
            "duplicates": 0,
            "refused": 0,
            "cancels": 0,
            "steps_sent": 0,
            "guard_stops": 0,
            "ground_stops": 0,
            "bad_estimates": 0,
            "stop_repeats": 0,
        }
        """What the core has seen and done, by name (the program's diagnostics)."""

    # -- reading -----------------------------------------------------------------------------
    @property
    def latched(self) -> bool:
        """The bridge's STOP latch, as ``stopped`` / ``cleared`` said."""
        return self._latched

    @property
    def active(self) -> bool:
        """A plan is armed or running."""
        return self._plan is not None and self._plan.state in (PlanState.ARMED, PlanState.RUNNING)

    @property
    def stop_unanswered(self) -> bool:
        """A STOP of the core's is out, neither answered ``stopped`` nor ended by ``cleared``."""
        return self._stop_sent

    @property
    def running(self) -> PlanUplink | None:
        """The uplink of the plan running now (``None``: none runs)."""
        plan = self._plan
        return plan.uplink if plan is not None and plan.state is PlanState.RUNNING else None

    @property
    def last_report(self) -> OnboardReport | None:
        """The latest report made."""
        return self._last_report

    def take_actions(self) -> list[Action]:
        """What to do now, in order (STOPs first); empties the queue."""
        actions, self._actions = self._actions, []
        stops = [a for a in actions if isinstance(a, SendStop)]
        if stops:
            actions = stops + [a for a in actions if not isinstance(a, SendStop)]
        return actions

    def next_deadline(self, now: float) -> float:
        """The latest time :meth:`tick` must run next (``inf``: nothing pending)."""
        due = self._next_report_s
        plan = self._plan
        cfg = self.config
        if plan is not None and plan.state is PlanState.ARMED:
            due = min(due, plan.taken_s + cfg.arm_timeout_s)
        if plan is not None and plan.state is PlanState.RUNNING:
            due = min(due, self._step_deadline(plan), self._last_estimate_s + cfg.blind_s)
        if self._settling is not None:
            due = min(due, self._settling.ended_s + cfg.rest_timeout_s)
        if self._stop_sent and self._stop_copies <= cfg.stop_repeats:
            due = min(due, self._stop_last_s + cfg.stop_repeat_s)
        return max(due, now) if due < math.inf else due

    # -- events ------------------------------------------------------------------------------
    def on_uplink(self, text: str | bytes, now: float) -> None:
        """An uplink envelope arrived (a plan or a cancel): :func:`screen_uplink`, then
        :meth:`on_screened` and, unless that answered it, :func:`decode_screened` and
        :meth:`on_decoded`. The program runs the two pure steps outside its lock."""
        screened = screen_uplink(text, self.config.token)
        if self.on_screened(screened, now):
            return
        self.on_decoded(screened, decode_screened(screened, self.rover), now)

    def on_screened(self, screened: Screened, now: float) -> bool:
        """The first, cheap look at an uplink: a bad envelope or tag is refused, a copy
        of a plan already taken answered ``duplicate``. ``True``: answered, nothing more
        to do; ``False``: decode the body and call :meth:`on_decoded`."""
        self.counts["uplinks"] += 1
        if screened.error is not None:
            self._refuse(screened.plan_id, screened.error.reason, screened.error.detail, now)
            return True
        pid = screened.plan_id
        if screened.is_plan and pid in self._states:
            self._duplicate(pid)
            return True
        return False

    def on_decoded(
        self, screened: Screened, message: PlanUplink | CancelUplink | UplinkError, now: float
    ) -> None:
        """The body of a screened uplink, decoded (or why it could not be)."""
        if isinstance(message, UplinkError):
            self._refuse(screened.plan_id, message.reason, message.detail, now)
        elif isinstance(message, CancelUplink):
            self._cancel(message.upto, now)
        else:
            self._plan_uplink(message, now)

    def _duplicate(self, pid: int) -> None:
        self.counts["duplicates"] += 1
        state = self._states[pid].value
        self._ack(UplinkAck(pid, "duplicate", "", f"plan {pid} was taken before", state))

    def _plan_uplink(self, uplink: PlanUplink, now: float) -> None:
        pid = uplink.plan_id
        if uplink.boot != self.boot:
            signed = f"boot {uplink.boot}" if uplink.boot else "no boot"
            self._refuse(
                pid,
                "other_boot",
                f"signed for {signed}; this is boot {self.boot} (a copy from before a "
                "restart of rover onboard, or a plan for another rover)",
                now,
            )
            return
        if pid in self._states:
            self._duplicate(pid)
            return
        if pid <= self._cancel_floor:
            self._refuse(
                pid,
                "cancelled",
                f"the ground cancelled every plan up to {self._cancel_floor}",
                now,
            )
            return
        if pid < self._max_taken or pid < self.config.min_plan_id:
            floor = max(self._max_taken, self.config.min_plan_id)
            self._refuse(
                pid,
                "stale",
                f"plan {pid} is older than {floor} (a replay or a late copy)",
                now,
            )
            return
        current = self._plan
        if current is not None and current.state in (PlanState.ARMED, PlanState.RUNNING):
            running = current.uplink.plan_id
            self._refuse(
                pid,
                "busy",
                f"plan {running} is {current.state.value}; resend once it ends",
                now,
            )
            return
        if self._latched and not self._latch_own:
            self._refuse(
                pid,
                "latched",
                "the rover is latched by a STOP that is not its own guard's; resend once "
                "the latch is released",
                now,
            )
            return
        unfit = self._unfit_start(uplink, now)
        if unfit is not None:
            self._refuse(pid, *unfit, now)
            return
        plan = _Plan(uplink, PlanState.ARMED, now)
        self._plan = plan
        self._states[pid] = PlanState.ARMED
        while len(self._states) > self.config.remember:
            self._states.pop(next(iter(self._states)))
        self._max_taken = max(self._max_taken, pid)
        self.counts["accepted"] += 1
        logger.info(
            "plan %d taken: %d steps, verdict %s%s",
            pid,
            len(uplink.steps),
            uplink.verdict[:12],
            "; armed until the latch is released" if self._latched else "",
        )
        if self._latched:
            self._ack(
                UplinkAck(pid, "accepted", "", "armed: waits for the latch's release", "armed")
            )
            self._report("armed", now)
            return
        self._ack(UplinkAck(pid, "accepted", "", "running", "running"))
        self._start(plan, now)

    def _unfit_start(self, uplink: PlanUplink, now: float) -> tuple[str, str] | None:
        """``(reason, detail)`` when the plan may not start from where the rover is
        (``no_fix``, ``start_mismatch``); ``None``: it may."""
        est = self._estimate
        fresh = self.config.fix_fresh_s
        if est is None or not now - est.pose_stamp_s <= fresh:
            age = (
                "none"
                if est is None or est.pose_stamp_s == -math.inf
                else (f"{now - est.pose_stamp_s:.1f} s old")
            )
            return (
                "no_fix",
                f"no POSE fix in the last {fresh:g} s (last: {age}): the guard needs a "
                "sensor that sees the ground",
            )
        start = uplink.start
        linear = math.hypot(est.x_m - start.x, est.y_m - start.y)
        angular = abs(wrap_deg(est.yaw_deg - start.yaw_deg))
        limits = uplink.limits
        if linear > limits.linear_m or angular > limits.angular_deg:
            return (
                "start_mismatch",
                f"the plan starts at ({start.x:.2f}, {start.y:.2f}, {start.yaw_deg:.0f} deg), "
                f"{linear:.2f} m and {angular:.1f} deg from the rover's estimate "
                f"({est.x_m:.2f}, {est.y_m:.2f}, {est.yaw_deg:.0f} deg)",
            )
        return None

    def _cancel(self, upto: int, now: float) -> None:
        self.counts["cancels"] += 1
        self._cancel_floor = max(self._cancel_floor, upto)
        plan = self._plan
        detail = f"every plan up to {upto} is cancelled"
        state = "cancelled"
        if plan is not None and plan.uplink.plan_id <= upto:
            if plan.state is PlanState.RUNNING:
                # Its step is stopped where it is: the latch then holds until the ground
                # releases it (the ack says "stopped" so that the ground knows).
                self._stop("cancelled by the ground", now)
                self._end(plan, "cancelled", "cancelled by the ground", now)
                state = "stopped"
                detail += f"; plan {plan.uplink.plan_id} was running and is stopped"
            elif plan.state is PlanState.ARMED:
                self._end(plan, "cancelled", "cancelled by the ground before it started", now)
        self._ack(UplinkAck(upto, "cancelled", "", detail, state))

    def on_status(self, text: str, now: float) -> None:
        """One ``/command_status`` string of the bridge (the core's own refusals are ignored)."""
        kind, reason = parse_status(text)
        plan = self._plan
        if text == STOPPED:
            if self._stop_sent or now - self._stop_last_s <= self.config.echo_window_s:
                # The core's own (or the answer to a copy that crossed the first answer).
                self._stop_sent = False
                self._latched = True
            else:
                self._foreign_stop("the ground's STOP (stopped)", now)
            return
        if text == CLEARED:
            if self._stop_sent:
                logger.warning(
                    "the latch was released before the bridge answered the core's STOP "
                    "(%s): no more copies",
                    self._stop_reason,
                )
            self._stop_sent = False
            self._latched = False
            self._latch_own = False
            if plan is not None and plan.state is PlanState.ARMED:
                unfit = self._unfit_start(plan.uplink, now)
                if unfit is not None:
                    self._end(plan, "failed", f"not started: {unfit[0]}: {unfit[1]}", now)
                    return
                logger.info("plan %d: latch released; starting", plan.uplink.plan_id)
                self._start(plan, now)
            return
        if plan is None or plan.state is not PlanState.RUNNING:
            if kind == Outcome.REJECTED.value and reason == "stop_latched":
                self._latch_unknown()
            return
        if text == ACCEPTED:
            if plan.accepted:
                # A second ``accepted`` for the one step outstanding is another's step.
                self._foreign_step(plan, "a second 'accepted' for one step", now)
                return
            # The callback's time is the start plus however late this computer runs it.
            plan.accepted = True
            plan.status = text
            self._report("step", now)
            return
        if text == COMPLETED:
            if not plan.accepted:
                # Another's step (or a repeated status): it would advance the plan past
                # a step that never ran.
                self._foreign_step(plan, "'completed' before the step was accepted", now)
                return
            plan.status = text
            self._next_step(plan, now)
            return
        if kind == Outcome.FAULT.value and reason in REPORTING_FAULTS:
            plan.status = text
            self._report("step", now)
            return
        if kind not in (Outcome.REJECTED.value, Outcome.ABORTED.value, Outcome.FAULT.value):
            return  # ready, the core's own plan_refused:..., anything new
        plan.status = text
        if kind == Outcome.REJECTED.value and reason == "stop_latched":
            self._latch_unknown()
        if kind == Outcome.ABORTED.value and reason == "stop" and not self._stop_sent:
            self._foreign_stop(f"the ground's STOP ({text})", now)
            return
        n = len(plan.uplink.steps)
        self._stop(f"step {plan.step + 1}/{n}: {text}", now)
        self._end(plan, "failed", f"step {plan.step + 1}/{n}: {text}", now)

    def _foreign_step(self, plan: _Plan, what: str, now: float) -> None:
        """A status that is no fate of the step outstanding: STOP; the plan ends (foreign_step)."""
        n = len(plan.uplink.steps)
        why = f"step {plan.step + 1}/{n}: {what}: a step the plan did not send (foreign_step)"
        plan.status = f"foreign_step: {what}"
        self._stop(why, now)
        self._end(plan, "failed", why, now)

    def on_ground_stop(self, now: float) -> None:
        """``true`` heard on ``emergency_stop``: the core's own STOP heard back (one per
        STOP it sent), else someone else's (the ground's, an operator's)."""
        echoes = self._own_echoes
        while echoes and now - echoes[0] > self.config.echo_window_s:
            echoes.popleft()  # an echo that never came (a copy lost on the way)
        if echoes:
            echoes.popleft()
            self._latched = True
            return
        self._foreign_stop("the ground's STOP (emergency_stop)", now)

    def _latch_unknown(self) -> None:
        """The latch is held and the core did not know it: it is not the core's own."""
        if not self._latched:
            self._latch_own = False
        self._latched = True

    def _foreign_stop(self, reason: str, now: float) -> None:
        """A STOP the core did not send (module docstring, "Running")."""
        self._latched = True
        self._latch_own = False
        self._cancel_floor = max(self._cancel_floor, self._max_taken)
        plan = self._plan
        if plan is not None and plan.state is PlanState.RUNNING:
            self._ground_stop(plan, reason, now)
        elif plan is not None and plan.state is PlanState.ARMED:
            self._ground_stop(plan, f"{reason}, before it started", now)

    def shutdown(self, reason: str, now: float) -> None:
        """The program is ending: a plan armed or running ends (``failed``), with STOP
        when it was running; nobody will run the rest of it."""
        plan = self._plan
        if plan is not None and plan.state is PlanState.RUNNING:
            self._stop(reason, now)
            self._end(plan, "failed", reason, now)
        elif plan is not None and plan.state is PlanState.ARMED:
            self._end(plan, "failed", reason, now)

    def _ground_stop(self, plan: _Plan, reason: str, now: float) -> None:
        self.counts["ground_stops"] += 1
        logger.warning("plan %d ended by %s", plan.uplink.plan_id, reason)
        self._end(plan, "ground_stop", reason, now)

    def on_estimate(self, estimate: Estimate, now: float) -> None:
        """The pose estimate changed (every ``odom`` and POSE): guard, and watch for rest.
        One that is not finite (a broken filter) is no estimate: a running plan stops
        at once (``blind``), and it is neither kept nor reported."""
        plan = self._plan
        if not estimate.finite:
            self.counts["bad_estimates"] += 1
            if plan is not None and plan.state is PlanState.RUNNING:
                self._blind(plan, "the pose estimate is not finite", now)
            return
        self._estimate = estimate
        self._last_estimate_s = now
        if plan is not None and plan.state is PlanState.RUNNING:
            self._seen_start(plan, estimate)
            self._guard(plan, estimate, now)
        if plan is not None and plan.state is PlanState.RUNNING:
            self._sees_ground(plan, estimate, now)
        settling = self._settling
        if settling is not None:
            self._watch_rest(settling, estimate, now)

    def tick(self, now: float) -> None:
        """The passing of time: step timeouts, the armed wait, blindness, rest, reports."""
        cfg = self.config
        plan = self._plan
        if (
            plan is not None
            and plan.state is PlanState.ARMED
            and now >= plan.taken_s + cfg.arm_timeout_s
        ):
            reason = f"the latch was not released within {cfg.arm_timeout_s:g} s"
            self._end(plan, "failed", reason, now)
        if plan is not None and plan.state is PlanState.RUNNING:
            n = len(plan.uplink.steps)
            if now >= self._step_deadline(plan):
                self._stop(f"step {plan.step + 1}/{n} timed out", now)
                self._end(plan, "failed", f"step {plan.step + 1}/{n}: no 'completed' in time", now)
            elif now >= self._last_estimate_s + cfg.blind_s:
                self._blind(plan, f"no pose estimate for {cfg.blind_s:g} s", now)
        if self._stop_sent and now >= self._stop_last_s + cfg.stop_repeat_s:
            self._repeat_stop(now)
        settling = self._settling
        if settling is not None and now >= settling.ended_s + cfg.rest_timeout_s:
            self._rest(settling, self._estimate, now, at_rest=False)
        if now >= self._next_report_s:
            self._report("periodic" if self._last_report is not None else "idle", now)

    def _blind(self, plan: _Plan, why: str, now: float) -> None:
        """STOP: the guard cannot see (outcome ``blind``)."""
        n = len(plan.uplink.steps)
        self.counts["guard_stops"] += 1
        self._stop(f"guard blind: {why}", now)
        self._end(plan, "blind", f"{why} in step {plan.step + 1}/{n}", now)

    # -- the plan ----------------------------------------------------------------------------
    def _start(self, plan: _Plan, now: float) -> None:
        plan.state = PlanState.RUNNING
        self._states[plan.uplink.plan_id] = PlanState.RUNNING
        plan.started = [math.nan] * len(plan.uplink.steps)
        self._last_estimate_s = max(self._last_estimate_s, now)  # blindness counts from here
        self._send_step(plan, 0, now)
        self._report("running", now)

    def _send_step(self, plan: _Plan, index: int, now: float) -> None:
        plan.step = index
        plan.accepted = False
        plan.status = "published"
        plan.published_s = now
        plan.started[index] = now  # until the wheels are seen to move
        plan.moved = False
        plan.still_s = now
        plan.over = 0
        self.counts["steps_sent"] += 1
        self._actions.append(SendStep(plan.uplink.plan_id, index, plan.uplink.steps[index]))

    def _next_step(self, plan: _Plan, now: float) -> None:
        if plan.step + 1 >= len(plan.uplink.steps):
            self._end(plan, "completed", "all steps completed", now)
            return
        self._send_step(plan, plan.step + 1, now)
        self._report("step", now)

    def _step_deadline(self, plan: _Plan) -> float:
        predicted = plan.uplink.durations_s[plan.step] / self.config.time_scale
        return plan.published_s + 1.5 * predicted + self.config.step_margin_s

    def _stop(self, reason: str, now: float) -> None:
        if not self._latched:
            self._latch_own = True  # a latch of someone else's stays theirs
        self._stop_sent = True
        self._stop_reason = reason
        self._stop_copies = 0
        self._latched = True
        self._send_stop(reason, now)

    def _send_stop(self, reason: str, now: float) -> None:
        self._stop_copies += 1
        self._stop_last_s = now
        self._own_echoes.append(now)
        self._actions.append(SendStop(reason))

    def _repeat_stop(self, now: float) -> None:
        """The core's STOP is still unanswered: again, up to ``stop_repeats`` times."""
        cfg = self.config
        if self._stop_copies > cfg.stop_repeats:
            return
        self.counts["stop_repeats"] += 1
        reason = f"{self._stop_reason} (again: no 'stopped' yet)"
        self._send_stop(reason, now)
        if self._stop_copies > cfg.stop_repeats:
            logger.error(
                "the bridge has not answered the core's STOP after %d copies (%s)",
                self._stop_copies,
                self._stop_reason,
            )

    def _end(self, plan: _Plan, outcome: str, reason: str, now: float) -> None:
        plan.state = _ENDS[outcome]
        self._states[plan.uplink.plan_id] = plan.state
        plan.outcome = outcome
        plan.reason = reason
        plan.ended_s = now
        est = self._estimate
        if plan.end_pose is None and est is not None:
            plan.end_pose = Pose(est.x_m, est.y_m, est.yaw_deg)
        if outcome != "completed":
            logger.warning("plan %d ended: %s: %s", plan.uplink.plan_id, outcome, reason)
        plan.still_since = None
        self._settling = plan
        self._report("ended" if outcome != "guard" else "guard_stop", now)
        if est is not None:
            self._watch_rest(plan, est, now)

    # -- the guard ---------------------------------------------------------------------------
    def predicted_at(self, stamp_s: float) -> tuple[int, int, Pose] | None:
        """The running plan's id, the step in force at ``stamp_s`` and the predicted
        pose then, as the guard compares (``None``: no plan runs)."""
        plan = self._plan
        if plan is None or plan.state is not PlanState.RUNNING:
            return None
        step, pose = self._predicted(plan, stamp_s)
        return plan.uplink.plan_id, step, pose

    def _predicted(self, plan: _Plan, stamp_s: float) -> tuple[int, Pose]:
        """The step in force at ``stamp_s`` and the predicted pose then."""
        step = plan.step
        while step > 0 and stamp_s < plan.started[step]:
            step -= 1
        start = plan.started[step]
        if math.isnan(start) or stamp_s < start or (step == plan.step and not plan.moved):
            # Until the wheels are seen to move, the step's prediction waits at its start.
            return step, plan.uplink.pose_at(step, 0.0)
        return step, plan.uplink.pose_at(step, (stamp_s - start) * self.config.time_scale)

    def _moving(self, est: Estimate) -> bool:
        cfg = self.config
        return (
            abs(est.v_mps) >= cfg.rest_speed_mps
            or abs(est.yaw_rate_rad_s) >= cfg.rest_yaw_rate_rad_s
        )

    def _starting(self, plan: _Plan, est: Estimate) -> bool:
        """The estimate moves the way the step out drives, above the start thresholds."""
        cfg = self.config
        command = plan.uplink.steps[plan.step][0]
        sign = _DIRECTION.get(command)
        if sign is None:
            return False
        rate, threshold = (
            (est.yaw_rate_rad_s, cfg.start_yaw_rate_rad_s)
            if command in (Command.LEFT, Command.RIGHT)
            else (est.v_mps, cfg.start_speed_mps)
        )
        return sign * rate >= threshold

    def _seen_start(self, plan: _Plan, est: Estimate) -> None:
        """The step's start: the stamp of the last estimate not moving its way (above
        ``start_speed_mps`` or ``start_yaw_rate_rad_s`` in its direction) before the first
        that does, or its publication if later."""
        if plan.moved or est.stamp_s < plan.published_s:
            return
        if not self._starting(plan, est):
            plan.still_s = max(plan.still_s, est.stamp_s)
            return
        plan.moved = True
        plan.started[plan.step] = max(plan.published_s, plan.still_s)

    def _guard(self, plan: _Plan, est: Estimate, now: float) -> None:
        step, predicted = self._predicted(plan, est.stamp_s)
        linear = math.hypot(est.x_m - predicted.x, est.y_m - predicted.y)
        angular = abs(wrap_deg(est.yaw_deg - predicted.yaw_deg))
        plan.drift = (linear, angular)
        plan.worst = (max(plan.worst[0], linear), max(plan.worst[1], angular))
        limits = plan.uplink.limits
        if linear > limits.linear_m or angular > limits.angular_deg:
            plan.over += 1
        else:
            plan.over = 0
        if plan.over < self.config.persistence:
            return
        self.counts["guard_stops"] += 1
        pose = Pose(est.x_m, est.y_m, est.yaw_deg)
        self._stop(f"drift {linear:.3f} m {angular:.1f} deg in step {step + 1}", now)
        plan.guard = GuardStop(
            step, est.stamp_s, now, pose, predicted, linear, angular, est.pose_age_s
        )
        plan.end_pose = pose
        self._end(plan, "guard", plan.guard.reason, now)

    def _sees_ground(self, plan: _Plan, est: Estimate, now: float) -> None:
        """Drift control needs a sensor that sees the ground (docs/onboard.md): STOP
        (``blind``) when, since the last POSE fix, the estimate moved the plan's linear
        limit (by the samples' stamps, after ``unseen_grace_s``), or the wheels moved for
        ``pose_gap_s``, or the estimate's own 1-sigma position error reached the limit."""
        cfg = self.config
        limit = plan.uplink.limits.linear_m
        if est.unseen_m < limit:
            plan.unseen_since = None
        elif plan.unseen_since is None:
            plan.unseen_since = now
        why = None
        if plan.unseen_since is not None and now - plan.unseen_since >= cfg.unseen_grace_s:
            why = f"{est.unseen_m:.2f} m driven since the last POSE fix"
        elif self._moving(est) and est.pose_age_s > cfg.pose_gap_s:
            why = f"no POSE fix for {est.pose_age_s:.1f} s while moving"
        elif est.sigma_xy_m >= limit:
            why = f"the estimate's position error reached {est.sigma_xy_m:.2f} m"
        if why is not None:
            self._blind(plan, why, now)

    # -- rest --------------------------------------------------------------------------------
    def _watch_rest(self, plan: _Plan, est: Estimate, now: float) -> None:
        cfg = self.config
        still = (
            abs(est.v_mps) < cfg.rest_speed_mps
            and abs(est.yaw_rate_rad_s) < cfg.rest_yaw_rate_rad_s
        )
        if not still:
            plan.still_since = None
            return
        if plan.still_since is None:
            plan.still_since = est.stamp_s
        if est.stamp_s - plan.still_since >= cfg.rest_hold_s:
            self._rest(plan, est, now, at_rest=True)

    def _rest(self, plan: _Plan, est: Estimate | None, now: float, *, at_rest: bool) -> None:
        self._settling = None
        if est is None:
            logger.warning("plan %d: no estimate to report at rest", plan.uplink.plan_id)
            return
        pose = Pose(est.x_m, est.y_m, est.yaw_deg)
        since = plan.end_pose or pose
        t_ref = plan.guard.stamp_s if plan.guard is not None else plan.ended_s
        rest_s = plan.still_since if at_rest and plan.still_since is not None else est.stamp_s
        plan.rest = RestReport(
            rest_s,
            pose,
            est.covariance,
            at_rest,
            math.hypot(pose.x - since.x, pose.y - since.y),
            max(0.0, rest_s - t_ref),
        )
        self._report("rest", now)

    # -- answers and reports -----------------------------------------------------------------
    def _ack(self, ack: UplinkAck) -> None:
        self._actions.append(SendAck(ack))

    def _refuse(self, plan_id: int, reason: str, detail: str, now: float) -> None:
        self.counts["refused"] += 1
        # One line a second per reason at most: junk on the uplink must not flood the log.
        last, quiet = self._refusal_log.get(reason, (-math.inf, 0))
        if now - last >= REFUSAL_LOG_PERIOD_S:
            more = f" ({quiet} more since the last line)" if quiet else ""
            logger.warning("uplink of plan %d refused: %s: %s%s", plan_id, reason, detail, more)
            self._refusal_log[reason] = (now, 0)
        else:
            self._refusal_log[reason] = (last, quiet + 1)
        state = self._states.get(plan_id)
        self._ack(UplinkAck(plan_id, "refused", reason, detail, state.value if state else ""))
        self._actions.append(SayStatus(plan_refused(f"{reason}:{plan_id}")))

    def _report(self, event: str, now: float) -> None:
        plan = self._plan
        self._seq += 1
        if plan is None:
            report = OnboardReport(self._seq, event, now, boot=self.boot)
        else:
            up = plan.uplink
            report = OnboardReport(
                self._seq,
                event,
                now,
                up.plan_id,
                up.verdict,
                plan.state.value,
                plan.step,
                len(up.steps),
                plan.status,
                plan.drift[0] if plan.drift else None,
                plan.drift[1] if plan.drift else None,
                plan.outcome,
                plan.reason,
                plan.guard,
                plan.rest,
                {"worst_linear_m": plan.worst[0], "worst_angular_deg": plan.worst[1]},
                self.boot,
            )
        self._last_report = report
        self._next_report_s = now + self.config.report_period_s
        self._actions.append(SendReport(report))


@dataclass(frozen=True)
class Screened:
    """An uplink after its first, cheap look (:func:`screen_uplink`).

    Attributes:
        body: the authenticated body's text (``""`` when ``error``).
        plan_id: its plan id (a cancel's ``upto``), 0 when none can be read.
        is_plan: the body says it is a plan.
        error: why the envelope or its tag is refused (``None``: it is authentic).
    """

    body: str
    plan_id: int
    is_plan: bool
    error: UplinkError | None = None


def screen_uplink(text: str | bytes, token: str | None) -> Screened:
    """Open an envelope and check its tag; read the body's id and type (pure, cheap)."""
    try:
        body = open_envelope(text, token)
    except UplinkError as exc:
        return Screened("", _peek_id(text), False, exc)
    pid, kind = peek_body(body)
    return Screened(body, pid, kind == "plan")


def decode_screened(
    screened: Screened, rover: RoverDescription
) -> PlanUplink | CancelUplink | UplinkError:
    """The full check of a screened body (pure; the slow step for a large plan)."""
    try:
        return decode_body(screened.body, rover=rover)
    except UplinkError as exc:
        return exc


def _peek_id(text: str | bytes) -> int:
    """The plan id of an envelope that was refused, if it can be read at all (0: not)."""
    import json  # noqa: PLC0415 - only for a refusal

    try:
        env = json.loads(text)
        body = env["body"]
    except (ValueError, TypeError, KeyError, RecursionError):
        return 0
    return peek_body(body)[0] if isinstance(body, str) else 0
