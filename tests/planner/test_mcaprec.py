"""Recording what the ground station's ROS port sends and receives as ROS 2 MCAP, read
back with the mcap reader (and, for the bytes, with rclpy's own deserializer), and
``rover decode x.mcap``."""

from __future__ import annotations

import json
import math
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import pytest

from bridge.ros.rosport import TAP_RECEIVED, TAP_SENT, open_port, qos
from bridge.ros.rosport.msgs import Bool, Empty, Int16MultiArray, Odometry, String
from planner.record.mcaprec import McapRecorder, msgdef, read_summary


def _odom(x: float, y: float, yaw_deg: float) -> Odometry:
    msg = Odometry()
    msg.header.frame_id = "map"
    msg.pose.pose.position.x = x
    msg.pose.pose.position.y = y
    msg.pose.pose.orientation.z = math.sin(math.radians(yaw_deg) / 2)
    msg.pose.pose.orientation.w = math.cos(math.radians(yaw_deg) / 2)
    msg.pose.covariance[0] = 0.01  # a numpy array in the generated class
    return msg


def test_msgdef_lists_dependencies_as_ros2_does() -> None:
    text = msgdef(Odometry)
    assert text.startswith("std_msgs/Header header\nstring child_frame_id\n")
    assert (
        "MSG: geometry_msgs/PoseWithCovariance\ngeometry_msgs/Pose pose\nfloat64[36] covariance"
        in text
    )
    assert "MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec" in text
    assert msgdef(Int16MultiArray).startswith("std_msgs/MultiArrayLayout layout\nint16[] data\n")
    assert msgdef(Empty) == "uint8 structure_needs_at_least_one_member\n"


def test_a_tapped_port_is_recorded_and_reads_back(tmp_path: Path) -> None:
    path = tmp_path / "mission.mcap"
    taps: list[tuple[str, str]] = []
    got = threading.Event()
    with (
        open_port("inprocess", namespace="rover", node_name="rover", bus="rec") as rover,
        open_port("inprocess", namespace="ground", node_name="ground", bus="rec") as ground,
        McapRecorder(path) as recorder,
    ):
        ground.add_tap(lambda d, t, m: taps.append((d, t)))
        ground.add_tap(recorder.tap)
        statuses: list[str] = []

        def on_status(msg: String) -> None:
            statuses.append(msg.data)
            if msg.data == "stopped":
                got.set()

        ground.subscribe("/rover/command_status", String, on_status, qos.STATUS)
        ground.subscribe("/rover/odom_ground", Odometry, lambda m: None, qos.SENSOR)
        steps = ground.publisher("wheel_instructions", Int16MultiArray, qos.COMMAND)
        stop = ground.publisher("emergency_stop", Bool, qos.STOP)
        clear = ground.publisher("clear_emergency_stop", Empty, qos.STOP)
        status = rover.publisher("command_status", String, qos.STATUS)
        odom = rover.publisher("odom_ground", Odometry, qos.TELEMETRY)
        assert status.wait_for_subscribers(1) and odom.wait_for_subscribers(1)
        steps.publish(Int16MultiArray(data=[1, 30, 23000]))
        for i in range(5):
            odom.publish(_odom(1.2 + 0.1 * i, 3.0, 2.0 * i))
        stop.publish(Bool(data=True))
        clear.publish(Empty())
        for text in ("accepted", "completed", "stopped"):
            status.publish(String(data=text))
        assert got.wait(10)
    assert (TAP_SENT, "/ground/wheel_instructions") in taps
    assert (TAP_RECEIVED, "/rover/command_status") in taps
    assert recorder.counts["/rover/odom_ground"] == 5

    summary = read_summary(path)
    assert summary.counts == {
        "/ground/wheel_instructions": 1,
        "/ground/emergency_stop": 1,
        "/ground/clear_emergency_stop": 1,
        "/rover/command_status": 3,
        "/rover/odom_ground": 5,
    }
    assert summary.types["/rover/odom_ground"] == "nav_msgs/msg/Odometry"
    assert summary.first_pose["/rover/odom_ground"] == pytest.approx((1.2, 3.0, 0.0))
    assert summary.last_pose["/rover/odom_ground"] == pytest.approx((1.6, 3.0, 8.0))
    assert summary.statuses == ["accepted", "completed", "stopped"]

    # The bytes are ROS 2's own CDR: rclpy deserializes them (what ros2 bag play does).
    from mcap.reader import make_reader
    from rclpy.serialization import deserialize_message

    types = {"nav_msgs/msg/Odometry": Odometry, "std_msgs/msg/Empty": Empty}
    with path.open("rb") as f:
        for schema, _channel, message in make_reader(f).iter_messages():
            assert schema is not None
            if schema.name in types:
                decoded = deserialize_message(message.data, types[schema.name])
                assert isinstance(decoded, types[schema.name])

    out = subprocess.run(
        [sys.executable, "-m", "firmware_proto.cli", "decode", str(path)],
        capture_output=True,
        text=True,
        timeout=60,
        check=True,
    )
    assert "11 messages on 5 topics" in out.stdout
    assert "/rover/odom_ground" in out.stdout and "first (1.200, 3.000, 0.0 deg)" in out.stdout
    assert "stopped x1" in out.stdout


def test_decode_refuses_a_damaged_mcap_cleanly(tmp_path: Path) -> None:
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"\x89MCAP0\r\n" + b"garbage" * 10)
    out = subprocess.run(
        [sys.executable, "-m", "firmware_proto.cli", "decode", str(bad)],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert out.returncode == 1, out.stdout + out.stderr
    assert "Traceback" not in out.stderr and "rover decode: error" in out.stderr


def _odom_frame(x: float, y: float, yaw_deg: float) -> Odometry:
    msg = _odom(x, y, yaw_deg)
    msg.header.frame_id, msg.child_frame_id = "odom", "base_link"
    return msg


def test_a_recording_a_lab_can_open_tf_markers_diagnostics_metadata(
    tmp_path: Path, orchestrator: Any, worlds: dict[str, Any]
) -> None:
    """/tf (map -> odom -> base_link), the map and the plans as markers, /diagnostics and
    the metadata, read back with the mcap reader and mcap-ros2-support's decoder."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    from bridge.ros.diagnostics import diagnostic_array
    from bridge.ros.rosport.msgs import DiagnosticArray, stamp
    from tests.planner.test_console import BASE

    world = worlds["lab"]
    goal = world.goal("behind_table").pose
    mission = orchestrator("lab").plan_mission(goal, start=world.start)
    assert mission.approved and len(mission.attempts) >= 2  # the direct plan collides
    path = tmp_path / "mission.mcap"
    heard = threading.Event()
    with (
        open_port("inprocess", node_name="bridge", bus="lab-rec") as rover,
        open_port("inprocess", namespace="ground", node_name="ground", bus="lab-rec") as ground,
        McapRecorder(path) as recorder,
    ):
        recorder.attach(ground)
        recorder.set_map(world, goal)
        recorder.planned(mission)
        ground.subscribe("/odom", Odometry, lambda m: None, qos.SENSOR)
        ground.subscribe("/odom_ground", Odometry, lambda m: heard.set(), qos.SENSOR)
        odom = rover.publisher("odom", Odometry, qos.TELEMETRY)
        ground_pose = rover.publisher("odom_ground", Odometry, qos.TELEMETRY)
        diag = rover.publisher("/ground/diagnostics", DiagnosticArray, qos.DIAGNOSTICS)
        assert odom.wait_for_subscribers(1) and ground_pose.wait_for_subscribers(1)
        assert diag.wait_for_subscribers(1)
        # The rover is at (2, 3.5, 30 deg) on the map; odometry, started elsewhere, says
        # (0.5, 0.2, 10 deg): map -> odom must carry the difference.
        ground_pose.publish(_odom(2.0, 3.5, 30.0))
        assert heard.wait(10)
        odom.publish(_odom_frame(0.5, 0.2, 10.0))
        diag.publish(diagnostic_array(BASE, stamp(), statuses=["ready"]))
        deadline = time.monotonic() + 10
        while "/tf" not in recorder.counts or "/ground/diagnostics" not in recorder.counts:
            assert time.monotonic() < deadline, recorder.counts
            time.sleep(0.02)

    decoded: dict[str, list[Any]] = {}
    with path.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for schema, channel, _message, msg in reader.iter_decoded_messages():
            assert schema is not None
            decoded.setdefault(channel.topic, []).append((schema.name, msg))
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}

    [(kind, tf)] = decoded["/tf"]
    assert kind == "tf2_msgs/msg/TFMessage"
    frames = [(t.header.frame_id, t.child_frame_id) for t in tf.transforms]
    assert frames == [("map", "odom"), ("odom", "base_link")]
    m_o, o_b = tf.transforms

    def yaw(q: Any) -> float:
        return math.degrees(2 * math.atan2(q.z, q.w))

    # map -> odom composed with odom -> base_link is the map pose.
    a = math.radians(yaw(m_o.transform.rotation))
    bx, by = o_b.transform.translation.x, o_b.transform.translation.y
    x = m_o.transform.translation.x + math.cos(a) * bx - math.sin(a) * by
    y = m_o.transform.translation.y + math.sin(a) * bx + math.cos(a) * by
    assert (x, y) == pytest.approx((2.0, 3.5), abs=1e-9)
    assert yaw(m_o.transform.rotation) + yaw(o_b.transform.rotation) == pytest.approx(30.0)

    [(kind, map_markers)] = decoded["/map/markers"]
    assert kind == "visualization_msgs/msg/MarkerArray"
    texts = {m.text for m in map_markers.markers if m.type == 9}
    assert {o.id for o in world.obstacles} | {"start", "goal"} <= texts
    [(_, plans)] = decoded["/gate/plan_markers"]
    assert any(m.type == 2 for m in plans.markers)  # the collision, a sphere
    assert any("collision with table" in m.text for m in plans.markers)
    [(kind, diagnostics)] = decoded["/ground/diagnostics"]
    assert kind == "diagnostic_msgs/msg/DiagnosticArray"
    assert [s.name for s in diagnostics.status][:2] == [
        "rover_bridge: link",
        "rover_bridge: controller",
    ]

    assert metadata["map"]["name"] == "lab"
    assert "table" in metadata["map"]["obstacles"]
    verdicts = json.loads(metadata["planning-1"]["verdicts"])
    assert [v["approved"] for v in verdicts][-1] is True
    assert verdicts[0]["collision"]["obstacle"] == "table"
    assert json.loads(metadata["planning-1"]["plans"])[0]["commands"]
    assert metadata["mission"] == {"plannings": "1"}


def test_without_the_record_extra_rover_go_refuses_to_record(tmp_path: Path) -> None:
    """MCAP is optional (the ``record`` extra): the check names what is missing, and
    ``rover go --record`` refuses at once (exit 2) instead of failing mid-mission."""
    from planner.record.mcaprec import recording_unavailable

    assert recording_unavailable() == ""
    hide = "import sys; sys.modules['mcap_ros2'] = None; "
    check = subprocess.run(
        [sys.executable, "-c", hide + "from planner.record.mcaprec import recording_unavailable"
         "; print(recording_unavailable())"],
        capture_output=True, text=True, timeout=60, check=True,
    )  # fmt: skip
    assert check.stdout.strip() == (
        "MCAP recording needs mcap_ros2: pip install 'rover-hil[record]'"
    )
    go = subprocess.run(
        [sys.executable, "-c", hide + "from firmware_proto.cli import main; sys.exit(main())",
         "go", "--goal", "2,3,0", "--record", str(tmp_path / "x.mcap")],
        check=False, capture_output=True, text=True, timeout=60, cwd=tmp_path,
    )  # fmt: skip
    assert go.returncode == 2, go.stderr
    assert "rover go: --record: MCAP recording needs mcap_ros2" in go.stderr
    assert not (tmp_path / "x.mcap").exists()
