"""Rover motor-controller emulator: the pymunk twin, the controller model, fault
injection, and front ends serving it over a pty or a python-can bus.

The twin part (what the gate imports): :class:`Twin`, :class:`StepProfile`,
:func:`play`, :class:`Ground` and :func:`load_ground`; maps are
:mod:`firmware_proto.model.worldmap`'s. See docs/twin.md.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from emulator.errors import (
    CommandError,
    EmulatorError,
    GroundError,
    InjectionError,
    TwinConfigError,
)
from firmware_proto.lazyexports import lazy_exports

if TYPE_CHECKING:
    from emulator.drive import (
        StepProfile,
        brake,
        motor_omegas,
        side_directions,
        travel_units,
        turn_units_for_yaw,
        yaw_for_turn_units,
    )
    from emulator.ground import Ground, list_grounds, load_ground
    from emulator.playback import (
        PlaybackResult,
        Stall,
        StepResult,
        TimedPose,
        measure_turn_efficiency,
        play,
    )
    from emulator.traction import TractionModel
    from emulator.twin import (
        GATE_DT_S,
        BodyAcceleration,
        BodyVelocity,
        Collision,
        Pose2D,
        Twin,
    )

__getattr__, __dir__ = lazy_exports(
    __name__,
    {
        "emulator.drive": (
            "StepProfile",
            "brake",
            "motor_omegas",
            "side_directions",
            "travel_units",
            "turn_units_for_yaw",
            "yaw_for_turn_units",
        ),
        "emulator.ground": ("Ground", "list_grounds", "load_ground"),
        "emulator.playback": (
            "PlaybackResult",
            "Stall",
            "StepResult",
            "TimedPose",
            "measure_turn_efficiency",
            "play",
        ),
        "emulator.traction": ("TractionModel",),
        "emulator.twin": (
            "GATE_DT_S",
            "BodyAcceleration",
            "BodyVelocity",
            "Collision",
            "Pose2D",
            "Twin",
        ),
    },
)

__all__ = [
    "GATE_DT_S",
    "BodyAcceleration",
    "BodyVelocity",
    "Collision",
    "CommandError",
    "EmulatorError",
    "Ground",
    "GroundError",
    "InjectionError",
    "PlaybackResult",
    "Pose2D",
    "Stall",
    "StepProfile",
    "StepResult",
    "TimedPose",
    "TractionModel",
    "Twin",
    "TwinConfigError",
    "brake",
    "list_grounds",
    "load_ground",
    "measure_turn_efficiency",
    "motor_omegas",
    "play",
    "side_directions",
    "travel_units",
    "turn_units_for_yaw",
    "yaw_for_turn_units",
]
