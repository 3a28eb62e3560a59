"""The live view's state and its fan-out to browsers.

:class:`ViewHub` is fed by the ground station (``tap``, ``planned``, ``progress``,
``event``, any thread); feeding never blocks: an append to a bounded, drop-oldest queue
(:data:`INBOX_LEN`). One hub thread (``view-hub``) turns inputs into events, keeps the
state, and adds a ``tick`` every :data:`TICK_S`. Each event is encoded once and put on
every client's :class:`ClientQueue` (bounded, drop-oldest), so a slow browser never
holds up the hub or the mission; a new client gets ``hello`` (the state) first. Events:
docs/view.md "The push channel".

The ghost follows the prediction of the verdict each progress report names
(:attr:`~planner.ground.executor.ExecutionProgress.verdict`), and halts when its step
ends other than ``completed`` or a STOP is sent, until the next step is published.
"""

from __future__ import annotations

import json
import logging
import math
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from firmware_proto.model.downlink import decode_report
from firmware_proto.model.geometry import wrap_deg
from firmware_proto.model.pose import Pose
from firmware_proto.model.uplink import decode_ack
from firmware_proto.model.verdict import Verdict
from firmware_proto.model.worldmap import WorldMap
from planner.ground.executor import ExecutionProgress
from planner.plan.orchestrator import MissionResult

__all__ = [
    "INBOX_LEN",
    "PATH_STEP_M",
    "PLANS_KEPT",
    "QUEUE_LEN",
    "TICK_S",
    "TRAIL_LEN",
    "ClientQueue",
    "ViewHub",
    "ViewLimits",
]

logger = logging.getLogger(__name__)

TICK_S = 0.1
"""Period of the ``tick`` event, s: at least 10 updates a second."""
QUEUE_LEN = 256
"""Records a client may have waiting before its oldest are dropped."""
INBOX_LEN = 10_000
"""Inputs the hub may have waiting before its oldest are dropped."""
TRAIL_LEN = 5000
"""Points of each pose's trail kept for a page that opens later (1 cm apart)."""
PLANS_KEPT = 64
"""Attempts kept for a page that opens later, oldest out first: a bound of the state's size."""
PATH_STEP_M = 0.01
"""Least spacing of a plan's drawn path, m (and the last sample): its length bounds its points."""
_ENDS_BADLY = ("fault:", "aborted:", "rejected:")


class ClientQueue:
    """One browser's records: bounded, drop-oldest; :meth:`take` waits with a timeout."""

    def __init__(self, maxlen: int = QUEUE_LEN) -> None:
        self._items: deque[bytes] = deque()
        self._maxlen = maxlen
        self._cond = threading.Condition()
        self.dropped = 0
        self.closed = False

    def put(self, record: bytes) -> None:
        """Add a record; drop the oldest when full. Never blocks on the reader."""
        with self._cond:
            if len(self._items) >= self._maxlen:
                self._items.popleft()
                self.dropped += 1
            self._items.append(record)
            self._cond.notify()

    def take(self, timeout_s: float) -> list[bytes]:
        """Every waiting record, waiting at most ``timeout_s`` for one; ``[]`` on
        timeout or once closed."""
        with self._cond:
            if not self._items and not self.closed:
                self._cond.wait(timeout_s)
            items = list(self._items)
            self._items.clear()
            return items

    def close(self) -> None:
        """Wake the reader; it sends no more."""
        with self._cond:
            self.closed = True
            self._cond.notify_all()


@dataclass(frozen=True)
class ViewLimits:
    """What the page shows the drift against (the executor's thresholds)."""

    drift_linear_m: float = 0.25
    drift_angular_deg: float = 12.0


def _json(data: Any) -> str:
    return json.dumps(data, separators=(",", ":"))


def _record(name: str, data: dict[str, Any]) -> bytes:
    return f"event: {name}\ndata: {_json(data)}\n\n".encode()


def _thin(points: list[list[float]], step_m: float) -> list[list[float]]:
    """``points`` less those within ``step_m`` of the last one kept (the last always kept)."""
    kept: list[list[float]] = []
    for i, p in enumerate(points):
        if (
            not kept
            or i == len(points) - 1
            or math.hypot(p[0] - kept[-1][0], p[1] - kept[-1][1]) >= step_m
        ):
            kept.append(p)
    return kept


def _map_json(world: WorldMap) -> dict[str, Any]:
    b = world.bounds
    return {
        "name": world.name,
        "bounds": [b.min_x, b.min_y, b.max_x, b.max_y],
        "obstacles": [
            {"id": o.id, "kind": o.kind, "points": [list(p) for p in o.points], "r": o.radius_m}
            for o in world.obstacles
        ],
        "traction": [
            {"id": r.id, "polygon": [list(p) for p in r.polygon], "mu_scale": r.mu_scale}
            for r in world.traction_regions
        ],
        "start": [world.start.x, world.start.y, world.start.yaw_deg],
    }


def _plan_json(planning: int, index: int, repair: str, verdict: Verdict) -> dict[str, Any]:
    c = verdict.collision
    return {
        "planning": planning,
        "attempt": index,
        "repair": repair,
        "approved": verdict.approved,
        "summary": verdict.summary(),
        "path": _thin(
            [[round(s.pose.x, 4), round(s.pose.y, 4)] for s in verdict.trajectory.samples],
            PATH_STEP_M,
        ),
        "collision": None if c is None else [c.contact[0], c.contact[1]],
        # With the gate's uncertainty: where the samples are (the level's ellipses along
        # each step: x, y, semi-axes m, angle deg) and how many of them collided.
        "envelope": [
            [p.pose.x, p.pose.y, p.major_m, p.minor_m, p.angle_deg]
            for p in (verdict.uncertainty.envelope if verdict.uncertainty else ())
        ],
        "collision_p": (verdict.uncertainty.collision_probability if verdict.uncertainty else None),
    }


def _pose_of(msg: Any) -> tuple[Pose, float]:
    p = msg.pose.pose
    q = p.orientation
    yaw = math.degrees(math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y**2 + q.z**2)))
    stamp = float(msg.header.stamp.sec) + float(msg.header.stamp.nanosec) * 1e-9
    return Pose(p.position.x, p.position.y, yaw), stamp


class ViewHub:
    """The view's state and its clients. :meth:`start` the hub thread, :meth:`close`
    it (idempotent).

    Args:
        world: the map to draw.
        rtt_s: the link's configured round trip, wall s.
        time_scale: twin seconds per wall second (to move the ghost along its prediction).
        drift_source: returns the latest drift sample ``(m, deg)`` of the running plan
            (``PlanExecutor.latest_drift``), or ``None``.
        limits: the drift thresholds shown.
        queue_len: see :class:`ClientQueue`.
        clock: wall seconds (``time.time``; with its own, a test drives :meth:`pump`).
    """

    def __init__(
        self,
        world: WorldMap,
        *,
        rtt_s: float = 3.0,
        time_scale: float = 1.0,
        drift_source: Callable[[], tuple[float, float] | None] | None = None,
        limits: ViewLimits | None = None,
        queue_len: int = QUEUE_LEN,
        clock: Callable[[], float] = time.time,
    ) -> None:
        self.world = world
        self._clock = clock
        self.rtt_s = rtt_s
        self.time_scale = time_scale
        self.limits = limits or ViewLimits()
        self._drift_source = drift_source
        self._queue_len = queue_len
        # Bounded too: a hub that cannot keep up drops the oldest input, never grows.
        self._inbox: deque[tuple[str, float, Any]] = deque(maxlen=INBOX_LEN)
        self._inbox_cond = threading.Condition()
        self.dropped_inputs = 0
        """Inputs dropped because the hub fell :data:`INBOX_LEN` behind."""
        self._lock = threading.Lock()  # clients and the snapshot
        self._joined = threading.Condition(self._lock)
        self._clients: set[ClientQueue] = set()
        self._thread: threading.Thread | None = None
        self._closed = False
        # State, touched by the hub thread only (the snapshot under the lock).
        self._plans: deque[dict[str, Any]] = deque(maxlen=PLANS_KEPT)
        self._plans_json: deque[str] = deque(maxlen=PLANS_KEPT)  # each encoded once
        self._plannings = 0
        self._ghosts: list[Verdict] = []  # approved, in order of execution
        self._following: Verdict | None = None
        """The verdict of the plan whose step runs now (the ghost's prediction)."""
        self._poses: dict[str, dict[str, Any]] = {}
        self._odom_anchor: tuple[Pose, Pose] | None = None
        self._last_odom: Pose | None = None
        self._step_sent: float | None = None
        self._step_started: float | None = None
        self._step_index = 0
        self._step_sent_for: float | None = None
        """When a step was last sent from the ground (step by step; ``None``: never)."""
        self._moved_at = -math.inf
        """When the progress last moved to another plan or step."""
        self._rtt_measured: float | None = None
        self._progress: dict[str, Any] = {}
        self._status = ""
        self._latched = False
        self._replan_approved = False
        self._stop_source = ""
        self._log: deque[str] = deque(maxlen=50)
        self._trails: dict[str, deque[list[float]]] = {
            "reported": deque(maxlen=TRAIL_LEN),
            "odom": deque(maxlen=TRAIL_LEN),
        }
        self._trails_json: dict[str, deque[str]] = {  # each point encoded once
            "reported": deque(maxlen=TRAIL_LEN),
            "odom": deque(maxlen=TRAIL_LEN),
        }
        self._map_json = _json(_map_json(world))
        self._version = 0  # bumped under the lock with every event
        self._state_json: tuple[int, float, bytes] | None = None  # version, time, bytes
        self._stops: list[dict[str, Any]] = []
        self._onboard: dict[str, Any] | None = None
        """The latest report of the plan on board (docs/onboard.md)."""
        self._onboard_seen: set[tuple[Any, ...]] = set()
        self._goal: list[float] | None = None
        self._result: dict[str, Any] | None = None
        self._halted: tuple[float, float, float] | None = None
        """The ghost's pose, frozen, while the step it followed ended badly."""
        self._last_ghost: tuple[float, float, float] | None = None
        self.records = 0
        """Events encoded so far."""

    # -- feeding (any thread; never blocks) ---------------------------------------------------
    def tap(self, direction: str, topic: str, msg: Any) -> None:
        """A :data:`bridge.ros.rosport.Tap` of the ground station's port."""
        self._put(topic.rsplit("/", 1)[-1], msg)

    def planned(self, mission: MissionResult) -> None:
        """A planning was judged (``MissionRunner.on_planned``)."""
        self._put("_planned", mission)

    def progress(self, p: ExecutionProgress) -> None:
        """The executor's progress (``on_progress``)."""
        self._put("_progress", p)

    def event(self, line: str) -> None:
        """One line of the mission's log."""
        self._put("_log", line)

    def stop_requested(self, source: str) -> None:
        """The operator asked for STOP (``source``: ``view``, ``signal``)."""
        self._put("_stop", source)

    def result(self, ok: bool, text: str) -> None:
        """The mission's outcome, for the banner (``REACHED``, ``NOT REACHED (why)``)."""
        self._put("_result", (ok, text))

    def _put(self, kind: str, payload: Any) -> None:
        if self._closed:
            return
        with self._inbox_cond:
            if len(self._inbox) == INBOX_LEN:
                self.dropped_inputs += 1
            self._inbox.append((kind, self._clock(), payload))
            self._inbox_cond.notify()

    # -- clients ------------------------------------------------------------------------------
    def subscribe(self) -> ClientQueue:
        """A new client's queue, the state first (``hello``)."""
        client = ClientQueue(self._queue_len)
        with self._lock:
            client.put(b"event: hello\ndata: " + self._encoded_state(0.0) + b"\n\n")
            self._clients.add(client)
            self._joined.notify_all()
        return client

    def wait_for_client(self, timeout_s: float) -> bool:
        """Wait until a client is connected; False when ``timeout_s`` passed first."""
        with self._joined:
            return self._joined.wait_for(lambda: bool(self._clients), timeout_s)

    def unsubscribe(self, client: ClientQueue) -> None:
        """Forget a client (its connection ended)."""
        client.close()
        with self._lock:
            self._clients.discard(client)

    @property
    def clients(self) -> int:
        """Connected clients."""
        with self._lock:
            return len(self._clients)

    def clear_allowed(self) -> tuple[bool, str]:
        """Whether releasing the STOP latch is allowed now, and why not: only while
        latched and after a re-plan was approved since the last STOP."""
        with self._lock:
            if not self._latched:
                return False, "the rover is not latched"
            if not self._replan_approved:
                return False, "no re-plan has been approved since the STOP"
            return True, ""

    def state(self) -> dict[str, Any]:
        """The state a new client starts from (``GET /state``)."""
        with self._lock:
            return self._snapshot()

    def state_json(self, max_age_s: float = 0.0) -> bytes:
        """:meth:`state` as JSON bytes, shared by every caller: the last encoding is
        returned again while nothing changed or while it is younger than ``max_age_s``
        (at most one encoding per ``max_age_s``). Bounded: :data:`TRAIL_LEN` points per
        trail, :data:`PLANS_KEPT` attempts, paths thinned to :data:`PATH_STEP_M`. Any
        thread; joins pieces each encoded once."""
        with self._lock:
            return self._encoded_state(max_age_s)

    def _encoded_state(self, max_age_s: float) -> bytes:
        """The state's JSON (lock held); see :meth:`state_json`."""
        now = time.monotonic()
        cached = self._state_json
        if cached is not None and (cached[0] == self._version or now - cached[1] < max_age_s):
            return cached[2]
        small = self._snapshot(pieces=False)
        trails = ",".join(
            f'"{name}":[{",".join(points)}]' for name, points in self._trails_json.items()
        )
        body = (
            f'{{"map":{self._map_json},"plans":[{",".join(self._plans_json)}],'
            f'"trails":{{{trails}}},{_json(small)[1:]}'
        ).encode()
        self._state_json = (self._version, now, body)
        return body

    def _snapshot(self, *, pieces: bool = True) -> dict[str, Any]:
        """The state a new client starts from (lock held); without ``pieces``, without
        the map, the plans and the trails (:meth:`state_json` has them encoded)."""
        small = {
            "poses": dict(self._poses),
            "progress": dict(self._progress),
            "status": self._status,
            "latched": self._latched,
            "stop_source": self._stop_source,
            "limits": [self.limits.drift_linear_m, self.limits.drift_angular_deg],
            "rtt_s": self.rtt_s,
            "log": list(self._log),
            "stops": list(self._stops),
            "onboard": self._onboard,
            "goal": self._goal,
            "result": self._result,
            "halted": self._halted is not None,
        }
        if not pieces:
            return small
        return {
            "map": _map_json(self.world),
            "plans": list(self._plans),
            "trails": {k: list(v) for k, v in self._trails.items()},
            **small,
        }

    def _broadcast(self, name: str, data: dict[str, Any]) -> None:
        record = _record(name, data)
        self.records += 1
        with self._lock:
            self._version += 1
            for client in self._clients:
                client.put(record)

    # -- the hub thread -----------------------------------------------------------------------
    def start(self) -> ViewHub:
        """Start the hub thread."""
        if self._thread is None:
            self._thread = threading.Thread(target=self._loop, name="view-hub", daemon=True)
            self._thread.start()
        return self

    def close(self) -> None:
        """Stop the hub thread and close every client queue (idempotent)."""
        if self._closed:
            return
        self._closed = True
        with self._inbox_cond:
            self._inbox_cond.notify()
        if self._thread is not None:
            self._thread.join(5.0)
        with self._lock:
            clients = list(self._clients)
            self._clients.clear()
        for client in clients:
            client.close()

    def pump(self) -> None:
        """Turn every waiting input into events, then send one ``tick``: the hub thread's
        work, for a caller that drives the hub itself (never beside :meth:`start`)."""
        with self._inbox_cond:
            items = list(self._inbox)
            self._inbox.clear()
        self._handle_all(items)
        self._tick()

    def _handle_all(self, items: list[tuple[str, float, Any]]) -> None:
        for kind, rx, payload in items:
            try:
                self._handle(kind, rx, payload)
            except Exception:
                logger.exception("view: cannot show %s", kind)

    def _loop(self) -> None:
        next_tick = time.monotonic() + TICK_S
        while True:
            with self._inbox_cond:
                if not self._inbox and not self._closed:
                    self._inbox_cond.wait(max(0.0, next_tick - time.monotonic()))
                items = list(self._inbox)
                self._inbox.clear()
            if self._closed:
                return
            self._handle_all(items)
            if time.monotonic() >= next_tick:
                next_tick = time.monotonic() + TICK_S
                try:
                    self._tick()
                except Exception:
                    logger.exception("view: tick failed")

    def _handle(self, kind: str, rx: float, payload: Any) -> None:
        # Inputs of the ground station are "_name"; ROS topics go by their last part.
        name = "_on" + kind if kind.startswith("_") else "_topic_" + kind
        handler = getattr(self, name, None)
        if handler is not None:
            handler(rx, payload)

    def _topic_odom_ground(self, rx: float, msg: Any) -> None:
        pose, stamp = _pose_of(msg)
        if self._last_odom is not None and self._odom_anchor is None:
            self._odom_anchor = (self._last_odom, pose)
        self._pose("reported", pose, stamp, rx)

    def _topic_odom(self, rx: float, msg: Any) -> None:
        raw, stamp = _pose_of(msg)
        self._last_odom = raw
        if self._odom_anchor is None:
            return  # not in the map frame until a reported pose ties it there
        o, m = self._odom_anchor
        dyaw = math.radians(m.yaw_deg - o.yaw_deg)
        dx, dy = raw.x - o.x, raw.y - o.y
        pose = Pose(
            m.x + dx * math.cos(dyaw) - dy * math.sin(dyaw),
            m.y + dx * math.sin(dyaw) + dy * math.cos(dyaw),
            wrap_deg(raw.yaw_deg + m.yaw_deg - o.yaw_deg),
        )
        twist = msg.twist.twist
        self._pose("odom", pose, stamp, rx, v=twist.linear.x, w=twist.angular.z)

    def _pose(self, src: str, pose: Pose, stamp: float, rx: float, **extra: float) -> None:
        data: dict[str, Any] = {
            "src": src,
            "x": round(pose.x, 4),
            "y": round(pose.y, 4),
            "yaw": round(pose.yaw_deg, 2),
            "stamp_s": stamp,
            "tap_s": rx,
            **{k: round(v, 4) for k, v in extra.items()},
        }
        with self._lock:
            self._poses[src] = data
            trail = self._trails[src]
            if not trail or math.hypot(pose.x - trail[-1][0], pose.y - trail[-1][1]) > 0.01:
                point = [round(pose.x, 4), round(pose.y, 4)]
                trail.append(point)
                self._trails_json[src].append(_json(point))
        self._broadcast("pose", data)

    def _topic_command_status(self, rx: float, msg: Any) -> None:
        text = str(msg.data)
        if text == "accepted" and self._step_sent is not None:
            self._rtt_measured = rx - self._step_sent
            self._step_started = (self._step_sent + rx) / 2.0
        elif text == "cleared":
            with self._lock:
                self._latched = False
                self._replan_approved = False
                self._stop_source = ""
        with self._lock:
            self._status = text
        self._broadcast("status", {"status": text, "tap_s": rx, "latched": self._latched})
        if text.startswith(_ENDS_BADLY) and self._step_sent is not None:
            self._halt()
            if text.startswith("fault:") or text.startswith("aborted:"):
                p = self._progress
                where = f" at step {p['step'] + 1}/{p['steps']}" if p else ""
                self._show_result(False, f"{text}{where}", final=False)

    def _topic_wheel_instructions(self, rx: float, msg: Any) -> None:
        self._step_sent = rx
        self._step_sent_for = rx
        self._step_started = None
        self._halted = None  # a new step: the ghost follows it
        if self._result is not None and not self._result.get("final"):
            self._show_result(None, "", final=False)  # a fault's banner ends with a new step

    def _halt(self) -> None:
        """Freeze the ghost where it is (the step it followed will not be driven)."""
        if self._halted is None and self._last_ghost is not None:
            self._halted = self._last_ghost

    def _show_result(self, ok: bool | None, text: str, *, final: bool) -> None:
        data = None if ok is None else {"ok": ok, "text": text, "final": final}
        with self._lock:
            self._result = data
        self._broadcast("result", data or {"ok": None, "text": "", "final": False})

    def _on_result(self, rx: float, outcome: tuple[bool, str]) -> None:
        self._show_result(outcome[0], outcome[1], final=True)

    def _stop_at(self) -> list[float] | None:
        pose = self._poses.get("reported") or self._poses.get("odom")
        return None if pose is None else [pose["x"], pose["y"]]

    def _topic_emergency_stop(self, rx: float, msg: Any) -> None:
        self._halt()
        with self._lock:
            first = not self._latched
            self._latched = True
            self._replan_approved = False
            self._stop_source = self._stop_source or "ground station"
            at = self._stop_at()
            if first and at is not None:
                self._stops.append({"at": at, "source": self._stop_source})
        if first:
            self._broadcast(
                "stop", {"latched": True, "source": self._stop_source, "tap_s": rx, "at": at}
            )

    # -- the plan on board (docs/onboard.md): the uplink, its answers, the rover's reports --
    def _topic_plan_uplink(self, rx: float, msg: Any) -> None:
        try:
            body = json.loads(json.loads(msg.data)["body"])
            pid, steps = int(body.get("plan_id", body.get("upto", 0))), body.get("steps")
        except (ValueError, KeyError, TypeError):
            return
        key = ("uplink", pid)
        if key in self._onboard_seen:
            return  # a copy sent again until the rover answers
        self._onboard_seen.add(key)
        what = f"{len(steps)} steps" if isinstance(steps, list) else "a cancel"
        self._on_log(rx, f"uplink: plan {pid} ({what}) sent to the rover")

    def _topic_plan_ack(self, rx: float, msg: Any) -> None:
        try:
            ack = decode_ack(msg.data)
        except ValueError:
            return
        key = ("ack", ack.plan_id, ack.result, ack.reason)
        if key in self._onboard_seen:
            return
        self._onboard_seen.add(key)
        why = f" ({ack.reason}: {ack.detail})" if ack.reason else ""
        self._on_log(rx, f"rover: plan {ack.plan_id} {ack.result}{why}")

    def _topic_onboard_report(self, rx: float, msg: Any) -> None:
        try:
            report = decode_report(msg.data)
        except ValueError:
            return
        with self._lock:
            self._onboard = json.loads(report.to_json())
        self._broadcast("onboard", {"report": self._onboard, "tap_s": rx})
        guard = report.guard
        if guard is not None and ("guard", report.plan_id) not in self._onboard_seen:
            # Where and why the rover stopped itself: a STOP marker where it was.
            self._onboard_seen.add(("guard", report.plan_id))
            self._halt()
            at = [round(guard.pose.x, 4), round(guard.pose.y, 4)]
            source = f"guard on board: {guard.reason}"
            with self._lock:
                self._latched = True
                self._stops.append({"at": at, "source": source})
            self._broadcast("stop", {"latched": True, "source": source, "tap_s": rx, "at": at})
            self._on_log(
                rx, f"rover: STOP by its guard at ({at[0]:.2f}, {at[1]:.2f}): {guard.reason}"
            )
        if report.rest is not None and ("rest", report.plan_id) not in self._onboard_seen:
            self._onboard_seen.add(("rest", report.plan_id))
            rest = report.rest
            self._on_log(
                rx,
                f"rover: plan {report.plan_id} {report.outcome}; at rest "
                f"({rest.pose.x:.2f}, {rest.pose.y:.2f}, {rest.pose.yaw_deg:.0f} deg) "
                f"+- {rest.sigma_xy_m:.3f} m",
            )

    def _on_stop(self, rx: float, source: str) -> None:
        with self._lock:
            self._stop_source = source
            self._replan_approved = False  # an approval before this STOP no longer counts
        self._broadcast("stop", {"latched": self._latched, "source": source, "tap_s": rx})

    def _on_planned(self, rx: float, mission: MissionResult) -> None:
        self._plannings += 1
        plans = [
            _plan_json(self._plannings, a.index, a.repair_name, a.verdict) for a in mission.attempts
        ]
        with self._lock:
            self._plans.extend(plans)
            self._plans_json.extend(_json(p) for p in plans)
            if mission.approved and self._latched:
                self._replan_approved = True
        self._ghosts = list(mission.verdicts)
        goal = mission.goal
        self._goal = [goal.x, goal.y, goal.yaw_deg]
        self._broadcast("plans", {"plans": plans, "approved": mission.approved, "goal": self._goal})

    def _leg_of(self, verdict: Verdict | None) -> int:
        """The place of ``verdict`` among the latest planning's approved plans, by
        identity (0-based; 0 when it is none of them: a plan the view was not told of)."""
        return next((i for i, v in enumerate(self._ghosts) if v is verdict), 0)

    def _on_progress(self, rx: float, p: ExecutionProgress) -> None:
        moved = p.verdict is not self._following or p.step != self._step_index
        if moved and p.status in ("published", "accepted", "running"):
            # Another plan, or another step of it, under way: the ghost follows it again
            # (a plan run on board has no wheel_instructions to say so).
            self._halted = None
            if self._step_sent_for is None or self._step_sent_for < self._moved_at:
                # No step sent from here: the plan runs on board, and this report (half
                # a round trip old) is the first the ground hears of the step.
                self._step_started = rx - self.rtt_s / 2.0 if p.status == "running" else None
            self._moved_at = rx
        self._following = p.verdict
        self._step_index = p.step
        data = {
            "step": p.step,
            "steps": p.steps,
            "status": p.status,
            "eta_s": p.eta_s,
            "leg": self._leg_of(p.verdict),
            "legs": max(1, len(self._ghosts)),
            "planning": self._plannings,
        }
        with self._lock:
            self._progress = data
        self._broadcast("progress", data)

    def _on_log(self, rx: float, line: str) -> None:
        with self._lock:
            self._log.append(line)
        self._broadcast("log", {"line": line})

    def _ghost(self) -> Pose | None:
        """Where the prediction of the plan running now says the rover is (the ghost
        ahead of the reports); ``None`` without one."""
        if self._following is None:
            return None
        trajectory = self._following.trajectory
        step_t = 0.0
        if self._step_started is not None:
            step_t = (self._clock() - self._step_started) * self.time_scale
        samples = trajectory.for_step(self._step_index)
        if not samples:
            return None
        if step_t >= samples[-1].step_t_s:
            return samples[-1].pose
        return trajectory.pose_at(self._step_index, step_t)

    def _ghost_envelope(self) -> list[float] | None:
        """The spread of the gate's samples where the ghost is: ``[semi-major m,
        semi-minor m, angle deg]`` of the step's first envelope point not behind it
        (``None`` without uncertainty)."""
        if self._following is None:
            return None
        u = self._following.uncertainty
        points = u.for_step(self._step_index) if u is not None else ()
        if not points:
            return None
        step_t = 0.0
        if self._step_started is not None:
            step_t = (self._clock() - self._step_started) * self.time_scale
        at = next((p for p in points if p.step_t_s >= step_t), points[-1])
        return [round(at.major_m, 4), round(at.minor_m, 4), round(at.angle_deg, 2)]

    def _tick(self) -> None:
        drift = self._drift_source() if self._drift_source is not None else None
        if self._halted is not None:
            ghost: Pose | None = Pose(*self._halted)
        else:
            ghost = self._ghost()
            if ghost is not None:
                self._last_ghost = (ghost.x, ghost.y, ghost.yaw_deg)
        self._broadcast(
            "tick",
            {
                "t": self._clock(),
                "ghost": None
                if ghost is None
                else [round(ghost.x, 4), round(ghost.y, 4), round(ghost.yaw_deg, 2)],
                "envelope": None if ghost is None else self._ghost_envelope(),
                "drift": None if drift is None else [round(drift[0], 4), round(drift[1], 2)],
                "rtt_s": self._rtt_measured,
                "latched": self._latched,
                "halted": self._halted is not None,
                "clients": len(self._clients),
            },
        )
