"""What may be a stack's controller (``rover stack up --controller``, ``rover demo
--controller``): the emulator, or a firmware image in an emulated MCU (``rover pil``).
Light: the ``rover`` parser imports it."""

from __future__ import annotations

__all__ = ["CONTROLLERS", "PIL_TARGETS", "pil_target_of"]

PIL_TARGETS = ("microbit", "atmega2560")
"""The MCUs ``rover pil`` emulates (emulator/pil/registry.py), as ``pil:TARGET``."""
CONTROLLERS = ("emulator", *(f"pil:{t}" for t in PIL_TARGETS))
"""What may be the stack's controller (``--controller``)."""


def pil_target_of(controller: str) -> str | None:
    """The PIL target of ``pil:TARGET``; ``None`` for ``emulator``; ``ValueError`` for
    anything else (the message lists the known ones)."""
    if controller == "emulator":
        return None
    target = controller.removeprefix("pil:")
    if controller.startswith("pil:") and target in PIL_TARGETS:
        return target
    raise ValueError(f"unknown controller {controller!r}; known: {', '.join(CONTROLLERS)}")
