"""Simulation gate: HTTP ``/validate_plan`` playing command plans on the pymunk twin.

The light names (option data types, errors, configuration, and the verdict's types,
defined once in :mod:`firmware_proto.model.verdict` for the gate and its clients) are imported
here; the ones that pull in the twin (pymunk) or the HTTP server load on first use, so
that ``from gate import Verdict`` stays cheap for a client. See docs/gate.md.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from firmware_proto.lazyexports import lazy_exports
from firmware_proto.model.pose import Point, Pose
from firmware_proto.model.verdict import (
    FAILURE_TYPES,
    CollisionReport,
    Replay,
    StallReport,
    StepPrediction,
    Tolerances,
    Trajectory,
    TrajectorySample,
    Uncertainty,
    Verdict,
)
from gate.config import GateConfig, PlaybackSettings, load_config
from gate.errors import (
    BadRequestError,
    CallCancelledError,
    GateConfigError,
    GateError,
    GoalRangeError,
    HttpError,
    LengthRequiredError,
    NotFoundError,
    OptionError,
    OverloadedError,
    PayloadTooLargeError,
    PlanSchemaError,
    RequestTimeoutError,
    TooManyRequestsError,
    UnsupportedMediaError,
)
from gate.options import ResolvedOptions, ValidateOptions

if TYPE_CHECKING:
    from gate.pool import ProcessWorkerPool, ThreadWorkerPool, WorkerPool
    from gate.server import GateServer
    from gate.validator import Job, Validator

__all__ = [
    "FAILURE_TYPES",
    "BadRequestError",
    "CallCancelledError",
    "CollisionReport",
    "GateConfig",
    "GateConfigError",
    "GateError",
    "GateServer",
    "GoalRangeError",
    "HttpError",
    "Job",
    "LengthRequiredError",
    "NotFoundError",
    "OptionError",
    "OverloadedError",
    "PayloadTooLargeError",
    "PlanSchemaError",
    "PlaybackSettings",
    "Point",
    "Pose",
    "ProcessWorkerPool",
    "Replay",
    "RequestTimeoutError",
    "ResolvedOptions",
    "StallReport",
    "StepPrediction",
    "ThreadWorkerPool",
    "Tolerances",
    "TooManyRequestsError",
    "Trajectory",
    "TrajectorySample",
    "Uncertainty",
    "UnsupportedMediaError",
    "ValidateOptions",
    "Validator",
    "Verdict",
    "WorkerPool",
    "load_config",
]

__getattr__, __dir__ = lazy_exports(
    __name__,
    {
        "gate.pool": ("ProcessWorkerPool", "ThreadWorkerPool", "WorkerPool"),
        "gate.server": ("GateServer",),
        "gate.validator": ("Job", "Validator"),
    },
)
