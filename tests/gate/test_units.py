"""Pure parts of the gate: body framing and JSON, options, configuration, verdict data,
goal errors, exports; and what must not be imported until it is needed."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import pytest

from emulator.twin import GATE_DT_S
from firmware_proto.http.bindpolicy import is_loopback
from firmware_proto.model.pose import Pose
from firmware_proto.model.verdict import Verdict
from gate.config import (
    DEFAULT_DT_S,
    KEYS,
    GateConfig,
    PlaybackSettings,
    load_config,
)
from gate.errors import (
    BadRequestError,
    GateConfigError,
    LengthRequiredError,
    OptionError,
    PayloadTooLargeError,
    UnsupportedMediaError,
)
from gate.goal import approach_heading_rad, goal_error
from gate.options import ValidateOptions
from gate.request import check_declared_length, check_json_media_type, parse_json

# -- request ---------------------------------------------------------------------------


def test_declared_length_and_limits() -> None:
    assert check_declared_length({"content-length": "12"}, 100) == 12
    assert check_declared_length({"transfer-encoding": "chunked"}, 100) is None
    with pytest.raises(LengthRequiredError):
        check_declared_length({}, 100)
    with pytest.raises(PayloadTooLargeError):
        check_declared_length({"content-length": "101"}, 100)


def test_media_type_and_strict_json() -> None:
    check_json_media_type("application/json")
    check_json_media_type("Application/JSON; charset=utf-8")
    for bad in (None, "text/json", "application/json; charset=utf-16"):
        with pytest.raises(UnsupportedMediaError):
            check_json_media_type(bad)
    assert parse_json(b'{"a": [1, 2.5]}') == {"a": [1, 2.5]}
    deep = b"[" * 33 + b"]" * 33  # one level past the limit
    deeper = b"[" * 100_000 + b"]" * 100_000  # past the parser's own stack
    assert parse_json(b"[" * 32 + b"]" * 32) is not None
    for text in (b"{", b"[Infinity]", b'{"a":1,"a":2}', b"\xc3", deep, deeper):
        with pytest.raises(BadRequestError) as info:
            parse_json(text)
        assert info.value.code == "not_json"


# -- options and configuration ----------------------------------------------------------


def test_options_round_trip_through_the_query() -> None:
    options = ValidateOptions.from_query(
        "map=scn02&start=1.5,-2,90&render=true&margin_m=0.05&pos_tol_m=0.2&yaw_tol_deg=5"
        "&sample_hz=20"
    )
    assert options.start is not None and options.start.yaw_deg == 90.0
    assert options.render and options.safety_margin_m == 0.05
    assert ValidateOptions.from_query(options.to_query()) == options
    assert ValidateOptions.from_query("") == ValidateOptions()
    measured = ValidateOptions.from_query("samples=8&start_sigma_m=0.001&start_sigma_deg=0.05")
    assert (measured.start_sigma_m, measured.start_sigma_deg) == (0.001, 0.05)
    assert ValidateOptions.from_query(measured.to_query()) == measured
    pinned = measured.resolve(PlaybackSettings(), "lab").to_query(Pose(0.0, 0.0, 0.0))
    assert "start_sigma_m=0.001&start_sigma_deg=0.05" in pinned
    resolved = ValidateOptions(map="scn01").resolve(PlaybackSettings(), "lab")
    assert resolved.map == "scn01"
    assert resolved.safety_margin_m == PlaybackSettings().safety_margin_m
    with pytest.raises(OptionError) as info:
        ValidateOptions(sample_hz=500.0).resolve(PlaybackSettings(), "lab")
    assert info.value.parameter == "sample_hz"
    for query in ("a", "start=1,2,3&&", "margin_m=1_0", "margin_m= 1", "start=1,,2"):
        with pytest.raises(OptionError):
            ValidateOptions.from_query(query)


def test_option_error_survives_pickling() -> None:
    import pickle

    error = pickle.loads(pickle.dumps(OptionError("start", "outside the map")))
    assert (error.parameter, str(error)) == ("start", "start: outside the map")


def test_config_precedence_arguments_environment_file_defaults(tmp_path: Path) -> None:
    toml = tmp_path / "gate.toml"
    toml.write_text('[gate]\nport = 9000\nworkers = 3\nsafety_margin_m = 0.2\npool = "thread"\n')
    env = {"ROVER_GATE_PORT": "9100", "ROVER_GATE_YAW_TOLERANCE_DEG": "4"}
    config = load_config({"port": 9200, "workers": None}, env, toml)
    assert config.port == 9200  # argument
    assert config.workers == 3  # file (the None argument counts as not given)
    assert config.playback.yaw_tolerance_deg == 4.0  # environment
    assert config.playback.safety_margin_m == 0.2  # file
    assert config.playback.position_tolerance_m == 0.10  # default
    assert load_config({}, env, toml).port == 9100  # environment beats file
    assert load_config({}, {"ROVER_GATE_CONFIG": str(toml)}).port == 9000
    assert "token" not in repr(load_config({"token": "secret"}, {}))
    with pytest.raises(GateConfigError, match="unknown"):
        load_config({"colour": "red"}, {})
    with pytest.raises(GateConfigError, match="ROVER_GATE_PORT"):
        load_config({}, {"ROVER_GATE_PORT": "eighty"})
    toml.write_text("[gate]\nport = true\n")
    with pytest.raises(GateConfigError, match="wrong type"):
        load_config({}, {}, toml)
    assert set(KEYS) >= {"host", "port", "token", "dt_s", "allowed_hosts"}
    names = {"ROVER_GATE_ALLOWED_HOSTS": " gate.lab, rover-ground ,"}
    assert load_config({}, names).allowed_hosts == ("gate.lab", "rover-ground")
    toml.write_text('[gate]\nallowed_hosts = ["gate.lab"]\n')
    assert load_config({}, {}, toml).allowed_hosts == ("gate.lab",)
    toml.write_text('[gate]\nallowed_hosts = "gate.lab"\n')
    with pytest.raises(GateConfigError, match="wrong type"):
        load_config({}, {}, toml)


def test_bind_policy_and_ranges() -> None:
    assert is_loopback("127.0.0.1") and is_loopback("::1") and is_loopback("localhost")
    assert not is_loopback("0.0.0.0") and not is_loopback("10.0.0.1")
    assert not is_loopback("gate.example")
    with pytest.raises(GateConfigError, match="without a token"):
        GateConfig(host="0.0.0.0")
    assert GateConfig(host="0.0.0.0", token="k3Jf9-xQ2mPz8vLw").host == "0.0.0.0"
    with pytest.raises(GateConfigError, match="too weak"):
        GateConfig(host="0.0.0.0", token="t")
    for bad in ({"workers": 0}, {"queue_depth": -1}, {"pool": "fibres"}, {"port": 70000}):
        with pytest.raises(GateConfigError):
            GateConfig(**bad)
    for bad_pb in ({"dt_s": 0.05}, {"safety_margin_m": -1.0}, {"yaw_tolerance_deg": 0.0}):
        with pytest.raises(GateConfigError):
            PlaybackSettings(**bad_pb)


def test_the_gate_step_is_the_one_the_twin_recommends() -> None:
    assert DEFAULT_DT_S == GATE_DT_S


# -- goal errors ---------------------------------------------------------------------------


def test_goal_error_signs() -> None:
    east = 0.0
    err = goal_error((1.0, 0.0, 10.0), (2.0, 0.5, -10.0), east)
    assert err.longitudinal_m == pytest.approx(1.0)  # short of the goal
    assert err.lateral_m == pytest.approx(0.5)  # goal to the left
    assert err.distance_m == pytest.approx(math.hypot(1.0, 0.5))
    assert err.yaw_deg == pytest.approx(-20.0)
    assert goal_error((3.0, 0.0, 0.0), (2.0, 0.0, 0.0), east).longitudinal_m == pytest.approx(-1.0)
    # Approach heading: last FWD (as is) or REV (reversed); else the bearing to the goal.
    assert approach_heading_rad([1, 3], [0.5, 0.9], (0, 0, 0), (1, 1)) == 0.5
    assert approach_heading_rad([2], [0.5], (0, 0, 0), (1, 1)) == pytest.approx(0.5 + math.pi)
    assert approach_heading_rad([3], [0.0], (0, 0, 0.3), (0, 2)) == pytest.approx(math.pi / 2)
    assert approach_heading_rad([], [], (0, 0, 0.3), (0, 0)) == 0.3


# -- data types and exports -------------------------------------------------------------------


def test_verdict_round_trips(validator: object) -> None:
    from firmware_proto.model.plan import Plan
    from gate.validator import Validator

    assert isinstance(validator, Validator)
    plan = Plan.from_dict(
        {
            "goal": {"x": 6.2, "y": 3.0, "yaw_deg": 0},
            "commands": [{"command": "FWD", "speed": 60, "distance": 30000}] * 3,
        }
    )
    verdict = validator.validate(plan, ValidateOptions().resolve(validator.settings, "lab"))
    assert Verdict.from_dict(verdict.to_dict()) == verdict
    keys = list(verdict.to_dict())
    assert keys[0] == "approved" and keys[-1] == "wall_time_s"
    assert "image_png_base64" not in keys


def test_importing_the_data_types_does_not_load_the_twin_or_pillow() -> None:
    code = (
        "import sys, gate, gate.options, gate.errors, gate.config; "
        "heavy = [m for m in ('pymunk', 'PIL', 'gate.server', 'gate.render', 'uvicorn', "
        "'starlette') if m in sys.modules]; "
        "print(heavy)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_validation_without_a_picture_does_not_load_pillow() -> None:
    code = (
        "import sys\n"
        "from firmware_proto.model.plan import Plan\n"
        "from gate.config import GateConfig\n"
        "from gate.options import ValidateOptions\n"
        "from gate.validator import Validator\n"
        "v = Validator.from_config(GateConfig())\n"
        "p = Plan.from_dict({'goal': {'x': 2, 'y': 3, 'yaw_deg': 0},"
        " 'commands': [{'command': 'FWD', 'speed': 40, 'distance': 9000}]})\n"
        "v.validate(p, ValidateOptions().resolve(v.settings, 'lab'))\n"
        "print('PIL' in sys.modules, 'gate.render' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False False"
