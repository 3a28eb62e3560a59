"""The rover's onboard sequencer and drift guard (docs/onboard.md): the approved plan is
uplinked once and runs on the rover, and drift stops the wheels there. ``core`` (pure),
``ekf`` (the pose estimate) and ``node`` (the ROS 2 program, ``rover onboard``).
"""

from __future__ import annotations

from bridge.onboard.core import (
    Action,
    OnboardConfig,
    OnboardCore,
    PlanState,
    SayStatus,
    SendAck,
    SendReport,
    SendStep,
    SendStop,
)
from bridge.onboard.ekf import EkfConfig, Estimate, PoseEkf

__all__ = [
    "Action",
    "EkfConfig",
    "Estimate",
    "OnboardConfig",
    "OnboardCore",
    "PlanState",
    "PoseEkf",
    "SayStatus",
    "SendAck",
    "SendReport",
    "SendStep",
    "SendStop",
]
