"""The package's public names: sorted, importable, pinned."""

from __future__ import annotations

import emulator

EXPECTED = [
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


def test_exported_members_are_pinned() -> None:
    assert emulator.__all__ == EXPECTED


def test_exported_members_are_sorted_and_exist() -> None:
    assert emulator.__all__ == sorted(emulator.__all__, key=lambda n: (not n.isupper(), n))
    for name in emulator.__all__:
        assert getattr(emulator, name) is not None


def test_one_exception_root() -> None:
    for cls in (
        emulator.CommandError,
        emulator.InjectionError,
        emulator.TwinConfigError,
    ):
        assert issubclass(cls, emulator.EmulatorError)
        assert issubclass(cls, ValueError)
