"""Link emulation: a relay between the ground's topics and the rover's, with the
Earth-Moon link's delay, jitter and loss (the thesis's latency injection;
docs/ground.md "Link emulation").

:class:`LinkRelay` republishes every message of each route (:data:`DEFAULT_ROUTES`:
commands, STOP, clear and the uplink down; statuses, telemetry and onboard reports up;
relative names) on the other side after ``one_way_delay_s`` plus jitter, unless the loss
draw drops it. One topic's messages keep their order. Each route draws from a generator
seeded from ``seed`` and the topic name, so a run is reproducible whatever the
interleaving. One scheduler thread releases messages when due; ``close()`` drops what is
in flight and joins it. With a lockstep clock (docs/sim.md) there is no thread: each
tick releases what is due. Between two DDS ports the messages pass as the bytes they
came as, never turned into Python messages and back (:attr:`LinkRelay.serialized`).
"""

from __future__ import annotations

import heapq
import itertools
import logging
import random
import threading
import time
from collections import Counter
from dataclasses import dataclass
from types import TracebackType
from typing import Any

from bridge.ros.rosport import DEFAULT_LANE, STOP_LANE, Publisher, Qos, RosPort, Subscription, qos
from bridge.ros.rosport.contract import (
    CLEAR_EMERGENCY_STOP,
    COMMAND_STATUS,
    EMERGENCY_STOP,
    ONBOARD_POSE,
    ONBOARD_REPORT,
    PLAN_ACK,
    PLAN_UPLINK,
    WHEEL_INSTRUCTIONS,
)
from bridge.ros.rosport.msgs import Bool, DiagnosticArray, Empty, Int16MultiArray, Odometry, String
from firmware_proto.linkio.clock import WALL, Clock, LockstepClock

__all__ = ["DEFAULT_ROUTES", "LinkProfile", "LinkRelay", "RelayedTopic"]

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class LinkProfile:
    """The link: one-way delay and jitter (wall seconds; jitter uniform in ``[0, jitter_s]``
    added to the delay), loss ratio, seed. A 3 s round trip is ``one_way_delay_s = 1.5``."""

    one_way_delay_s: float = 1.5
    jitter_s: float = 0.0
    loss: float = 0.0
    seed: int = 0

    def __post_init__(self) -> None:
        if not (0.0 <= self.one_way_delay_s <= 600.0 and 0.0 <= self.jitter_s <= 600.0):
            raise ValueError("delay and jitter must be in 0..600 s")
        if not 0.0 <= self.loss < 1.0:
            raise ValueError("loss must be in [0, 1)")

    @property
    def rtt_s(self) -> float:
        """Nominal round trip (no jitter), s."""
        return 2.0 * self.one_way_delay_s


@dataclass(frozen=True)
class RelayedTopic:
    """One relayed topic: name (relative), message type, direction, QoS (republished
    with ``qos``, taken with ``subscribe_qos`` when given, else ``qos``) and the lane its
    subscription delivers on (:data:`~bridge.ros.rosport.STOP_LANE` for the emergency stop,
    so it never waits behind another topic's callback)."""

    topic: str
    msg_type: type[Any]
    uplink: bool  # ground -> rover
    qos: Qos = qos.DEFAULT
    subscribe_qos: Qos | None = None
    lane: str = DEFAULT_LANE


DEFAULT_ROUTES: tuple[RelayedTopic, ...] = (
    RelayedTopic(WHEEL_INSTRUCTIONS, Int16MultiArray, True, qos.COMMAND),
    RelayedTopic(EMERGENCY_STOP, Bool, True, qos.STOP, lane=STOP_LANE),
    RelayedTopic(CLEAR_EMERGENCY_STOP, Empty, True, qos.STOP, lane=STOP_LANE),
    RelayedTopic(COMMAND_STATUS, String, False, qos.STATUS),
    RelayedTopic("odom", Odometry, False, qos.TELEMETRY, qos.SENSOR),
    RelayedTopic("odom_ground", Odometry, False, qos.TELEMETRY, qos.SENSOR),
    RelayedTopic("diagnostics", DiagnosticArray, False, qos.DIAGNOSTICS),
    # the onboard sequencer's (docs/onboard.md): the uplink, its answers, its reports
    RelayedTopic(PLAN_UPLINK, String, True, qos.COMMAND),
    RelayedTopic(PLAN_ACK, String, False, qos.STATUS),
    RelayedTopic(ONBOARD_REPORT, String, False, qos.STATUS),
    RelayedTopic(ONBOARD_POSE, Odometry, False, qos.TELEMETRY, qos.SENSOR),
)


class LinkRelay:
    """Relays :data:`DEFAULT_ROUTES` between a ground port and a rover port."""

    def __init__(
        self,
        ground: RosPort,
        rover: RosPort,
        profile: LinkProfile | None = None,
        routes: tuple[RelayedTopic, ...] = DEFAULT_ROUTES,
        *,
        clock: Clock = WALL,
    ) -> None:
        """``ground``: the operator side's port (its namespace applies to ground topics);
        ``clock``: what the delays run on (lockstep: released on its ticks, no thread)."""
        self.profile = profile or LinkProfile()
        self.clock = clock
        self._stepping = clock if isinstance(clock, LockstepClock) else None
        self.received = 0
        """Messages taken from either side so far (relayed, queued or dropped)."""
        self.forwarded: Counter[str] = Counter()
        self.dropped: Counter[str] = Counter()
        self._heap: list[tuple[float, int, Publisher[Any], Any, str]] = []
        self._order = itertools.count()
        self._cond = threading.Condition()
        self._closed = False
        self._last_due: dict[str, float] = {}
        self._subs: list[Subscription[Any]] = []
        self._publishers: list[Publisher[Any]] = []
        # Over DDS both ways, the bytes pass as they came (no Python message in between:
        # docs/rosport.md, "Serialized messages"); the in-process backend carries messages.
        self.serialized = ground.carries_serialized and rover.carries_serialized
        for route in routes:
            src, dst = (ground, rover) if route.uplink else (rover, ground)
            publisher = dst.publisher(route.topic, route.msg_type, route.qos)
            self._publishers.append(publisher)
            rng = random.Random(f"{self.profile.seed}:{route.topic}:{route.uplink}")
            self._subs.append(
                src.subscribe(
                    route.topic,
                    route.msg_type,
                    self._make_forward(route, publisher, rng),
                    route.subscribe_qos or route.qos,
                    lane=route.lane,
                    serialized=self.serialized,
                )
            )
        self._thread: threading.Thread | None = None
        if self._stepping is not None:
            self._stepping.add(self._release_due)
        else:
            self._thread = threading.Thread(target=self._run, name="link-relay", daemon=True)
            self._thread.start()

    def _make_forward(
        self, route: RelayedTopic, publisher: Publisher[Any], rng: random.Random
    ) -> Any:
        key = f"{'up' if route.uplink else 'down'}:{route.topic}"
        profile = self.profile

        def forward(msg: Any) -> None:
            self.received += 1
            if profile.loss and rng.random() < profile.loss:
                self.dropped[key] += 1
                return
            delay = profile.one_way_delay_s + (
                rng.uniform(0.0, profile.jitter_s) if profile.jitter_s else 0.0
            )
            with self._cond:
                if self._closed:
                    return
                due = max(self.clock.now() + delay, self._last_due.get(key, 0.0))  # in order
                self._last_due[key] = due
                entry = (due, next(self._order), publisher, msg, key)
                heapq.heappush(self._heap, entry)
                if self._heap[0] is entry:  # due first: the thread's wait must end sooner
                    self._cond.notify()

        return forward

    def _release_due(self) -> None:
        """Lockstep: publish every message due by now, in the order due."""
        now = self.clock.now()
        while True:
            with self._cond:
                if self._closed or not self._heap or self._heap[0][0] > now:
                    return
                _, _, publisher, msg, key = heapq.heappop(self._heap)
            self._publish(publisher, msg, key)

    def _publish(self, publisher: Publisher[Any], msg: Any, key: str) -> None:
        try:
            if self.serialized:
                publisher.publish_serialized(msg)
            else:
                publisher.publish(msg)
            self.forwarded[key] += 1
        except Exception:
            logger.exception("relay could not forward %s", key)

    def _run(self) -> None:
        while True:
            with self._cond:
                while not self._closed and (not self._heap or self._heap[0][0] > time.monotonic()):
                    timeout = self._heap[0][0] - time.monotonic() if self._heap else None
                    self._cond.wait(timeout)
                if self._closed:
                    return
                _, _, publisher, msg, key = heapq.heappop(self._heap)
            self._publish(publisher, msg, key)

    def wait_until_matched(self, timeout_s: float = 10.0, topics: set[str] | None = None) -> bool:
        """Wait until each route (of ``topics``, default all) is matched both ways, each
        seen from its own end (a sample sent before both ends discovered each other is
        lost); False when ``timeout_s`` passed first."""
        clock = self.clock
        deadline = clock.now() + timeout_s

        def wanted(topic: str) -> bool:
            return topics is None or topic.rsplit("/", 1)[-1] in topics

        for sub in self._subs:
            if wanted(sub.topic) and not sub.wait_for_publishers(
                1, max(0.0, deadline - clock.now())
            ):
                return False
        for pub in self._publishers:
            if wanted(pub.topic) and not pub.wait_for_subscribers(
                1, max(0.0, deadline - clock.now())
            ):
                return False
        return True

    @property
    def in_flight(self) -> int:
        """Messages waiting for their delay to pass."""
        with self._cond:
            return len(self._heap)

    def close(self) -> None:
        """Stop relaying; messages in flight are lost (idempotent)."""
        for sub in self._subs:
            sub.close()
        with self._cond:
            self._closed = True
            self._heap.clear()
            self._cond.notify_all()
        if self._stepping is not None:
            self._stepping.remove(self._release_due)
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=5.0)

    def __enter__(self) -> LinkRelay:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
