"""The plan uplink's codec, authentication and fit check (firmware_proto/model/uplink.py),
and the onboard report's codec (firmware_proto/model/downlink.py)."""

from __future__ import annotations

import json
import math
from dataclasses import replace
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_proto.errors import UplinkError
from firmware_proto.model.downlink import GuardStop, OnboardReport, RestReport, decode_report
from firmware_proto.model.pose import Pose
from firmware_proto.model.rover import load_rover
from firmware_proto.model.uplink import (
    MAX_UPLINK_BYTES,
    REFUSALS,
    CancelUplink,
    DriftLimits,
    PlanUplink,
    PredictedSample,
    UplinkAck,
    check_fit,
    decode_ack,
    decode_uplink,
    verdict_digest,
)
from firmware_proto.wire.messages import Command

ROVER = load_rover(None)
TOKEN = "s3cret"
FWD, LEFT = int(Command.FWD), int(Command.LEFT)


def _uplink(plan_id: int = 7, **changes: Any) -> PlanUplink:
    """A two-step plan (1 m forward, a quarter turn left) with a plausible prediction."""
    quarter = ROVER.turn_units_for_yaw(math.pi / 2)
    samples = [PredictedSample(0, 0.1 * i, 0.1 * i, 0.0, 0.0) for i in range(11)]
    samples += [PredictedSample(1, 0.0, 1.0, 0.0, 0.0)]
    samples += [PredictedSample(1, 0.2 * i, 1.0, 0.0, 9.0 * i) for i in range(1, 11)]
    fields: dict[str, Any] = {
        "plan_id": plan_id,
        "steps": ((FWD, 30, 23000), (LEFT, 30, quarter)),
        "durations_s": (1.0, 2.0),
        "prediction": tuple(samples),
        "start": Pose(0.0, 0.0, 0.0),
        "goal": Pose(1.0, 0.0, 90.0),
        "limits": DriftLimits.of(ROVER),
        "verdict": "a" * 64,
        "boot": "b" * 32,
    }
    fields.update(changes)
    return PlanUplink(**fields)


def _body(env: str) -> dict[str, Any]:
    body: dict[str, Any] = json.loads(json.loads(env)["body"])
    return body


def _reenvelope(body: dict[str, Any], token: str | None = TOKEN) -> str:
    from firmware_proto.model.uplink import sign

    text = json.dumps(body)
    return json.dumps({"body": text, "tag": sign(text.encode(), token) if token else None})


def test_a_signed_plan_reads_back_as_it_was_sent() -> None:
    up = _uplink()
    back = decode_uplink(up.envelope(TOKEN), token=TOKEN, rover=ROVER)
    assert back == up
    assert check_fit(up, ROVER) == []


def test_a_cancel_reads_back() -> None:
    assert decode_uplink(CancelUplink(12).envelope(TOKEN), token=TOKEN) == CancelUplink(12)


@pytest.mark.parametrize(
    ("mutate", "reason", "words"),
    [
        (lambda b: b.pop("steps"), "malformed", "body.steps: missing"),
        (lambda b: b.update(extra=1), "malformed", "unexpected field(s) extra"),
        (lambda b: b.update(plan_id="7"), "malformed", "body.plan_id: not an integer"),
        (lambda b: b.update(plan_id=0), "out_of_range", "body.plan_id: 0 not in"),
        (lambda b: b["steps"][0].__setitem__(1, 61), "out_of_range", "speed 61 not in 0..60"),
        (lambda b: b["steps"][0].__setitem__(0, 9), "out_of_range", "command 9"),
        (lambda b: b.update(steps=[]), "out_of_range", "0 steps"),
        (lambda b: b["limits"].update(linear_m=0.5), "out_of_range", "never looser"),
        (lambda b: b["limits"].update(angular_deg=0.0), "out_of_range", "angular_deg 0"),
        (lambda b: b.update(version=1), "unsupported_version", "this rover reads 2"),
        (lambda b: b.update(type="dance"), "malformed", "neither 'plan' nor 'cancel'"),
        (lambda b: b.update(verdict="XYZ"), "malformed", "SHA-256"),
        (lambda b: b["prediction"][3].__setitem__(2, "x"), "malformed", "not a number"),
        (lambda b: b.update(durations_s=[1.0]), "prediction_mismatch", "1 durations for 2"),
        (lambda b: b["prediction"].pop(0), "prediction_mismatch", "start at step 0"),
        (
            lambda b: b["prediction"].__setitem__(5, [0, 0.35, 0.5, 0.0, 0.0]),
            "prediction_mismatch",
            "time goes back",
        ),
        (
            lambda b: b["steps"].__setitem__(0, [FWD, 30, 2300]),
            "prediction_mismatch",
            "predicted to move 1.00 m, its wheels travel 0.10 m",
        ),
        (
            lambda b: b["steps"].__setitem__(1, [int(Command.RIGHT), 30, b["steps"][1][2]]),
            "prediction_mismatch",
            "turn the other way",
        ),
        (
            lambda b: b["steps"].__setitem__(0, [int(Command.REV), 30, 23000]),
            "prediction_mismatch",
            "the other way",
        ),
        (
            lambda b: b.update(start={"x": 1.0, "y": 0.0, "yaw_deg": 0.0}),
            "prediction_mismatch",
            "start pose",
        ),
    ],
)
def test_a_bad_plan_is_refused_with_its_specific_reason(
    mutate: Any, reason: str, words: str
) -> None:
    body = _body(_uplink().envelope(TOKEN))
    mutate(body)
    with pytest.raises(UplinkError) as caught:
        decode_uplink(_reenvelope(body), token=TOKEN, rover=ROVER)
    assert caught.value.reason == reason
    assert reason in REFUSALS
    assert words in caught.value.detail


def test_authentication() -> None:
    env = _uplink().envelope(TOKEN)
    with pytest.raises(UplinkError, match="bad_tag"):
        decode_uplink(env, token="another", rover=ROVER)
    with pytest.raises(UplinkError, match="unauthenticated"):
        decode_uplink(_uplink().envelope(None), token=TOKEN, rover=ROVER)
    # A rover without a token cannot check, and takes a tagged or untagged one.
    assert decode_uplink(env, token=None, rover=ROVER) == _uplink()
    # Any change after signing breaks the tag, even a valid one.
    changed = json.loads(env)
    changed["body"] = changed["body"].replace('"plan_id":7', '"plan_id":8')
    with pytest.raises(UplinkError) as caught:
        decode_uplink(json.dumps(changed), token=TOKEN, rover=ROVER)
    assert caught.value.reason == "bad_tag"


@pytest.mark.parametrize("tag", ["\u00e9" * 64, "A" * 64, "ab", "0" * 65, "g" * 64])
def test_a_tag_that_is_not_64_lower_case_hex_digits_is_refused_not_raised(tag: str) -> None:
    """A non-ASCII tag made hmac.compare_digest raise TypeError out of the decoder (review
    A14): no answer, no refusal on command_status."""
    env = json.dumps({"body": json.loads(_uplink().envelope(TOKEN))["body"], "tag": tag})
    with pytest.raises(UplinkError) as caught:
        decode_uplink(env, token=TOKEN, rover=ROVER)
    assert caught.value.reason == "bad_tag"


def test_the_boot_id_is_signed_and_checked_for_form() -> None:
    """A plan is bound to one run of the onboard program: its boot id is in the signed
    body (so it cannot be changed on the way), and must be a boot id or empty."""
    up = _uplink()
    assert decode_uplink(up.envelope(TOKEN), token=TOKEN, rover=ROVER) == up  # boot and all
    env = json.loads(up.envelope(TOKEN))
    env["body"] = env["body"].replace("b" * 32, "c" * 32)
    with pytest.raises(UplinkError) as caught:
        decode_uplink(json.dumps(env), token=TOKEN, rover=ROVER)
    assert caught.value.reason == "bad_tag"
    body = _body(up.envelope(TOKEN))
    body["boot"] = "not a boot"
    with pytest.raises(UplinkError) as caught:
        decode_uplink(_reenvelope(body), token=TOKEN, rover=ROVER)
    assert caught.value.reason == "malformed" and "body.boot" in caught.value.detail
    body["boot"] = ""
    assert decode_uplink(_reenvelope(body), token=TOKEN, rover=ROVER) == replace(up, boot="")


def test_the_cheap_look_reads_the_id_and_type_of_an_authentic_body() -> None:
    from firmware_proto.model.uplink import open_envelope, peek_body

    body = open_envelope(_uplink(41).envelope(TOKEN), TOKEN)
    assert peek_body(body) == (41, "plan")
    assert peek_body(open_envelope(CancelUplink(9).envelope(TOKEN), TOKEN)) == (9, "cancel")
    assert peek_body("[1]") == (0, "") and peek_body("{not json") == (0, "")
    assert peek_body('{"plan_id": true, "type": 3}') == (0, "")


@pytest.mark.parametrize(
    ("text", "reason"),
    [
        ("", "malformed"),
        ("[]", "malformed"),
        ('{"body": 3, "tag": null}', "malformed"),
        ('{"body": "{}", "tag": 5}', "malformed"),
        ('{"body": "nope", "tag": null}', "malformed"),
        ('{"body": "{}", "tag": null, "x": 1}', "malformed"),
        ("x" * (MAX_UPLINK_BYTES + 1), "too_large"),
    ],
)
def test_garbage_is_refused_not_raised_through(text: str, reason: str) -> None:
    with pytest.raises(UplinkError) as caught:
        decode_uplink(text, rover=ROVER)
    assert caught.value.reason == reason


@settings(max_examples=100, deadline=None)
@given(st.binary(max_size=300))
def test_any_bytes_are_refused_with_an_uplink_error_or_read(data: bytes) -> None:
    reason = ""
    try:
        decode_uplink(data, token=TOKEN, rover=ROVER)
    except UplinkError as exc:
        reason = exc.reason
    assert reason in REFUSALS  # garbage is always refused, never read


@settings(max_examples=50, deadline=None)
@given(
    st.integers(1, 2**62),
    st.floats(0.01, 0.25),
    st.floats(0.5, 12.0),
    st.integers(1, 60),
)
def test_round_trip(plan_id: int, linear: float, angular: float, speed: int) -> None:
    up = _uplink(
        plan_id,
        limits=DriftLimits(linear, angular),
        steps=((FWD, speed, 23000), (LEFT, speed, ROVER.turn_units_for_yaw(math.pi / 2))),
    )
    assert decode_uplink(up.envelope(TOKEN), token=TOKEN) == up


def test_the_prediction_is_interpolated_per_step() -> None:
    up = _uplink()
    assert up.pose_at(-1, 0.0) == Pose(0.0, 0.0, 0.0)
    assert up.pose_at(0, 0.55).x == pytest.approx(0.55)
    assert up.pose_at(0, 9.0).x == pytest.approx(1.0)  # held at the step's end
    assert up.pose_at(1, 1.0).yaw_deg == pytest.approx(45.0)
    with pytest.raises(IndexError):
        up.pose_at(5, 0.0)


def test_the_verdict_digest_ignores_the_wall_time_only() -> None:
    a = {"approved": True, "steps": [1, 2], "wall_time_s": 0.1}
    b = {"steps": [1, 2], "approved": True, "wall_time_s": 9.9}
    assert verdict_digest(a) == verdict_digest(b)
    assert verdict_digest(a) != verdict_digest({**a, "approved": False})
    assert len(verdict_digest(a)) == 64


def test_acks_read_back_and_say_whether_the_plan_is_taken() -> None:
    for result, taken in (("accepted", True), ("duplicate", True), ("refused", False)):
        ack = UplinkAck(5, result, "stale" if result == "refused" else "", "why", "running")
        assert decode_ack(ack.to_json()) == ack
        assert ack.taken is taken
    with pytest.raises(UplinkError, match="result"):
        decode_ack('{"plan_id":1,"result":"maybe","reason":"","detail":"","state":""}')


def test_reports_read_back() -> None:
    guard = GuardStop(2, 10.0, 10.01, Pose(1, 2, 3), Pose(1, 2.3, 3), 0.3, 0.5, 0.05)
    rest = RestReport(10.4, Pose(1, 2.35, 4), tuple(float(i) for i in range(9)), True, 0.06, 0.4)
    report = OnboardReport(
        3, "rest", 10.5, 7, "a" * 64, "stopped", 2, 4, "aborted:stop", 0.3, 0.5, "guard",
        guard.reason, guard, rest, {"worst_linear_m": 0.31}, "c" * 32,
    )  # fmt: skip
    assert decode_report(report.to_json()) == report
    assert json.loads(report.to_json())["boot"] == "c" * 32
    moved = report.shifted(100.0)
    assert (moved.t_s, moved.guard.stamp_s, moved.guard.stop_s) == (110.5, 110.0, 110.01)  # type: ignore[union-attr]
    assert moved.rest.stamp_s == 110.4 and moved.rest.pose == rest.pose  # type: ignore[union-attr]
    assert report.ended
    assert "plan 7: stopped, step 3/4" in report.line()
    with pytest.raises(UplinkError):
        decode_report('{"seq": 1}')
    with pytest.raises(UplinkError):
        decode_report(report.to_json().replace('"stopped"', '"dancing"'))
