"""The errors of processor-in-the-loop runs (``rover pil``), under the emulator's root.

::

    EmulatorError
     +-- PilError                 a runner could not start, talk to or stop its emulator
          +-- PilToolMissingError      a cross compiler, qemu, simavr or libsimavr is missing
"""

from __future__ import annotations

from emulator.errors import EmulatorError

__all__ = ["PilError", "PilToolMissingError"]


class PilError(EmulatorError):
    """A PIL runner could not build its image, start its emulator or reach it."""


class PilToolMissingError(PilError):
    """A tool the target needs is not installed; the message names the Debian packages."""
