"""The package's exceptions and lazy imports (its public names are pinned by
tests/test_exports.py)."""

from __future__ import annotations

import emulator


def test_one_exception_root() -> None:
    for cls in (
        emulator.CommandError,
        emulator.InjectionError,
        emulator.TwinConfigError,
    ):
        assert issubclass(cls, emulator.EmulatorError)
        assert issubclass(cls, ValueError)
