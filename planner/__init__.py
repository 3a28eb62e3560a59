"""Ground station (docs/planner.md, docs/ground.md):

- ``plan/``: the heuristic planner, repairs, orchestrator and gate client;
- ``ground/``: the executor with drift control, missions, the link relay, the operator's
  console;
- ``stack/``: a stack of the programs on one machine, and the demo;
- ``record/``: MCAP recordings, markers, Foxglove, the mission picture;
- ``view/``: the live view.

The names an operator's script needs are imported here. :mod:`planner.record.picture` (Pillow)
and :mod:`planner.stack.demo` (subprocesses) are imported from their modules.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from firmware_proto.lazyexports import lazy_exports
from firmware_proto.model.geometry import Point
from firmware_proto.model.pose import Pose
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
    from firmware_proto.model.verdict import Trajectory, Verdict
    from planner.ground.drift import DriftEvent, DriftMonitor
    from planner.ground.executor import (
        ExecutionProgress,
        ExecutionResult,
        ExecutorConfig,
        PlanExecutor,
    )
    from planner.ground.mission import MissionReport, MissionRunner, MoveAndWait
    from planner.ground.relay import LinkProfile, LinkRelay
    from planner.plan.experiment import ExperimentResult, run_planning_experiment
    from planner.plan.gate_client import GateClient, GateOptions
    from planner.plan.orchestrator import Attempt, MissionResult, PlannerOrchestrator, PlanResult
    from planner.plan.planner import HeuristicLowLevelPlanner, LegPlan
    from planner.plan.repairs import RepairSettings

__getattr__, __dir__ = lazy_exports(
    __name__,
    {
        "firmware_proto.model.verdict": ("Trajectory", "Verdict"),
        "planner.ground.drift": ("DriftEvent", "DriftMonitor"),
        "planner.ground.executor": (
            "ExecutionResult",
            "ExecutorConfig",
            "PlanExecutor",
            "ExecutionProgress",
        ),
        "planner.plan.experiment": ("ExperimentResult", "run_planning_experiment"),
        "planner.plan.gate_client": ("GateClient", "GateOptions"),
        "planner.ground.mission": ("MissionReport", "MissionRunner", "MoveAndWait"),
        "planner.plan.orchestrator": (
            "Attempt",
            "MissionResult",
            "PlannerOrchestrator",
            "PlanResult",
        ),
        "planner.plan.planner": ("HeuristicLowLevelPlanner", "LegPlan"),
        "planner.ground.relay": ("LinkProfile", "LinkRelay"),
        "planner.plan.repairs": ("RepairSettings",),
    },
)

__all__ = [
    "Attempt",
    "DriftEvent",
    "DriftMonitor",
    "ExecutionProgress",
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
    "RepairError",
    "RepairSettings",
    "Trajectory",
    "UnreachableGoalError",
    "Verdict",
    "run_planning_experiment",
]
