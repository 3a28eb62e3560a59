"""Processor in the loop: the firmware image in an emulated MCU (``rover pil``).

- :mod:`emulator.pil.images`: the images (the same ``fw.c``, a port per MCU), built and
  cached;
- :mod:`emulator.pil.registry`: the targets by name;
- :mod:`emulator.pil.target`: a running target, its control hooks and status;
- :mod:`emulator.pil.qemu`: the nRF51 (micro:bit) under qemu-system-arm;
- :mod:`emulator.pil.avr`: the ATmega2560 under simavr with the twin as its plant;
- :mod:`emulator.pil.cli_pil`: the command.
"""

from __future__ import annotations

from emulator.pil.errors import PilError, PilToolMissingError
from emulator.pil.images import IMAGES, Image, build_image
from emulator.pil.registry import TARGETS, target_class

__all__ = [
    "IMAGES",
    "TARGETS",
    "Image",
    "PilError",
    "PilToolMissingError",
    "build_image",
    "target_class",
]
