"""Ground station: heuristic planner with repairs, orchestrator, gate client, executor
with drift control, link emulation, missions and the operator CLI (docs/planner.md,
docs/ground.md).

The names an operator's script needs are imported here. :mod:`planner.picture` (Pillow)
and :mod:`planner.demo` (subprocesses) are imported from their modules.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from firmware_proto.geometry import Point
from firmware_proto.lazyexports import lazy_exports
from firmware_proto.pose import Pose
from planner.errors import (
    GateCallError,
    GateOverloadedError,
    GateStatusError,
    GateTimeoutError,
    GateUnavailableError,
    GoalInObstacleError,
    InvalidPoseError,
    OutOfBoundsError,
    PlannerError,
    PlanTooLongError,
    RepairError,
    UnreachableGoalError,
)

if TYPE_CHECKING:
    from firmware_proto.verdict import Trajectory, Verdict
    from planner.drift import DriftEvent, DriftMonitor
    from planner.executor import ExecutionResult, ExecutorConfig, PlanExecutor, Progress
    from planner.experiment import ExperimentResult, run_planning_experiment
    from planner.gate_client import GateClient, GateOptions
    from planner.mission import MissionReport, MissionRunner, MoveAndWait
    from planner.orchestrator import Attempt, MissionResult, PlannerOrchestrator, PlanResult
    from planner.planner import HeuristicLowLevelPlanner, LegPlan
    from planner.relay import LinkProfile, LinkRelay
    from planner.repairs import RepairSettings

__getattr__, __dir__ = lazy_exports(
    __name__,
    {
        "firmware_proto.verdict": ("Trajectory", "Verdict"),
        "planner.drift": ("DriftEvent", "DriftMonitor"),
        "planner.executor": ("ExecutionResult", "ExecutorConfig", "PlanExecutor", "Progress"),
        "planner.experiment": ("ExperimentResult", "run_planning_experiment"),
        "planner.gate_client": ("GateClient", "GateOptions"),
        "planner.mission": ("MissionReport", "MissionRunner", "MoveAndWait"),
        "planner.orchestrator": ("Attempt", "MissionResult", "PlannerOrchestrator", "PlanResult"),
        "planner.planner": ("HeuristicLowLevelPlanner", "LegPlan"),
        "planner.relay": ("LinkProfile", "LinkRelay"),
        "planner.repairs": ("RepairSettings",),
    },
)

__all__ = [
    "Attempt",
    "DriftEvent",
    "DriftMonitor",
    "ExecutionResult",
    "ExecutorConfig",
    "ExperimentResult",
    "GateCallError",
    "GateClient",
    "GateOptions",
    "GateOverloadedError",
    "GateStatusError",
    "GateTimeoutError",
    "GateUnavailableError",
    "GoalInObstacleError",
    "HeuristicLowLevelPlanner",
    "InvalidPoseError",
    "LegPlan",
    "LinkProfile",
    "LinkRelay",
    "MissionReport",
    "MissionResult",
    "MissionRunner",
    "MoveAndWait",
    "OutOfBoundsError",
    "PlanExecutor",
    "PlanResult",
    "PlanTooLongError",
    "PlannerError",
    "PlannerOrchestrator",
    "Point",
    "Pose",
    "Progress",
    "RepairError",
    "RepairSettings",
    "Trajectory",
    "UnreachableGoalError",
    "Verdict",
    "run_planning_experiment",
]
