"""The plan uplink: what the ground sends the rover once a plan is approved, and what the
rover answers. The fields, the tokens and the refusals are in docs/onboard.md.

A plan (:class:`PlanUplink`) carries what the rover needs to run and guard it by itself:
its id (positive, growing across ground restarts; the rover runs an id at most once and
refuses one not newer than the last it took), the steps, the twin's durations and
predicted trajectory, the drift limits (never looser than the rover's ``[safety]``), the
approved verdict's identity and the boot id of the onboard program it is for. A cancel
(:class:`CancelUplink`) drops every plan with an id up to ``upto`` (the one running is
stopped). Both travel in an envelope ``{"body": "<JSON text>", "tag": "<hex>" | null}``,
the tag HMAC-SHA256 of the body's bytes under the uplink token (:data:`TOKEN_ENV`, never
the gate's), checked before the body is parsed.

Pure, no I/O, no clock. The codec validates strictly and refuses with a specific reason
(:class:`UplinkError`), never a traceback, in two parts so that the rover answers copies
cheaply: :func:`open_envelope` and :func:`peek_body`, then :func:`decode_body`.
"""

from __future__ import annotations

import bisect
import hashlib
import hmac
import itertools
import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Final

from firmware_proto.errors import UplinkError
from firmware_proto.model.geometry import wrap_deg
from firmware_proto.model.plan import MAX_PLAN_STEPS
from firmware_proto.model.pose import Pose
from firmware_proto.model.rover import RoverDescription
from firmware_proto.wire.messages import Command

__all__ = [
    "ACK_RESULTS",
    "BOOT_HEX_DIGITS",
    "MAX_PREDICTION_SAMPLES",
    "MAX_UPLINK_BYTES",
    "REFUSALS",
    "REFUSED_FOR_NOW",
    "TOKEN_ENV",
    "UPLINK_VERSION",
    "CancelUplink",
    "DriftLimits",
    "PlanUplink",
    "PredictedSample",
    "UplinkAck",
    "check_fit",
    "decode_ack",
    "decode_body",
    "decode_uplink",
    "is_boot_id",
    "open_envelope",
    "peek_body",
    "sign",
    "token_from_env",
    "verdict_digest",
]

UPLINK_VERSION: Final = 2
"""Uplink format version (2: a plan names its ``boot``); another is ``unsupported_version``."""
BOOT_HEX_DIGITS: Final = 32
"""A boot id: this many lower-case hex digits (128 random bits)."""
_TAG_HEX_DIGITS: Final = 64
MAX_UPLINK_BYTES: Final = 512 * 1024
"""Largest envelope taken, bytes (a 12-step plan at 10 samples a second is ~40 KiB)."""
MAX_PREDICTION_SAMPLES: Final = 6000
"""Most prediction samples taken (12 steps of the longest the playback allows, 10 Hz)."""
MAX_PLAN_ID: Final = (1 << 63) - 1

REFUSALS: Final[dict[str, str]] = {
    "malformed": "not the uplink's JSON: a field missing, of the wrong type, or extra",
    "out_of_range": "a value outside its range (a step, a limit looser than the rover's)",
    "unauthenticated": "no tag, and the rover has a token",
    "bad_tag": "the tag does not match the body under the rover's token",
    "prediction_mismatch": "the predicted trajectory does not fit the steps",
    "too_large": "more bytes or samples than the rover takes",
    "unsupported_version": "a format version this rover does not read",
    "busy": "another plan is armed or running on board",
    "stale": "an id not newer than the last plan the rover took (a replay)",
    "cancelled": "the ground cancelled every plan up to this id",
    "latched": "the rover is latched by a STOP that is not its own guard's",
    "other_boot": "signed for another run of the rover's onboard program (a restart, "
    "another rover)",
    "no_fix": "no recent ground-seeing POSE fix: drift control needs one",
    "start_mismatch": "the plan starts further than the drift limits from the rover's estimate",
}
"""Why the rover refuses an uplink: each reason's code and meaning (the first seven come
from this module, the rest from the rover's sequencer, ``bridge/onboard/core.py``)."""
REFUSED_FOR_NOW: Final = frozenset({"busy", "latched", "no_fix"})
"""Refusals that hold only for now: the ground resends the same uplink (within its budget); every
other refusal is for good (the ground re-plans or gives up)."""

ACK_RESULTS: Final = ("accepted", "duplicate", "refused", "cancelled")
"""The results an :class:`UplinkAck` can carry."""

_COMMANDS: Final = {int(c) for c in Command}
_PLAN_KEYS: Final = {
    "type",
    "version",
    "plan_id",
    "steps",
    "durations_s",
    "prediction",
    "start",
    "goal",
    "limits",
    "verdict",
    "boot",
}
_CANCEL_KEYS: Final = {"type", "version", "upto"}
_POSE_TOL_M: Final = 0.01
"""Consecutive steps' boundary samples agree within this, m (the gate writes the pose twice)."""
_START_TOL_M: Final = 0.01
_START_TOL_DEG: Final = 0.5
_DRIVE_SLACK_M: Final = 0.05
"""A drive may be predicted this much longer than its wheel travel (settling), m."""
_SPIN_MOVE_M: Final = 0.3
"""A spin in place may move the rover's centre this much, m (skid, settling)."""
_LEAST_SHARE: Final = 0.2
"""A step the gate approved is predicted to do at least this share of what its wheels do
(a drive's distance, a spin's ideal turn): less is another step's prediction."""
_SETTLE_S: Final = 2.0
"""The last step's samples may run this much past its duration (settling), twin s."""


def _canonical(obj: Any) -> bytes:
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), allow_nan=False).encode()


TOKEN_ENV: Final = "ROVER_UPLINK_TOKEN"
"""The uplink token's variable: passed in the environment only (a command line is readable in
``/proc``); not the gate's token, which travels over plain HTTP. ``rover stack up`` and
``rover demo`` make a random one per stack (docs/onboard.md)."""


def token_from_env(env: Mapping[str, str]) -> str | None:
    """The uplink token from an environment (``None``: none configured)."""
    return env.get(TOKEN_ENV) or None


def is_boot_id(text: object) -> bool:
    """``text`` is a boot id: :data:`BOOT_HEX_DIGITS` lower-case hex digits."""
    return isinstance(text, str) and _is_hex(text, BOOT_HEX_DIGITS)


def _is_hex(text: str, digits: int) -> bool:
    return len(text) == digits and all(c in "0123456789abcdef" for c in text)


def verdict_digest(verdict: Mapping[str, Any] | Any) -> str:
    """The identity of a verdict (a :class:`~firmware_proto.model.verdict.Verdict` or its
    ``to_dict()``): SHA-256 (hex) of its JSON with sorted keys, without ``wall_time_s`` (the
    one field that differs between two playbacks of one plan)."""
    data = verdict if isinstance(verdict, Mapping) else verdict.to_dict()
    data = {k: v for k, v in data.items() if k != "wall_time_s"}
    return hashlib.sha256(_canonical(data)).hexdigest()


def sign(body: bytes, token: str) -> str:
    """HMAC-SHA256 of ``body`` under ``token``, hex."""
    return hmac.new(token.encode(), body, hashlib.sha256).hexdigest()


@dataclass(frozen=True)
class DriftLimits:
    """Stop at ``linear_m`` off the prediction or ``angular_deg`` of heading error."""

    linear_m: float
    angular_deg: float

    @classmethod
    def of(cls, rover: RoverDescription) -> DriftLimits:
        """The rover description's ``[safety]`` limits."""
        return cls(rover.safety.drift_linear_m, rover.safety.drift_angular_deg)


@dataclass(frozen=True)
class PredictedSample:
    """One predicted pose: its step, the twin time since that step started (s), the pose
    (map frame, m and deg)."""

    step: int
    step_t_s: float
    x: float
    y: float
    yaw_deg: float

    @property
    def pose(self) -> Pose:
        """The sample's pose."""
        return Pose(self.x, self.y, self.yaw_deg)


@dataclass(frozen=True)
class PlanUplink:
    """An approved plan as the rover takes it (see the module docstring): ``steps`` as
    ``wheel_instructions`` carries them, ``[command, speed, distance]``; ``durations_s``
    in twin seconds."""

    plan_id: int
    steps: tuple[tuple[int, int, int], ...]
    durations_s: tuple[float, ...]
    prediction: tuple[PredictedSample, ...]
    start: Pose
    goal: Pose
    limits: DriftLimits
    verdict: str
    boot: str = ""
    """The boot id of the onboard program the plan is for (``""``: none, refused)."""
    _by_step: dict[int, tuple[tuple[float, ...], tuple[PredictedSample, ...]]] = field(
        default_factory=dict, init=False, repr=False, compare=False
    )

    # -- building and encoding ------------------------------------------------------------
    @classmethod
    def from_verdict(
        cls,
        plan_id: int,
        steps: Sequence[tuple[int, int, int]],
        verdict: Any,
        limits: DriftLimits,
        boot: str = "",
    ) -> PlanUplink:
        """The uplink of an approved plan: ``plan_id`` (the ground's id), ``steps``
        (``Plan.to_wire()``), the gate's ``verdict`` on it (prediction, durations, digest),
        the drift ``limits`` and the ``boot`` id of the rover's onboard program (its latest
        report's)."""
        prediction = tuple(
            PredictedSample(s.step, s.step_t_s, s.pose.x, s.pose.y, s.pose.yaw_deg)
            for s in verdict.trajectory.samples
        )
        return cls(
            plan_id,
            tuple(tuple(s) for s in steps),  # type: ignore[misc]
            tuple(float(s.expected_duration_s) for s in verdict.steps),
            prediction,
            verdict.start_pose,
            verdict.goal,
            limits,
            verdict_digest(verdict),
            boot,
        )

    def to_dict(self) -> dict[str, Any]:
        """The uplink's body as JSON-ready data."""
        return {
            "type": "plan",
            "version": UPLINK_VERSION,
            "plan_id": self.plan_id,
            "steps": [list(s) for s in self.steps],
            "durations_s": list(self.durations_s),
            "prediction": [[s.step, s.step_t_s, s.x, s.y, s.yaw_deg] for s in self.prediction],
            "start": self.start.to_dict(),
            "goal": self.goal.to_dict(),
            "limits": {"linear_m": self.limits.linear_m, "angular_deg": self.limits.angular_deg},
            "verdict": self.verdict,
            "boot": self.boot,
        }

    def envelope(self, token: str | None = None) -> str:
        """The message to send: the body as JSON text, tagged under ``token`` (``None``: no tag)."""
        return _envelope(self.to_dict(), token)

    # -- the prediction -----------------------------------------------------------------
    @property
    def expected_duration_s(self) -> float:
        """The plan's predicted drive time, twin s (steps back to back)."""
        return sum(self.durations_s)

    def _step_samples(self, step: int) -> tuple[tuple[float, ...], tuple[PredictedSample, ...]]:
        cached = self._by_step.get(step)
        if cached is None:
            samples = tuple(s for s in self.prediction if s.step == step)
            cached = (tuple(s.step_t_s for s in samples), samples)
            self._by_step[step] = cached
        return cached

    def pose_at(self, step: int, step_t_s: float) -> Pose:
        """The predicted pose ``step_t_s`` twin seconds into ``step`` (interpolated, yaw along
        the shorter arc; held at a step's ends); before step 0 the start pose. IndexError when
        ``step`` has no samples (:func:`check_fit` refuses such plans)."""
        if step < 0:
            return self.start
        times, samples = self._step_samples(step)
        if not samples:
            raise IndexError(f"step {step} has no predicted samples")
        i = bisect.bisect_right(times, step_t_s)
        if i == 0:
            return samples[0].pose
        if i >= len(samples):
            return samples[-1].pose
        a, b = samples[i - 1], samples[i]
        span = b.step_t_s - a.step_t_s
        f = 0.0 if span <= 0 else (step_t_s - a.step_t_s) / span
        return Pose(
            a.x + f * (b.x - a.x),
            a.y + f * (b.y - a.y),
            wrap_deg(a.yaw_deg + f * wrap_deg(b.yaw_deg - a.yaw_deg)),
        )

    def path(self) -> list[tuple[float, float]]:
        """The predicted positions in order (for pictures and off-path distances)."""
        return [(s.x, s.y) for s in self.prediction]


@dataclass(frozen=True)
class CancelUplink:
    """Drop every plan with an id up to ``upto`` (running or still to come)."""

    upto: int

    def to_dict(self) -> dict[str, Any]:
        """The cancel's body as JSON-ready data."""
        return {"type": "cancel", "version": UPLINK_VERSION, "upto": self.upto}

    def envelope(self, token: str | None = None) -> str:
        """The message to send (see :meth:`PlanUplink.envelope`)."""
        return _envelope(self.to_dict(), token)


def _envelope(body: dict[str, Any], token: str | None) -> str:
    text = json.dumps(body, separators=(",", ":"), allow_nan=False)
    tag = sign(text.encode(), token) if token else None
    return json.dumps({"body": text, "tag": tag}, separators=(",", ":"))


@dataclass(frozen=True)
class UplinkAck:
    """The rover's answer to one uplink message.

    Attributes:
        plan_id: the plan answered (a cancel's ``upto``; 0 when the message was too broken
            to name one).
        result: one of :data:`ACK_RESULTS`.
        reason: a code of :data:`REFUSALS` when refused, else ``""``.
        detail: one sentence for the operator.
        state: where the plan is on board: ``armed`` (waiting for the latch's release),
            ``running``, ``completed``, ``stopped``, ``failed``, ``cancelled`` or ``""``.
    """

    plan_id: int
    result: str
    reason: str = ""
    detail: str = ""
    state: str = ""

    def to_json(self) -> str:
        """Compact JSON text."""
        return json.dumps(
            {
                "plan_id": self.plan_id,
                "result": self.result,
                "reason": self.reason,
                "detail": self.detail,
                "state": self.state,
            },
            separators=(",", ":"),
        )

    @property
    def taken(self) -> bool:
        """The rover has this plan (accepted now or before): stop retransmitting."""
        return self.result in ("accepted", "duplicate")


def decode_ack(text: str) -> UplinkAck:
    """Read an :class:`UplinkAck` (ground side); UplinkError ``malformed`` if it is not one."""
    obj = _json_object(text, "ack")
    r = _Fields(obj, "ack")
    ack = UplinkAck(
        r.integer("plan_id", 0, MAX_PLAN_ID),
        r.string("result"),
        r.string("reason"),
        r.string("detail"),
        r.string("state"),
    )
    if ack.result not in ACK_RESULTS:
        raise UplinkError("malformed", f"ack: result {ack.result!r} is not one of {ACK_RESULTS}")
    return ack


# -- decoding --------------------------------------------------------------------------------
def _json_object(text: str | bytes, what: str) -> dict[str, Any]:
    if len(text) > MAX_UPLINK_BYTES:
        raise UplinkError("too_large", f"{what}: {len(text)} bytes, at most {MAX_UPLINK_BYTES}")
    try:
        obj = json.loads(text)
    except (ValueError, UnicodeDecodeError, RecursionError) as exc:
        raise UplinkError("malformed", f"{what}: not JSON ({exc})") from exc
    if not isinstance(obj, dict):
        raise UplinkError("malformed", f"{what}: not a JSON object")
    return obj


class _Fields:
    """Strict reads of one JSON object's fields, each naming its path when it fails."""

    def __init__(self, obj: dict[str, Any], path: str) -> None:
        self.obj = obj
        self.path = path

    def _get(self, key: str) -> Any:
        if key not in self.obj:
            raise UplinkError("malformed", f"{self.path}.{key}: missing")
        return self.obj[key]

    def only(self, keys: set[str]) -> None:
        extra = sorted(set(self.obj) - keys)
        if extra:
            raise UplinkError("malformed", f"{self.path}: unexpected field(s) {', '.join(extra)}")

    def integer(self, key: str, low: int, high: int) -> int:
        value = self._get(key)
        if isinstance(value, bool) or not isinstance(value, int):
            raise UplinkError("malformed", f"{self.path}.{key}: not an integer")
        if not low <= value <= high:
            raise UplinkError("out_of_range", f"{self.path}.{key}: {value} not in {low}..{high}")
        return value

    def number(self, key: str) -> float:
        return _number(self._get(key), f"{self.path}.{key}")

    def string(self, key: str) -> str:
        value = self._get(key)
        if not isinstance(value, str):
            raise UplinkError("malformed", f"{self.path}.{key}: not a string")
        return value

    def array(self, key: str) -> list[Any]:
        value = self._get(key)
        if not isinstance(value, list):
            raise UplinkError("malformed", f"{self.path}.{key}: not an array")
        return value

    def child(self, key: str) -> _Fields:
        value = self._get(key)
        if not isinstance(value, dict):
            raise UplinkError("malformed", f"{self.path}.{key}: not an object")
        return _Fields(value, f"{self.path}.{key}")

    def pose(self, key: str) -> Pose:
        c = self.child(key)
        c.only({"x", "y", "yaw_deg"})
        return Pose(c.number("x"), c.number("y"), c.number("yaw_deg"))


def _number(value: Any, path: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise UplinkError("malformed", f"{path}: not a number")
    if not math.isfinite(value):
        raise UplinkError("out_of_range", f"{path}: not finite")
    return float(value)


def open_envelope(text: str | bytes, token: str | None = None) -> str:
    """Read one uplink envelope and authenticate it under ``token`` (``None``: tags are not
    checked, ``--insecure``): the body's text, not yet parsed. Cheap (one JSON parse and one
    HMAC), so the rover does it before anything else.

    Raises:
        UplinkError: ``too_large``, ``malformed``, ``unauthenticated`` or ``bad_tag``.
    """
    env = _json_object(text, "envelope")
    fields_ = _Fields(env, "envelope")
    fields_.only({"body", "tag"})
    body = fields_.string("body")
    tag = env.get("tag")
    if tag is not None and not isinstance(tag, str):
        raise UplinkError("malformed", "envelope.tag: not a string or null")
    if token:
        if tag is None:
            raise UplinkError("unauthenticated", "no tag, and this rover has a token")
        if not _is_hex(tag, _TAG_HEX_DIGITS):
            raise UplinkError("bad_tag", "the tag is not 64 lower-case hex digits")
        if not hmac.compare_digest(sign(body.encode(), token), tag):
            raise UplinkError("bad_tag", "the tag does not match the body under this rover's token")
    return body


def peek_body(body: str) -> tuple[int, str]:
    """The plan id (a cancel's ``upto``) and the type of a body, without checking the
    rest: ``(0, "")`` for what cannot be read. The rover answers a copy of a plan it
    took from this alone (after :func:`open_envelope` authenticated it)."""
    try:
        obj = json.loads(body)
    except (ValueError, RecursionError):
        return 0, ""
    if not isinstance(obj, dict):
        return 0, ""
    pid: Any = obj.get("plan_id", obj.get("upto", 0))
    kind: Any = obj.get("type")
    ok = isinstance(pid, int) and not isinstance(pid, bool) and 0 < pid <= MAX_PLAN_ID
    return (pid if ok else 0), (kind if isinstance(kind, str) else "")


def decode_uplink(
    text: str | bytes, *, token: str | None = None, rover: RoverDescription | None = None
) -> PlanUplink | CancelUplink:
    """Read one uplink envelope: :func:`open_envelope` (``text``, ``token``), then
    :func:`decode_body` (``rover``: the ranges of the limits and the fit check; ``None``
    checks the schema's ranges only and skips the fit).

    Raises:
        UplinkError: refused, with its reason (:data:`REFUSALS`) and one sentence.
    """
    return decode_body(open_envelope(text, token), rover=rover)


def decode_body(body: str, *, rover: RoverDescription | None = None) -> PlanUplink | CancelUplink:
    """Parse an authenticated body and check every field; for a plan, check that the
    prediction fits the steps (:func:`check_fit`, with ``rover``).

    Raises:
        UplinkError: refused, with its reason (:data:`REFUSALS`) and one sentence.
    """
    obj = _json_object(body, "body")
    r = _Fields(obj, "body")
    kind = r.string("type")
    version = r._get("version")
    if version != UPLINK_VERSION:
        raise UplinkError(
            "unsupported_version", f"body.version {version!r}, this rover reads {UPLINK_VERSION}"
        )
    if kind == "cancel":
        r.only(_CANCEL_KEYS)
        return CancelUplink(r.integer("upto", 1, MAX_PLAN_ID))
    if kind != "plan":
        raise UplinkError("malformed", f"body.type {kind!r} is neither 'plan' nor 'cancel'")
    r.only(_PLAN_KEYS)
    plan_id = r.integer("plan_id", 1, MAX_PLAN_ID)
    raw_steps = r.array("steps")
    if not 1 <= len(raw_steps) <= MAX_PLAN_STEPS:
        raise UplinkError(
            "out_of_range", f"body.steps: {len(raw_steps)} steps, 1..{MAX_PLAN_STEPS} allowed"
        )
    steps = tuple(_step(s, f"body.steps[{i}]") for i, s in enumerate(raw_steps))
    raw_durations = r.array("durations_s")
    durations = tuple(_number(d, f"body.durations_s[{i}]") for i, d in enumerate(raw_durations))
    if any(d < 0 for d in durations):
        raise UplinkError("out_of_range", "body.durations_s: a negative duration")
    raw_prediction = r.array("prediction")
    if len(raw_prediction) > MAX_PREDICTION_SAMPLES:
        raise UplinkError(
            "too_large",
            f"body.prediction: {len(raw_prediction)} samples, at most {MAX_PREDICTION_SAMPLES}",
        )
    prediction = tuple(_sample(s, f"body.prediction[{i}]") for i, s in enumerate(raw_prediction))
    limits_f = r.child("limits")
    limits_f.only({"linear_m", "angular_deg"})
    limits = DriftLimits(limits_f.number("linear_m"), limits_f.number("angular_deg"))
    ceiling = DriftLimits.of(rover) if rover is not None else DriftLimits(math.inf, math.inf)
    if not 0 < limits.linear_m <= ceiling.linear_m:
        raise UplinkError(
            "out_of_range",
            f"body.limits.linear_m {limits.linear_m:g} not in (0, {ceiling.linear_m:g}] "
            "(never looser than the rover's own)",
        )
    if not 0 < limits.angular_deg <= ceiling.angular_deg:
        raise UplinkError(
            "out_of_range",
            f"body.limits.angular_deg {limits.angular_deg:g} not in (0, {ceiling.angular_deg:g}]"
            " (never looser than the rover's own)",
        )
    verdict = r.string("verdict")
    if not _is_hex(verdict, 64):
        raise UplinkError("malformed", "body.verdict: not a SHA-256 digest in lower-case hex")
    boot = r.string("boot")
    if boot and not is_boot_id(boot):
        raise UplinkError(
            "malformed", f"body.boot: not {BOOT_HEX_DIGITS} lower-case hex digits (or empty)"
        )
    uplink = PlanUplink(
        plan_id,
        steps,
        durations,
        prediction,
        r.pose("start"),
        r.pose("goal"),
        limits,
        verdict,
        boot,
    )
    problems = check_fit(uplink, rover)
    if problems:
        raise UplinkError("prediction_mismatch", problems[0])
    return uplink


def _step(value: Any, path: str) -> tuple[int, int, int]:
    if not isinstance(value, list) or len(value) != 3:
        raise UplinkError("malformed", f"{path}: not [command, speed, distance]")
    for v in value:
        if isinstance(v, bool) or not isinstance(v, int):
            raise UplinkError("malformed", f"{path}: not three integers")
    command, speed, distance = value
    if command not in _COMMANDS:
        raise UplinkError("out_of_range", f"{path}: command {command} is not a command code")
    if not 0 <= speed <= 60:
        raise UplinkError("out_of_range", f"{path}: speed {speed} not in 0..60")
    if not 0 <= distance <= 30000:
        raise UplinkError("out_of_range", f"{path}: distance {distance} not in 0..30000")
    return (command, speed, distance)


def _sample(value: Any, path: str) -> PredictedSample:
    if not isinstance(value, list) or len(value) != 5:
        raise UplinkError("malformed", f"{path}: not [step, step_t_s, x, y, yaw_deg]")
    step = value[0]
    if isinstance(step, bool) or not isinstance(step, int):
        raise UplinkError("malformed", f"{path}: step not an integer")
    t, x, y, yaw = (_number(v, path) for v in value[1:])
    if t < 0:
        raise UplinkError("out_of_range", f"{path}: negative step time")
    return PredictedSample(step, t, x, y, yaw)


# -- does the prediction belong to the steps? -----------------------------------------------
def check_fit(uplink: PlanUplink, rover: RoverDescription | None = None) -> list[str]:
    """What makes the prediction not fit the steps (empty: it fits).

    Structure: one duration per step; samples in step order, each step with a sample at
    ``step_t_s`` 0 and non-decreasing times; the first at the start pose; one step's end
    where the next starts. With ``rover``, motion too: each step's duration within the
    playback's limit (1.5 x nominal + 2 s); a drive moves at most its wheel travel, in its
    direction; a spin turns its way, at most an ideal spin's turn, moving the centre little;
    a STOP step does not move. A gate's prediction of these steps passes; one of other
    steps, or edited after the fact, does not.
    """
    problems: list[str] = []
    n = len(uplink.steps)
    if len(uplink.durations_s) != n:
        return [f"{len(uplink.durations_s)} durations for {n} steps"]
    samples = uplink.prediction
    if not samples:
        return ["no predicted samples"]
    first = samples[0]
    if first.step != 0 or first.step_t_s != 0.0:
        return ["the prediction does not start at step 0, time 0"]
    if math.hypot(first.x - uplink.start.x, first.y - uplink.start.y) > _START_TOL_M or (
        abs(wrap_deg(first.yaw_deg - uplink.start.yaw_deg)) > _START_TOL_DEG
    ):
        return ["the prediction does not start at the start pose"]
    previous = first
    for i, s in enumerate(samples[1:], 1):
        if s.step < previous.step:
            return [f"prediction[{i}]: step {s.step} after step {previous.step}"]
        if s.step > previous.step + 1:
            return [f"prediction[{i}]: step {previous.step + 1} has no samples"]
        if s.step == previous.step and s.step_t_s < previous.step_t_s:
            return [f"prediction[{i}]: time goes back within step {s.step}"]
        if s.step == previous.step + 1:
            if s.step_t_s != 0.0:
                return [f"prediction[{i}]: step {s.step} does not start at time 0"]
            if math.hypot(s.x - previous.x, s.y - previous.y) > _POSE_TOL_M:
                return [f"prediction[{i}]: step {s.step} starts away from where {s.step - 1} ends"]
        previous = s
    if previous.step != n - 1:
        return [f"the prediction covers {previous.step + 1} of {n} steps"]
    if rover is None:
        return problems
    for k, (command, speed, distance) in enumerate(uplink.steps):
        problems += _step_fit(uplink, rover, k, command, speed, distance)
    return problems


def _step_fit(
    uplink: PlanUplink, rover: RoverDescription, k: int, command: int, speed: int, distance: int
) -> list[str]:
    _, samples = uplink._step_samples(k)
    a, b = samples[0], samples[-1]
    name = Command(command).name
    nominal = rover.step_duration_s(speed, distance)
    limit = 1.5 * nominal + 2.0 + 0.1
    duration = uplink.durations_s[k]
    last = k == len(uplink.steps) - 1
    if duration > limit:
        return [f"step {k} ({name}): predicted {duration:.2f} s, the limit is {limit:.2f} s"]
    if b.step_t_s > duration + (_SETTLE_S if last else 0.0) + 0.05:
        return [f"step {k} ({name}): samples run {b.step_t_s:.2f} s, past its {duration:.2f} s"]
    travel = rover.units_to_m(distance)
    dx, dy = b.x - a.x, b.y - a.y
    moved = math.hypot(dx, dy)
    # Unwrapped: a long spin turns past 180 degrees.
    dyaw = sum(wrap_deg(q.yaw_deg - p.yaw_deg) for p, q in itertools.pairwise(samples))
    if command == Command.STOP or speed == 0 or distance == 0:
        if moved > _DRIVE_SLACK_M:
            return [f"step {k} ({name}): predicted to move {moved:.2f} m, it does nothing"]
        return []
    if command in (Command.FWD, Command.REV):
        if moved > travel + _DRIVE_SLACK_M:
            return [
                f"step {k} ({name}): predicted to move {moved:.2f} m, its wheels travel "
                f"{travel:.2f} m"
            ]
        heading = math.radians(a.yaw_deg)
        along = dx * math.cos(heading) + dy * math.sin(heading)
        sign = 1.0 if command == Command.FWD else -1.0
        if moved > _DRIVE_SLACK_M and along * sign < 0:
            return [f"step {k} ({name}): predicted to move the other way"]
        if moved < _LEAST_SHARE * travel - _DRIVE_SLACK_M:
            return [
                f"step {k} ({name}): predicted to move {moved:.2f} m of its {travel:.2f} m "
                "(a prediction of another step)"
            ]
        return []
    # LEFT / RIGHT: a spin in place, each side's wheels travelling ``travel`` on its arc.
    ideal_deg = math.degrees(travel / (rover.geometry.track_width_m / 2.0))
    sign = 1.0 if command == Command.LEFT else -1.0
    if moved > _SPIN_MOVE_M:
        return [f"step {k} ({name}): predicted to move {moved:.2f} m, a spin moves little"]
    if abs(dyaw) > 2.0 and dyaw * sign < 0:
        return [f"step {k} ({name}): predicted to turn the other way ({dyaw:+.1f} deg)"]
    if abs(dyaw) < _LEAST_SHARE * ideal_deg - 2.0:
        return [
            f"step {k} ({name}): predicted to turn {abs(dyaw):.1f} deg of an ideal "
            f"{ideal_deg:.1f} deg (a prediction of another step)"
        ]
    if abs(dyaw) > ideal_deg * 1.2 + 5.0:
        return [
            f"step {k} ({name}): predicted to turn {abs(dyaw):.1f} deg, an ideal spin turns "
            f"{ideal_deg:.1f} deg"
        ]
    return []
