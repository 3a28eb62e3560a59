"""The public names of our packages' front doors, pinned: each package's ``__all__`` is the
list in ``tests/data/exports/<package>.txt`` (one name a line, in ruff's order:
constants first, then the rest, each sorted), and every name resolves. Changing a
package's public names means changing its file, in the same commit."""

from __future__ import annotations

import importlib
from pathlib import Path

import pytest

PINNED = Path(__file__).parent / "data" / "exports"
PACKAGES = sorted(path.stem for path in PINNED.glob("*.txt"))


def test_the_pinned_packages_are_the_front_doors() -> None:
    assert PACKAGES == ["bridge.ros.rosport", "emulator", "firmware_proto", "gate"]


@pytest.mark.parametrize("package", PACKAGES)
def test_exports_are_pinned_sorted_and_resolve(package: str) -> None:
    module = importlib.import_module(package)
    assert module.__all__ == (PINNED / f"{package}.txt").read_text().split()
    assert module.__all__ == sorted(module.__all__, key=lambda n: (not n.isupper(), n))
    for name in module.__all__:
        assert getattr(module, name) is not None
    with pytest.raises(AttributeError):
        module.NoSuchThing  # noqa: B018
