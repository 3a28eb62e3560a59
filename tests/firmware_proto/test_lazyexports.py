"""Lazy package exports (firmware_proto/lazyexports.py), and what they are for: building
the ``rover`` parser, which every ``rover`` command does first, loads none of the heavy
libraries (a test run starts about a hundred and fifty such processes)."""

from __future__ import annotations

import subprocess
import sys
import types

import pytest

from firmware_proto.lazyexports import lazy_exports


@pytest.fixture
def package(monkeypatch: pytest.MonkeyPatch) -> types.ModuleType:
    module = types.ModuleType("lazy_demo")
    monkeypatch.setitem(sys.modules, "lazy_demo", module)
    return module


def test_a_name_is_imported_on_first_use_and_then_kept(package: types.ModuleType) -> None:
    get, names = lazy_exports("lazy_demo", {"json": ("dumps",), "textwrap": ("dedent",)})
    assert "dumps" not in vars(package)
    import json

    assert get("dumps") is json.dumps
    assert vars(package)["dumps"] is json.dumps  # kept: the next use is a plain attribute
    assert {"dumps", "dedent"} <= set(names())


def test_an_unknown_name_is_an_attribute_error(package: types.ModuleType) -> None:
    get, _ = lazy_exports("lazy_demo", {"json": ("dumps",)})
    with pytest.raises(AttributeError, match="'lazy_demo' has no attribute 'loads'"):
        get("loads")


def test_a_name_from_two_modules_is_refused() -> None:
    with pytest.raises(ValueError, match="'dumps' is exported from two modules"):
        lazy_exports("lazy_demo", {"json": ("dumps",), "pickle": ("dumps",)})


def test_the_packages_still_export_every_name() -> None:
    import emulator
    import firmware_proto
    import planner
    import sim

    for package in (firmware_proto, emulator, planner, sim):
        assert [n for n in package.__all__ if getattr(package, n, None) is None] == []
        assert set(package.__all__) <= set(dir(package))


def test_building_the_rover_parser_loads_no_heavy_library() -> None:
    code = (
        "import sys\n"
        "from firmware_proto.cli import build_parser\n"
        "build_parser()\n"
        "heavy = ('jsonschema', 'fastjsonschema', 'numpy', 'pymunk', 'rclpy', 'scipy', "
        "'planner.ground.executor', 'emulator.twin')\n"
        "print(sorted(m for m in heavy if m in sys.modules))\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True
    )
    assert done.stdout.strip() == "[]", done.stdout + done.stderr
