"""Ground station: heuristic planner with repairs, orchestrator, gate client, executor
with drift control, link emulation, missions and the operator CLI (docs/planner.md,
docs/ground.md).

The names an operator's script needs are imported here. :mod:`planner.picture` (Pillow)
and :mod:`planner.demo` (subprocesses) are imported from their modules.
"""

from __future__ import annotations

from firmware_proto.geometry import Point
from firmware_proto.pose import Pose
from firmware_proto.verdict import Trajectory, Verdict
from planner.drift import DriftEvent, DriftMonitor
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
from planner.executor import ExecutionResult, ExecutorConfig, PlanExecutor, Progress
from planner.experiment import ExperimentResult, run_planning_experiment
from planner.gate_client import GateClient, GateOptions
from planner.mission import MissionReport, MissionRunner, MoveAndWait
from planner.orchestrator import Attempt, MissionResult, PlannerOrchestrator, PlanResult
from planner.planner import HeuristicLowLevelPlanner, LegPlan
from planner.relay import LinkProfile, LinkRelay
from planner.repairs import RepairSettings

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
