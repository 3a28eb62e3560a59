"""Exceptions raised by :mod:`emulator`.

Everything this package raises on purpose derives from :class:`EmulatorError`::

    EmulatorError
     +-- CommandError         a motion command cannot be executed; also ValueError
     +-- InjectionError       a fault or traction change is refused; also ValueError
     +-- TwinConfigError      a twin or playback parameter out of range; also ValueError
     +-- NativeBuildError     host C cannot be built or loaded here; also RuntimeError
     |    +-- FirmwareBuildError   the C firmware core cannot be built here
     +-- GroundError          a ground file or setting is invalid; also ValueError
     +-- UnknownMutantError   no mutant controller has this name; also ValueError
     +-- CalibrationError     fitting the twin to recordings failed; also ValueError
          +-- RecordingError        a recording cannot be read or holds no usable step
          +-- UnidentifiableError   the recordings cannot identify a parameter

An unusable map raises :class:`firmware_proto.errors.MapError`.
"""

from __future__ import annotations

__all__ = [
    "CalibrationError",
    "CommandError",
    "EmulatorError",
    "FirmwareBuildError",
    "GroundError",
    "InjectionError",
    "NativeBuildError",
    "RecordingError",
    "TwinConfigError",
    "UnidentifiableError",
    "UnknownMutantError",
]


class EmulatorError(Exception):
    """Root of every exception raised on purpose by the emulator package."""


class CommandError(EmulatorError, ValueError):
    """A motion command cannot be executed (unknown command, value out of range, ...)."""


class InjectionError(EmulatorError, ValueError):
    """An injection (traction scale, locked wheel, fault) was refused as inapplicable."""


class TwinConfigError(EmulatorError, ValueError):
    """A twin or playback parameter is out of range (time step, margin, period)."""


class NativeBuildError(EmulatorError, RuntimeError):
    """Host C (:mod:`emulator.sharedlib`) cannot be built or loaded here."""


class FirmwareBuildError(NativeBuildError):
    """The C firmware core cannot be built, loaded or configured here."""


class GroundError(EmulatorError, ValueError):
    """A ground file or setting cannot be used, or names a region the map lacks."""


class CalibrationError(EmulatorError, ValueError):
    """The twin cannot be fitted to the recordings given."""


class RecordingError(CalibrationError):
    """A recording cannot be read, or holds no step that can be replayed."""


class UnidentifiableError(CalibrationError):
    """The recordings cannot identify a parameter (no turns, too short, too noisy).

    Attributes:
        parameter: the parameter that cannot be identified (``""``: the recording as a
            whole is too short).
        advice: ``(command, speed, distance)`` steps that would identify it, in the
            order to drive them (empty: the message says what to drive).
    """

    def __init__(
        self,
        message: str,
        parameter: str = "",
        advice: tuple[tuple[int, int, int], ...] = (),
    ) -> None:
        super().__init__(message)
        self.parameter = parameter
        self.advice = advice


class UnknownMutantError(EmulatorError, ValueError):
    """No mutant controller has this name; the message lists the known ones."""
