"""Each concept has one name: no two of our modules define a public class of the same
name (docs/architecture.md, "Names"). A second ``Pose`` or ``Outcome`` makes every
reader, and every import list, say which one; this test fails on the first such pair."""

from __future__ import annotations

import ast
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MAKERS = {"NamedTuple", "namedtuple", "TypedDict", "type", "make_dataclass", "Enum", "IntEnum"}
"""Calls that make a class (a ``TypeVar`` is not one)."""
PACKAGES = ("firmware_proto", "emulator", "gate", "bridge", "planner", "udev", "sim", "benchmarks")
"""Our packages: the parts, the wire simulator, the benchmarks."""


def public_classes(source: str) -> list[str]:
    """The public classes a module defines at its top level (``class X`` and a class
    made by a call at module level, ``X = NamedTuple("X", ...)``)."""
    names = []
    for node in ast.parse(source).body:
        if isinstance(node, ast.ClassDef):
            names.append(node.name)
        elif isinstance(node, ast.Assign) and isinstance(node.value, ast.Call):
            func = node.value.func
            maker = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", "")
            if maker in MAKERS:
                names += [t.id for t in node.targets if isinstance(t, ast.Name)]
    return [n for n in names if not n.startswith("_")]


def test_no_two_modules_define_a_public_class_of_the_same_name() -> None:
    where: dict[str, list[str]] = defaultdict(list)
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            for name in public_classes(path.read_text()):
                where[name].append(str(path.relative_to(ROOT)))
    twice = {name: paths for name, paths in sorted(where.items()) if len(paths) > 1}
    assert not twice, "public classes defined in more than one module: " + "; ".join(
        f"{name} in {', '.join(paths)}" for name, paths in twice.items()
    )


def test_the_check_sees_a_class_and_a_class_made_by_a_call() -> None:
    source = (
        "class A:\n    pass\n"
        'B = NamedTuple("B", [])\n_C = type("_C", (), {})\nD = 3\nM = TypeVar("M")\n'
        'E = enum.Enum("E", "X Y")\n'
    )
    assert public_classes(source) == ["A", "B", "E"]
