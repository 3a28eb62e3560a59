"""The PIL targets by name (``rover pil --target``), each class imported when first used
(building the ``rover`` parser loads none of them)."""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

from emulator.pil.errors import PilError

if TYPE_CHECKING:
    from emulator.pil.target import PilTarget

__all__ = ["TARGETS", "target_class"]

TARGETS: dict[str, str] = {
    "microbit": "emulator.pil.qemu:MicrobitTarget",
    "atmega2560": "emulator.pil.avr:AvrTarget",
}
"""Target name -> ``module:Class``."""


def target_class(name: str) -> type[PilTarget]:
    """The class of target ``name``.

    Raises:
        PilError: an unknown name (the known ones listed).
    """
    where = TARGETS.get(name)
    if where is None:
        raise PilError(f"unknown PIL target {name!r}; known: {', '.join(TARGETS)}")
    module, _, cls = where.partition(":")
    found: type[PilTarget] = getattr(importlib.import_module(module), cls)
    return found
