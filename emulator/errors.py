"""Exceptions raised by :mod:`emulator`.

Everything this package raises on purpose derives from :class:`EmulatorError`::

    EmulatorError
     +-- MapError         a map file is missing, not JSON, or invalid; also ValueError.
     |                    ``violations`` lists ``(json_pointer, message)`` pairs.
     +-- CommandError     a motion command cannot be executed (unknown command, speed or
     |                    distance out of range, non-finite motor rate); also ValueError
     +-- InjectionError   a fault or traction change the twin cannot apply is refused;
     |                    also ValueError (never silently accepted)
     +-- ConfigError      a twin or playback parameter is out of range (time step,
     |                    safety margin, sample period); also ValueError
     +-- FirmwareBuildError  the C firmware core cannot be built or loaded here (no
                          compiler, a failed build, a rover it cannot represent);
                          also RuntimeError

Programming errors (wrong types, calling a closed object) raise the usual built-ins.
"""

from __future__ import annotations

__all__ = [
    "CommandError",
    "ConfigError",
    "EmulatorError",
    "FirmwareBuildError",
    "InjectionError",
    "MapError",
]


class EmulatorError(Exception):
    """Root of every exception raised on purpose by the emulator package."""


class MapError(EmulatorError, ValueError):
    """A map file cannot be used.

    Attributes:
        source: the file (or map name) that was read.
        violations: ``(json_pointer, message)`` pairs, sorted by pointer; the pointer is
            ``""`` for a problem with the whole document (unreadable, not JSON).
    """

    def __init__(self, source: str, violations: list[tuple[str, str]]) -> None:
        self.source = source
        self.violations = list(violations)
        lines = "; ".join(f"{ptr or '/'}: {msg}" for ptr, msg in self.violations)
        super().__init__(f"{source}: invalid map: {lines}")


class CommandError(EmulatorError, ValueError):
    """A motion command cannot be executed as given (unknown command, speed or distance
    out of range, non-finite motor rate)."""


class InjectionError(EmulatorError, ValueError):
    """An injection (traction scale, locked wheel, fault) was refused as inapplicable."""


class ConfigError(EmulatorError, ValueError):
    """A twin or playback parameter is out of range (time step, margin, period)."""


class FirmwareBuildError(EmulatorError, RuntimeError):
    """The C firmware core cannot be built or loaded here (no compiler, a failed build,
    or a rover description or time step its integer arithmetic cannot represent)."""
