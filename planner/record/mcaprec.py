"""Recording a mission as ROS 2 MCAP, and reading one back (``rover decode x.mcap``).

:class:`McapRecorder` is a tap of the ground station's ROS port: every message it sends
and receives, under the topic the port resolved, CDR-encoded (profile ``ros2``, so
Foxglove and ``ros2 bag`` open it); beside them the gate's predictions and verdicts,
``/tf``, map and plan markers, ``/diagnostics`` (:meth:`attach`) and metadata records
(docs/view.md "Recordings"). The tap only queues; a writer thread encodes and writes, so
the mission never waits on the disk; :meth:`McapRecorder.close` drains and finishes the
file (idempotent). Message definitions come from the generated classes' field lists.
"""

from __future__ import annotations

import importlib
import json
import logging
import math
import queue
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

from firmware_proto.model.pose import Pose, frame_in
from firmware_proto.model.verdict import Verdict
from firmware_proto.model.worldmap import WorldMap
from planner.plan.orchestrator import MissionResult
from planner.record.markers import map_markers, plan_markers

__all__ = [
    "MAP_MARKERS_TOPIC",
    "PLAN_MARKERS_TOPIC",
    "PREDICTED_TOPIC",
    "REJECTED_TOPIC",
    "TF_TOPIC",
    "VERDICT_TOPIC",
    "McapRecorder",
    "McapSummary",
    "gate_messages",
    "msgdef",
    "plain_message",
    "read_summary",
    "record_messages",
    "recording_unavailable",
    "ros_name",
]

logger = logging.getLogger(__name__)

PREDICTED_TOPIC = "/gate/predicted_trajectory"
"""The approved plan's predicted trajectory (``nav_msgs/msg/Path``, frame ``map``)."""
REJECTED_TOPIC = "/gate/rejected_trajectory"
"""A rejected attempt's predicted trajectory, up to its collision or stall."""
VERDICT_TOPIC = "/gate/verdict"
"""Each attempt's verdict as JSON (``std_msgs/msg/String``)."""
TF_TOPIC = "/tf"
"""``map -> odom -> base_link`` (``tf2_msgs/msg/TFMessage``)."""
MAP_MARKERS_TOPIC = "/map/markers"
"""The map as ``visualization_msgs/msg/MarkerArray``."""
PLAN_MARKERS_TOPIC = "/gate/plan_markers"
"""Each planning's attempts as ``visualization_msgs/msg/MarkerArray``."""
_TF_TYPE = "tf2_msgs/msg/TFMessage"

_PRIMITIVES = {
    "double": "float64",
    "float": "float32",
    "long double": "float64",
    "boolean": "bool",
    "octet": "byte",
}
_SEPARATOR = "=" * 80


def _field_type(idl: str) -> tuple[str, str | None]:
    """The .msg spelling of one field type from ``get_fields_and_field_types()`` and the
    nested message type it names (``pkg/Name``), if any."""
    suffix = ""
    base = idl
    if base.startswith("sequence<"):
        inner = base[len("sequence<") : -1]
        if "," in inner:
            inner, bound = (s.strip() for s in inner.rsplit(",", 1))
            suffix = f"[<={bound}]"
        else:
            suffix = "[]"
        base = inner
    elif base.endswith("]"):
        base, _, size = base[:-1].partition("[")
        suffix = f"[{size}]"
    for name in ("string", "wstring"):
        if base.startswith(f"{name}<"):
            base = f"{name}<={base[len(name) + 1 : -1]}"
    base = _PRIMITIVES.get(base, base)
    nested = base if "/" in base else None
    return base + suffix, nested


def _class_of(type_name: str) -> type[Any]:
    """``pkg/Name`` or ``pkg/msg/Name`` -> the generated class."""
    parts = type_name.split("/")
    module = importlib.import_module(f"{parts[0]}.msg")
    cls: type[Any] = getattr(module, parts[-1])
    return cls


def ros_name(cls: type[Any]) -> str:
    """``nav_msgs/msg/Odometry`` for the class ``nav_msgs.msg.Odometry``."""
    return f"{cls.__module__.split('.')[0]}/msg/{cls.__name__}"


def msgdef(cls: type[Any]) -> str:
    """The ROS 2 message definition of a generated message class, with its
    dependencies (the ``ros2msg`` schema text of a ROS 2 MCAP file)."""
    order: list[str] = []
    texts: dict[str, str] = {}

    def walk(c: type[Any], name: str) -> None:
        if name in texts:
            return
        lines = []
        texts[name] = ""
        for field_name, idl in c.get_fields_and_field_types().items():
            spelled, nested = _field_type(idl)
            lines.append(f"{spelled} {field_name}")
            if nested is not None:
                walk(_class_of(nested), nested)
        # An empty message is one dummy byte on the wire, as rosidl generates it.
        texts[name] = "\n".join(lines) or "uint8 structure_needs_at_least_one_member"
        order.append(name)

    top = ros_name(cls)
    walk(cls, top)
    parts = [texts[top]]
    for name in order:
        if name != top:
            pkg, _, short = name.rpartition("/")
            parts.append(f"{_SEPARATOR}\nMSG: {pkg.split('/')[0]}/{short}\n{texts[name]}")
    return "\n".join(parts) + "\n"


def plain_message(value: Any) -> Any:
    """A generated message as dicts and lists (what the CDR encoder reads): numpy and
    ``array.array`` fields become lists, a ROS ``byte`` its number (:func:`_octets`)."""
    fields = getattr(value, "get_fields_and_field_types", None)
    if fields is not None:
        return {
            name: _octets(idl, plain_message(getattr(value, name)))
            for name, idl in fields().items()
        }
    if isinstance(value, (str, bytes, int, float, bool, dict)):
        return value
    if hasattr(value, "__iter__"):
        return [plain_message(v) for v in value]
    return value


def _octets(idl: str, value: Any) -> Any:
    """ROS ``byte`` (``octet``) fields are one-byte ``bytes`` in rclpy, integers to the
    CDR encoder (a diagnostic status's level)."""
    if "octet" not in idl:
        return value
    if isinstance(value, (bytes, bytearray)) and idl == "octet":
        return value[0] if value else 0
    if isinstance(value, list):
        return [v[0] if isinstance(v, (bytes, bytearray)) and len(v) == 1 else v for v in value]
    if isinstance(value, (bytes, bytearray)):
        return list(value)
    return value


def _stamp(t_s: float) -> dict[str, int]:
    sec = math.floor(t_s)
    return {"sec": int(sec), "nanosec": int((t_s - sec) * 1e9)}


def _path_msg(verdict: Verdict, t_s: float) -> dict[str, Any]:
    """The verdict's prediction as a ``nav_msgs/Path`` dict, twin time from ``t_s``."""
    poses = []
    for sample in verdict.trajectory.samples:
        half = math.radians(sample.pose.yaw_deg) / 2.0
        poses.append(
            {
                "header": {"stamp": _stamp(t_s + sample.t_s), "frame_id": "map"},
                "pose": {
                    "position": {"x": sample.pose.x, "y": sample.pose.y, "z": 0.0},
                    "orientation": {"x": 0.0, "y": 0.0, "z": math.sin(half), "w": math.cos(half)},
                },
            }
        )
    return {"header": {"stamp": _stamp(t_s), "frame_id": "map"}, "poses": poses}


def _verdict_json(verdict: Verdict, attempt: int, repair: str) -> str:
    collision = verdict.collision
    return json.dumps(
        {
            "attempt": attempt,
            "repair": repair,
            "approved": verdict.approved,
            "summary": verdict.summary(),
            "failure_type": verdict.failure_type,
            "collision": None
            if collision is None
            else {
                "obstacle": collision.obstacle_id,
                "x": collision.contact[0],
                "y": collision.contact[1],
                "step": collision.step,
            },
            "plan_sha256": verdict.replay.plan_sha256,
        }
    )


def _transform(
    stamp: dict[str, int], parent: str, child: str, x: float, y: float, yaw_rad: float
) -> dict[str, Any]:
    half = yaw_rad / 2.0
    return {
        "header": {"stamp": stamp, "frame_id": parent},
        "child_frame_id": child,
        "transform": {
            "translation": {"x": x, "y": y, "z": 0.0},
            "rotation": {"x": 0.0, "y": 0.0, "z": math.sin(half), "w": math.cos(half)},
        },
    }


def _map_metadata(world: WorldMap, goal: Pose | None) -> dict[str, str]:
    b = world.bounds
    return {
        "name": world.name,
        "bounds": json.dumps([b.min_x, b.min_y, b.max_x, b.max_y]),
        "obstacles": json.dumps(
            [
                {
                    "id": o.id,
                    "kind": o.kind,
                    "points": [[p[0], p[1]] for p in o.points],
                    "radius_m": o.radius_m,
                }
                for o in world.obstacles
            ]
        ),
        "start": json.dumps([world.start.x, world.start.y, world.start.yaw_deg]),
        "goal": json.dumps(None if goal is None else [goal.x, goal.y, goal.yaw_deg]),
    }


def gate_messages(mission: MissionResult, t_ns: int) -> list[tuple[str, type[Any], Any]]:
    """The gate's judgement of a planning as ROS messages ``(topic, class, message as
    dicts)``: for each attempt its verdict (JSON on :data:`VERDICT_TOPIC`) and its
    predicted trajectory (``nav_msgs/msg/Path`` on :data:`PREDICTED_TOPIC` when approved,
    else :data:`REJECTED_TOPIC`), stamped from ``t_ns``."""
    from bridge.ros.rosport.msgs import String  # noqa: PLC0415  (ROS 2 messages: when used)

    path_cls = _class_of("nav_msgs/Path")
    out: list[tuple[str, type[Any], Any]] = []
    for attempt in mission.attempts:
        verdict = attempt.verdict
        topic = PREDICTED_TOPIC if verdict.approved else REJECTED_TOPIC
        text = _verdict_json(verdict, attempt.index, attempt.repair_name)
        out.append((VERDICT_TOPIC, String, {"data": text}))
        out.append((topic, path_cls, _path_msg(verdict, t_ns / 1e9)))
    return out


def recording_unavailable() -> str:
    """``""`` when MCAP recordings can be written and read, else why not (the ``record``
    extra, ``mcap`` and ``mcap-ros2-support``, is not installed) and how to get them."""
    try:
        import mcap.reader  # noqa: F401, PLC0415
        import mcap_ros2.writer  # noqa: F401, PLC0415
    except ImportError as exc:
        package = (exc.name or "mcap").split(".")[0]
        return f"MCAP recording needs {package}: pip install 'rover-hil[record]'"
    return ""


class McapRecorder:
    """Writes a ROS 2 MCAP file of what the ground station's port sees. A context
    manager; :meth:`close` is idempotent.

    Args:
        path: the file to write (replaced if it exists).
        clock: the log time of each message, ns since the epoch (default the wall
            clock; a lockstep run passes its own so its recordings read as real ones).

    Raises:
        OSError: the file cannot be created.
        ImportError: the ``record`` extra is not installed (:func:`recording_unavailable`).
    """

    def __init__(self, path: str | Path, *, clock: Callable[[], int] = time.time_ns) -> None:
        missing = recording_unavailable()
        if missing:
            raise ImportError(missing)
        from mcap_ros2.writer import Writer  # noqa: PLC0415  (only a recording needs it)

        self.path = Path(path)
        self._clock = clock
        self._file: BinaryIO = self.path.open("wb")
        self._writer = Writer(self._file)
        self._schemas: dict[str, Any] = {}
        self._queue: queue.SimpleQueue[tuple[int, str, Any, Any] | None] = queue.SimpleQueue()
        self._ground: tuple[float, float, float] | None = None  # map pose (x, y, yaw rad)
        self._plannings = 0
        self._counts: Counter[str] = Counter()
        self._errors = 0
        self._closed = False
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._write_loop, name="mcap-writer", daemon=True)
        self._thread.start()

    @property
    def counts(self) -> dict[str, int]:
        """Messages written so far, per topic."""
        with self._lock:
            return dict(self._counts)

    def tap(self, direction: str, topic: str, msg: Any) -> None:
        """A :data:`bridge.ros.rosport.Tap`: queue ``msg`` on ``topic`` (never blocks)."""
        if not self._closed:
            self._queue.put((self._clock(), topic, type(msg), msg))

    def attach(self, port: Any) -> None:
        """Record what ``port`` sends and receives (its tap), and subscribe it to
        ``diagnostics`` so that the bridge's ``/diagnostics`` are recorded too."""
        from bridge.ros.rosport import qos  # noqa: PLC0415
        from bridge.ros.rosport.msgs import DiagnosticArray  # noqa: PLC0415

        port.add_tap(self.tap)
        port.subscribe("diagnostics", DiagnosticArray, lambda _msg: None, qos.DIAGNOSTICS)

    def set_map(self, world: WorldMap, goal: Pose | None) -> None:
        """Record the map (markers on :data:`MAP_MARKERS_TOPIC`, metadata ``map``)."""
        if self._closed:
            return
        from bridge.ros.rosport.msgs import stamp  # noqa: PLC0415

        now_ns = self._clock()
        markers = map_markers(world, goal, stamp(now_ns / 1e9))
        self._queue.put((now_ns, MAP_MARKERS_TOPIC, type(markers), markers))
        self._queue.put((now_ns, "", None, ("map", _map_metadata(world, goal))))

    def planned(self, mission: MissionResult) -> None:
        """Record a planning: each attempt's verdict, and its predicted trajectory on
        :data:`PREDICTED_TOPIC` (approved) or :data:`REJECTED_TOPIC`; its markers on
        :data:`PLAN_MARKERS_TOPIC`; its plans and verdicts as metadata."""
        if self._closed:
            return
        from bridge.ros.rosport.msgs import stamp  # noqa: PLC0415

        now_ns = self._clock()
        for topic, cls, msg in gate_messages(mission, now_ns):
            self._queue.put((now_ns, topic, cls, msg))
        self._plannings += 1
        markers = plan_markers(mission, self._plannings, stamp(now_ns / 1e9))
        self._queue.put((now_ns, PLAN_MARKERS_TOPIC, type(markers), markers))
        meta = {
            "approved": str(mission.approved).lower(),
            "reason": str(mission.reason),
            "plans": json.dumps([plan.to_dict() for plan in mission.plans]),
            "verdicts": json.dumps(
                [
                    json.loads(_verdict_json(a.verdict, a.index, a.repair_name))
                    for a in mission.attempts
                ]
            ),
        }
        self._queue.put((now_ns, "", None, (f"planning-{self._plannings}", meta)))

    def _schema(self, cls: type[Any]) -> Any:
        name = ros_name(cls)
        schema = self._schemas.get(name)
        if schema is None:
            schema = self._writer.register_msgdef(name, msgdef(cls))
            self._schemas[name] = schema
        return schema

    def _tf_schema(self) -> Any:
        schema = self._schemas.get(_TF_TYPE)
        if schema is None:
            try:  # a sourced ROS 2 has tf2_msgs: its definition made from its class
                text = msgdef(_class_of(_TF_TYPE))
            except ImportError:
                # No tf2_msgs (PyPI wheels): its one-line TFMessage.msg over geometry_msgs.
                transform = _class_of("geometry_msgs/TransformStamped")
                text = (
                    "geometry_msgs/TransformStamped[] transforms\n"
                    f"{_SEPARATOR}\nMSG: geometry_msgs/TransformStamped\n{msgdef(transform)}"
                )
            schema = self._writer.register_msgdef(_TF_TYPE, text)
            self._schemas[_TF_TYPE] = schema
        return schema

    def _tf(self, topic: str, msg: Any) -> dict[str, Any] | None:
        """The ``/tf`` message an odometry message makes (writer thread), if any."""
        if not hasattr(msg, "child_frame_id"):
            return None
        p = msg.pose.pose
        yaw = 2.0 * math.atan2(p.orientation.z, p.orientation.w)
        if topic.endswith("/odom_ground"):
            self._ground = (p.position.x, p.position.y, yaw)
            return None
        if not topic.endswith("/odom"):
            return None
        header = msg.header
        stamp = {"sec": int(header.stamp.sec), "nanosec": int(header.stamp.nanosec)}
        transforms = [
            _transform(stamp, header.frame_id, msg.child_frame_id, p.position.x, p.position.y, yaw)
        ]
        if self._ground is not None:
            gx, gy, gyaw = self._ground
            # map -> odom = (map -> base) * inverse(odom -> base)
            odom = frame_in(
                Pose(gx, gy, math.degrees(gyaw)),
                Pose(p.position.x, p.position.y, math.degrees(yaw)),
            )
            transforms.insert(
                0, _transform(stamp, "map", header.frame_id, odom.x, odom.y, odom.yaw_rad)
            )
        return {"transforms": transforms}

    def _write_loop(self) -> None:
        while True:
            item = self._queue.get()
            if item is None:
                return
            t_ns, topic, cls, msg = item
            try:
                if cls is None:  # a metadata record: (name, {key: text})
                    self._writer._writer.add_metadata(*msg)  # the mcap writer under it
                    continue
                self._writer.write_message(
                    topic, self._schema(cls), plain_message(msg), log_time=t_ns
                )
                tf = self._tf(topic, msg)
                if tf is not None:
                    self._writer.write_message(TF_TOPIC, self._tf_schema(), tf, log_time=t_ns)
                    with self._lock:
                        self._counts[TF_TOPIC] += 1
            except Exception:
                self._errors += 1
                if self._errors & (self._errors - 1) == 0:
                    logger.exception("mcap: cannot record a message on %s", topic)
                continue
            with self._lock:
                self._counts[topic] += 1

    def close(self) -> None:
        """Write what is queued, finish the file and close it (idempotent)."""
        if self._closed:
            return
        self._closed = True
        self._queue.put((0, "", None, ("mission", {"plannings": str(self._plannings)})))
        self._queue.put(None)
        self._thread.join(30.0)
        try:
            self._writer.finish()  # type: ignore[no-untyped-call]
        finally:
            self._file.close()

    def __enter__(self) -> McapRecorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


@dataclass
class McapSummary:
    """What :func:`read_summary` found in a file.

    Attributes:
        counts: messages per topic; ``types``: each topic's message type.
        first_pose, last_pose: per odometry topic, ``(x, y, yaw_deg)`` of the first and
            last message.
        statuses: every ``command_status`` text, in order.
        start_ns, end_ns: log times of the first and last message.
    """

    counts: dict[str, int] = field(default_factory=dict)
    types: dict[str, str] = field(default_factory=dict)
    first_pose: dict[str, tuple[float, float, float]] = field(default_factory=dict)
    last_pose: dict[str, tuple[float, float, float]] = field(default_factory=dict)
    statuses: list[str] = field(default_factory=list)
    start_ns: int = 0
    end_ns: int = 0

    def text(self) -> str:
        """The summary ``rover decode`` prints."""
        span = (self.end_ns - self.start_ns) / 1e9 if self.counts else 0.0
        lines = [f"{sum(self.counts.values())} messages on {len(self.counts)} topics, {span:.1f} s"]
        width = max((len(t) for t in self.counts), default=0)
        for topic in sorted(self.counts):
            line = f"  {topic:<{width}}  {self.counts[topic]:6d}  {self.types[topic]}"
            if topic in self.first_pose:
                a, b = self.first_pose[topic], self.last_pose[topic]
                line += (
                    f"  first ({a[0]:.3f}, {a[1]:.3f}, {a[2]:.1f} deg)"
                    f" last ({b[0]:.3f}, {b[1]:.3f}, {b[2]:.1f} deg)"
                )
            lines.append(line)
        if self.statuses:
            seen = Counter(self.statuses)
            lines.append("  command_status: " + ", ".join(f"{k} x{n}" for k, n in seen.items()))
        return "\n".join(lines)


def read_summary(path: str | Path) -> McapSummary:
    """Read a ROS 2 MCAP file with the mcap reader and decode every message.

    Raises:
        OSError: the file cannot be read.
        mcap.exceptions.McapError: it is not an MCAP file, or is damaged.
    """
    from mcap.reader import make_reader  # noqa: PLC0415
    from mcap_ros2.decoder import DecoderFactory  # noqa: PLC0415

    summary = McapSummary()
    with Path(path).open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for schema, channel, message, decoded in reader.iter_decoded_messages(log_time_order=True):
            topic = channel.topic
            if not summary.counts:
                summary.start_ns = message.log_time
            summary.end_ns = message.log_time
            summary.counts[topic] = summary.counts.get(topic, 0) + 1
            summary.types[topic] = schema.name if schema is not None else "?"
            if summary.types[topic] == "nav_msgs/msg/Odometry":
                p = decoded.pose.pose
                q = p.orientation
                yaw = math.degrees(2.0 * math.atan2(q.z, q.w))
                pose = (p.position.x, p.position.y, yaw)
                summary.first_pose.setdefault(topic, pose)
                summary.last_pose[topic] = pose
            elif topic.endswith("/command_status"):
                summary.statuses.append(decoded.data)
    return summary


def record_messages(
    path: str | Path, messages: Iterable[tuple[int, str, Any]], direction: str = "lockstep"
) -> None:
    """Write ``(log time ns, topic, ROS message)`` as a recording, each at its own log
    time (a mission heard without a port: :func:`sim.calibration_runs.drive_lockstep`'s)."""
    clock = [0]
    recorder = McapRecorder(path, clock=lambda: clock[0])
    try:
        for t_ns, topic, msg in messages:
            clock[0] = t_ns
            recorder.tap(direction, topic, msg)
    finally:
        recorder.close()
