"""Bridge parameters (precedence, validation) and the odometry estimator (pure)."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from bridge.errors import ParameterError
from bridge.link.odometry import OdometryEstimator, ground_pose, unwrap24
from bridge.ros.params import BridgeParams, load_params, parameter_specs
from firmware_proto.model.rover import RoverDescription
from firmware_proto.wire.messages import Encoders, Imu, PoseMsg


def test_precedence_overrides_env_file_defaults(tmp_path: Path) -> None:
    file = tmp_path / "bridge.toml"
    file.write_text(
        '[rover_bridge.ros__parameters]\ndevice = "/dev/from-file"\nbaud = 57600\nnode_id = 4\n'
    )
    env = {"ROVER_BRIDGE_BAUD": "38400", "ROVER_BRIDGE_NODE_ID": "5", "OTHER": "x"}
    params = load_params({"node_id": 6, "baud": None}, env=env, file=file)
    assert (params.device, params.baud, params.node_id) == ("/dev/from-file", 38400, 6)
    assert params.url == "/dev/from-file?baud=38400"
    assert load_params(env={}).url == BridgeParams().device
    can = load_params({"can_interface": "socketcan", "can_channel": "vcan0", "node_id": 3}, env={})
    assert can.url == "can://socketcan/vcan0?node=3"


@pytest.mark.parametrize(
    ("values", "complaint"),
    [
        ({"node_id": 16}, "node_id"),
        ({"baud": "fast"}, "baud"),
        ({"ack_timeout_s": float("nan")}, "ack_timeout_s"),
        ({"ros_backend": "ros1"}, "ros_backend"),
        ({"speed": 1}, "unknown parameter 'speed'"),
        ({"reconnect_min_s": 5.0, "reconnect_max_s": 1.0}, "reconnect_max_s"),
        ({"topic_odom": ""}, "topic_odom"),
        ({"auto_clear_watchdog": "maybe"}, "auto_clear_watchdog"),
    ],
)
def test_bad_parameters_name_themselves(values: dict[str, object], complaint: str) -> None:
    with pytest.raises(ParameterError, match=complaint):
        load_params(values, env={})


def test_every_parameter_is_declared_with_a_description_and_its_range() -> None:
    params = load_params({"device": "/dev/ttyACM0", "heartbeat_hz": 20.0}, env={})
    specs = {spec.name: spec for spec in parameter_specs(params)}
    assert set(specs) == set(params.to_dict())
    assert all(spec.description for spec in specs.values())
    device, rate, node = specs["device"], specs["heartbeat_hz"], specs["node_id"]
    assert (device.default, device.read_only) == ("/dev/ttyACM0", True)
    assert (rate.default, rate.read_only, rate.range) == (20.0, False, (1.0, 100.0))
    assert (node.range, node.read_only) == ((1, 15), True)
    beats = specs["link_lost_beats"]
    assert (beats.default, beats.range, beats.read_only) == (3, (1, 100), True)
    slow = load_params({"device": "/dev/ttyACM0", "link_lost_beats": 10}, env={})
    assert slow.link_config().link_lost_beats == 10
    with pytest.raises(ParameterError, match="link_lost_beats"):
        load_params({"link_lost_beats": 0}, env={})
    runtime = {name for name, spec in specs.items() if not spec.read_only}
    assert runtime == {
        "heartbeat_hz",
        "ack_timeout_s",
        "motion_retries",
        "reconnect_min_s",
        "reconnect_max_s",
        "auto_clear_watchdog",
        "odom_frame",
        "map_frame",
        "base_frame",
        "diagnostics_hz",
    }


def test_unwrap24_handles_wraparound() -> None:
    assert unwrap24((1 << 23) - 10, -(1 << 23) + 5) == 15
    assert unwrap24(-(1 << 23) + 5, (1 << 23) - 10) == -15
    assert unwrap24(100, 50) == -50


def test_estimator_fuses_gyro_heading_with_encoder_distance(rover: RoverDescription) -> None:
    est = OdometryEstimator(rover)
    rate = 0.5  # rad/s, counter-clockwise
    est.update_encoders(Encoders(0, 0, 0))
    left = right = 0
    for i in range(1, 101):  # 2 s at 50 Hz, 0.1 m/s forward while turning
        t = i * 20
        est.update_imu(Imu(t, round(rate * 1000), 0, 0))
        left += 46
        right += 46
        out = est.update_encoders(Encoders(t, left, right))
    assert out.heading_source == "imu"
    assert out.yaw_rad == pytest.approx(1.0, abs=0.02)
    assert out.distance_m == pytest.approx(0.2, abs=0.001)
    radius = 0.1 / rate
    assert out.x_m == pytest.approx(radius * math.sin(1.0), abs=0.01)
    assert out.y_m == pytest.approx(radius * (1 - math.cos(1.0)), abs=0.01)
    assert out.var_xy_m2 > 0 and out.var_yaw_rad2 > 0


def test_estimator_falls_back_to_encoders_without_imu(rover: RoverDescription) -> None:
    est = OdometryEstimator(rover)
    est.update_encoders(Encoders(0, 0, 0))
    out = est.update_encoders(Encoders(500, -2000, 2000))  # a spin, no gyro for 0.5 s
    assert out.heading_source == "encoders"
    expected = (4000 / 23000) / rover.geometry.track_width_m * rover.traction.turn_efficiency
    assert out.yaw_rad == pytest.approx(expected)


def test_estimator_ignores_a_counter_reset(rover: RoverDescription) -> None:
    est = OdometryEstimator(rover)
    est.update_encoders(Encoders(0, 100_000, 100_000))
    out = est.update_encoders(Encoders(20, 0, 0))  # controller rebooted
    assert out.distance_m == 0 and est.resets == 1


def test_ground_pose_conversion_and_no_fix() -> None:
    pose = ground_pose(PoseMsg(1500, -250, 900, 2, 25))
    assert pose is not None
    assert (pose.x_m, pose.y_m, pose.sigma_m, pose.age_s) == (1.5, -0.25, 0.02, 0.1)
    assert pose.yaw_rad == pytest.approx(math.pi / 2)
    assert ground_pose(PoseMsg(0, 0, 0, 0, 0)) is None


def test_estimator_rebases_on_a_new_boot_nonce(rover: RoverDescription) -> None:
    est = OdometryEstimator(rover)
    assert est.observe_boot(0x1111) is False  # the first nonce seen: nothing to re-base
    est.update_encoders(Encoders(0, 0, 0))
    est.update_encoders(Encoders(20, 4600, 4600))  # 0.2 m
    assert est.observe_boot(0x1111) is False
    assert est.observe_boot(0x2222) is True  # rebooted: counts restart
    assert est.update_encoders(Encoders(5, 0, 0)).x_m == pytest.approx(0.2)
    assert est.update_encoders(Encoders(25, 2300, 2300)).x_m == pytest.approx(0.3)
    assert (est.reboots, est.resets) == (1, 0)
