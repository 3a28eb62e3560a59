"""Names a package exports but imports on first use (PEP 562), so that importing the
package, or any module in it, costs only what that module needs (every program of the
stack is a Python process, started hundreds of times by a test run).

A package lists its lazy names here, and imports them under ``TYPE_CHECKING``::

    if TYPE_CHECKING:
        from planner.ground.executor import PlanExecutor
    __getattr__, __dir__ = lazy_exports(__name__, {"planner.ground.executor": ("PlanExecutor",)})
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable, Mapping, Sequence

__all__ = ["lazy_exports"]


def lazy_exports(
    package: str, modules: Mapping[str, Sequence[str]]
) -> tuple[Callable[[str], object], Callable[[], list[str]]]:
    """The ``__getattr__`` and ``__dir__`` of ``package``: each name of ``modules[m]`` is
    ``m``'s attribute of that name, imported on first use and then kept in the package.

    An unknown name raises ``AttributeError`` as a plain module does; a name listed twice
    is a ``ValueError`` here, when the package is imported.
    """
    where: dict[str, str] = {}
    for module, names in modules.items():
        for name in names:
            if name in where:
                raise ValueError(f"{package}: {name!r} is exported from two modules")
            where[name] = module

    def get_attribute(name: str) -> object:
        module = where.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(module), name)
        setattr(sys.modules[package], name, value)
        return value

    def list_names() -> list[str]:
        return sorted(set(vars(sys.modules[package])) | set(where))

    return get_attribute, list_names
