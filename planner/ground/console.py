"""The operator's console: read the rover's state, stop it and release its latch over
ROS 2, through the bridge's topics (``rover status``, ``rover stop``, ``rover
clear-stop``, ``rover echo``; no ros2cli needed).

:class:`RoverConsole` sits on an open :class:`~bridge.ros.rosport.RosPort` in the namespace
of the topics it talks to: the ground's (through the link relay, as ``rover go`` does)
or the rover's own (the bridge's). It subscribes to ``diagnostics`` and
``command_status`` and publishes on ``emergency_stop`` and ``clear_emergency_stop``.
Every wait has a timeout and ends at :meth:`RoverConsole.close`; a discovery that has
not matched both sides in time is said, not assumed.
"""

from __future__ import annotations

import enum
import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

from bridge.ros.rosport import RosPort, qos
from bridge.ros.rosport.contract import (
    CLEAR_EMERGENCY_STOP,
    CLEARED,
    COMMAND_STATUS,
    EMERGENCY_STOP,
    ONBOARD_REPORT,
    STOPPED,
    fault,
)
from bridge.ros.rosport.msgs import Bool, DiagnosticArray, Empty, String
from firmware_proto.model.downlink import OnboardReport, decode_report
from planner.ground.roverstatus import RoverStatus, from_diagnostics

__all__ = ["DIAGNOSTICS", "STOP_REPEAT_S", "ClearOutcome", "ClearReport", "RoverConsole"]

logger = logging.getLogger(__name__)

DIAGNOSTICS = "diagnostics"
"""Relative: ``/diagnostics`` at the root (the bridge's), ``/ground/diagnostics`` as relayed."""
_FAULT_PERSISTS = fault("fault_persists")
_LATCH_CHANGED = fault("latch_changed")
STOP_REPEAT_S = 0.5
"""``rover stop`` publishes STOP again this often until ``stopped`` comes back."""
_CANCEL_POLL_S = 0.1
"""A wait given a ``cancel`` event notices it within this long."""


class ClearOutcome(str, enum.Enum):
    """What became of a clear-STOP."""

    RELEASED = "released"
    """The latch was set and the controller released it (``cleared``)."""
    NOT_LATCHED = "not_latched"
    """Nothing held the rover; the controller said so (``cleared``)."""
    FAULT_PERSISTS = "fault_persists"
    """A stopping fault's condition is still active: the latch holds; clear again once it ends."""
    LATCH_CHANGED = "latch_changed"
    """The latch gained a cause since the bridge last reported it: it holds; check, clear again."""
    NO_ANSWER = "no_answer"
    """Nothing came back in time (see :attr:`ClearReport.why`)."""


@dataclass(frozen=True)
class ClearReport:
    """The outcome, the rover's state before and after (``None``: not heard), and why
    it did not release, in words."""

    outcome: ClearOutcome
    before: RoverStatus | None
    after: RoverStatus | None
    why: str = ""
    armed: str = ""
    """A sentence saying that the plan waiting armed on board starts now (``""``: none was)."""

    @property
    def released(self) -> bool:
        """The rover is free to take steps as far as the latch goes."""
        return self.outcome in (ClearOutcome.RELEASED, ClearOutcome.NOT_LATCHED)


class RoverConsole:
    """The operator's reads and writes of the bridge's topics, on ``port`` (open, in the
    topics' namespace; not closed here); ``on_status`` is called with each
    ``command_status`` string heard, on the port's thread."""

    def __init__(self, port: RosPort, on_status: Callable[[str], None] | None = None) -> None:
        self.port = port
        self._lock = threading.Condition()
        self._diagnostics: RoverStatus | None = None
        self._diag_count = 0
        self._diag_at = time.monotonic()
        self._statuses: deque[tuple[int, str]] = deque(maxlen=200)
        self._status_count = 0
        self._on_status = on_status
        self._diag_sub = port.subscribe(
            DIAGNOSTICS, DiagnosticArray, self._on_diag, qos.DIAGNOSTICS
        )
        self._status_sub = port.subscribe(COMMAND_STATUS, String, self._on_text, qos.STATUS)
        self._onboard: OnboardReport | None = None
        self._report_sub = port.subscribe(ONBOARD_REPORT, String, self._on_report, qos.STATUS)
        self._estop = port.publisher(EMERGENCY_STOP, Bool, qos.STOP)
        self._clear = port.publisher(CLEAR_EMERGENCY_STOP, Empty, qos.STOP)
        self._listeners: list[Callable[[], None]] = []
        self._closed = False

    def add_listener(self, listener: Callable[[], None]) -> None:
        """Call ``listener()`` after every ``/diagnostics``, ``command_status`` and
        onboard report taken (on the port's thread: it must not block; one that raises
        is logged and the others are still called)."""
        with self._lock:
            self._listeners.append(listener)

    def remove_listener(self, listener: Callable[[], None]) -> None:
        """Stop calling ``listener`` (no error when it is not there)."""
        with self._lock:
            if listener in self._listeners:
                self._listeners.remove(listener)

    def _changed(self) -> None:
        with self._lock:
            listeners = list(self._listeners)
        for listener in listeners:
            try:
                listener()
            except Exception:
                logger.exception("console: a listener failed")

    # -- what comes in ------------------------------------------------------------------
    def _on_diag(self, msg: DiagnosticArray) -> None:
        try:
            status = from_diagnostics(msg)
        except ValueError:
            return  # another node's diagnostics on the same topic
        with self._lock:
            self._diagnostics = status
            self._diag_count += 1
            self._diag_at = time.monotonic()
            self._lock.notify_all()
        self._changed()

    def _on_text(self, msg: String) -> None:
        with self._lock:
            self._status_count += 1
            self._statuses.append((self._status_count, msg.data))
            self._lock.notify_all()
        self._changed()
        if self._on_status is not None:
            self._on_status(msg.data)

    def _on_report(self, msg: String) -> None:
        try:
            report = decode_report(msg.data)
        except ValueError:
            return
        with self._lock:
            known = self._onboard
            # seq counts within one boot of the onboard program: a new boot starts over
            if known is None or report.seq >= known.seq or report.boot != known.boot:
                self._onboard = report
        self._changed()

    @property
    def onboard(self) -> OnboardReport | None:
        """The latest report of the plan on board (``rover onboard`` repeats it every
        second), ``None`` when none was heard."""
        with self._lock:
            return self._onboard

    @property
    def heard(self) -> tuple[str, ...]:
        """Every ``command_status`` heard so far (the last 200), oldest first."""
        with self._lock:
            return tuple(text for _, text in self._statuses)

    def topic(self, name: str) -> str:
        """The fully qualified name of one of the console's topics."""
        return self.port.resolve(name)

    def status(
        self, timeout_s: float, *, newer_than: int = 0, cancel: threading.Event | None = None
    ) -> RoverStatus | None:
        """The next ``/diagnostics`` of the bridge after the ``newer_than``-th, waiting
        at most ``timeout_s`` (or until ``cancel`` is set: within 0.1 s); ``None`` when
        none came."""
        deadline = time.monotonic() + timeout_s
        with self._lock:
            while self._diag_count <= newer_than:
                left = deadline - time.monotonic()
                if left <= 0 or self._closed or (cancel is not None and cancel.is_set()):
                    return None
                self._lock.wait(left if cancel is None else min(left, _CANCEL_POLL_S))
            assert self._diagnostics is not None
            return self._diagnostics

    @property
    def diagnostics_seen(self) -> int:
        """How many of the bridge's ``/diagnostics`` came so far."""
        with self._lock:
            return self._diag_count

    @property
    def diagnostics_age_s(self) -> float:
        """Seconds since the latest ``/diagnostics`` came (monotonic)."""
        with self._lock:
            return time.monotonic() - self._diag_at

    def latest(self) -> RoverStatus | None:
        """The bridge's latest ``/diagnostics`` (``None``: none yet); never waits."""
        with self._lock:
            return self._diagnostics

    def mark(self) -> int:
        """How many ``command_status`` were heard so far: what :meth:`heard_since` counts from."""
        with self._lock:
            return self._status_count

    def heard_since(self, since: int, wanted: Callable[[str], bool]) -> str | None:
        """The first status heard after the ``since``-th (:meth:`mark`) that ``wanted``
        accepts, ``None`` when none was (of the last 200 kept); never waits."""
        with self._lock:
            return next((s for i, s in self._statuses if i > since and wanted(s)), None)

    def _wait_status(
        self,
        wanted: Callable[[str], bool],
        since: int,
        deadline: float,
        cancel: threading.Event | None = None,
    ) -> str | None:
        """The first status after the ``since``-th that ``wanted`` accepts, until
        ``deadline`` (monotonic), :meth:`close` or ``cancel``."""
        with self._lock:
            while True:
                hit = next((s for i, s in self._statuses if i > since and wanted(s)), None)
                if hit is not None:
                    return hit
                left = deadline - time.monotonic()
                if left <= 0 or self._closed or (cancel is not None and cancel.is_set()):
                    return None
                self._lock.wait(min(left, _CANCEL_POLL_S))

    def wait_matched(self, timeout_s: float) -> bool:
        """Wait until the publishers have a subscriber and the status subscription a
        publisher (a relay or the bridge), each side as DDS sees it."""
        deadline = time.monotonic() + timeout_s
        return all(
            endpoint(1, max(0.0, deadline - time.monotonic()))
            for endpoint in (
                self._estop.wait_for_subscribers,
                self._clear.wait_for_subscribers,
                self._status_sub.wait_for_publishers,
            )
        )

    # -- what goes out --------------------------------------------------------------------
    def publish_stop(self) -> None:
        """Publish ``true`` on ``emergency_stop`` once; never waits (the message is
        handed to the middleware, as any publish).

        Raises:
            RosPortError: the port failed to send it, or is closed.
        """
        self._estop.publish(Bool(data=True))

    def stop(self, timeout_s: float) -> bool:
        """Emergency stop: ``true`` on ``emergency_stop``, repeated every 0.5 s until the
        bridge says ``stopped`` (the controller acknowledged it) or ``timeout_s`` passes.
        Returns whether ``stopped`` came back."""
        deadline = time.monotonic() + timeout_s
        with self._lock:
            since = self._status_count
        while True:
            self.publish_stop()
            left = deadline - time.monotonic()
            if left <= 0:
                return False
            hit = self._wait_status(
                lambda s: s == STOPPED, since, time.monotonic() + min(left, STOP_REPEAT_S)
            )
            if hit is not None:
                return True

    def clear_stop(
        self,
        timeout_s: float,
        *,
        after_wait_s: float = 3.0,
        cancel: threading.Event | None = None,
    ) -> ClearReport:
        """Ask the bridge to release the controller's latch and say what became of it.

        Waits for the bridge's state (at most a third of ``timeout_s``), publishes on
        ``clear_emergency_stop``, waits for ``cleared`` or ``fault:fault_persists`` until
        ``timeout_s``, then up to ``after_wait_s`` for the next ``/diagnostics`` (the
        state after; ``None`` when late).
        """
        start = time.monotonic()
        deadline = start + timeout_s
        before = self.status(timeout_s / 3.0, cancel=cancel)
        with self._lock:
            since, seen = self._status_count, self._diag_count
            plan = self._onboard
        armed = (
            f"plan {plan.plan_id} was armed on board (it waited for this release) and starts now"
            if plan is not None and plan.state == "armed"
            else ""
        )
        self._clear.publish(Empty())
        answer = self._wait_status(
            lambda s: s in (CLEARED, _FAULT_PERSISTS, _LATCH_CHANGED), since, deadline, cancel
        )
        after = self.status(
            max(0.0, min(deadline - time.monotonic(), after_wait_s)),
            newer_than=seen,
            cancel=cancel,
        )
        if answer == CLEARED:
            latched = before is None or before.latched
            outcome = ClearOutcome.RELEASED if latched else ClearOutcome.NOT_LATCHED
            return ClearReport(outcome, before, after, armed=armed)
        state = after or before
        if answer == _FAULT_PERSISTS:
            faults = ", ".join(state.stopping_faults) if state is not None else ""
            why = (
                f"fault condition {faults} is still active"
                if faults
                else "a stopping fault's condition is still active"
            ) + "; clear again once it is gone"
            return ClearReport(ClearOutcome.FAULT_PERSISTS, before, after, why)
        if answer == _LATCH_CHANGED:
            causes = ", ".join(state.latch) if state is not None and state.latch else ""
            why = (
                "the latch gained a cause after the bridge last reported it"
                + (f" (now held by {causes})" if causes else "")
                + "; see what holds it and clear again"
            )
            return ClearReport(ClearOutcome.LATCH_CHANGED, before, after, why)
        if state is None:
            why = (
                f"no answer on {self.topic(COMMAND_STATUS)} and no {self.topic(DIAGNOSTICS)} "
                f"within {timeout_s:g} s: is a bridge running (and the link relaying) on this "
                "ROS domain?"
            )
        elif state.link_state != "ready":
            why = state.why_held()[0]
        else:
            why = f"no answer on {self.topic(COMMAND_STATUS)} within {timeout_s:g} s"
        return ClearReport(ClearOutcome.NO_ANSWER, before, after, why)

    def close(self) -> None:
        """Close the console's endpoints and end every wait under way at once (it
        returns as if nothing came); idempotent; the port stays open."""
        with self._lock:
            self._closed = True
            self._listeners.clear()
            self._lock.notify_all()
        for endpoint in (
            self._diag_sub,
            self._status_sub,
            self._report_sub,
            self._estop,
            self._clear,
        ):
            endpoint.close()

    def __enter__(self) -> RoverConsole:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
