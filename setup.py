"""Build glue for ROS 2: colcon builds an ament_python package by running this file.

Everything about the Python distribution (name, version, dependencies, packages, console
scripts, entry points) lives in pyproject.toml, which setuptools reads by itself. This
file only adds the ROS 2 data files (docs/ros2.md):

- the package marker for the ament index (``bridge/ros/resource/rover_hil``), so that
  ``ros2 run`` and ``ros2 launch`` find the package;
- ``package.xml``, the launch files (``bridge/ros/launch/*_launch.py``), the
  parameter files (``bridge/ros/config/*.yaml``), the bridge's systemd unit
  (``bridge/ros/systemd/*.service``) and the RViz and Foxglove layouts
  (``bridge/ros/layouts/``) under ``share/rover_hil``;
- the ``udev/`` files (rules, networkd file, bring-up scripts, README) under
  ``share/rover_hil/udev``, where ``rover udev install`` and ``rover devices`` find them
  in an install (udev/install.py).

Under ``colcon build --symlink-install`` colcon runs this file from the build directory,
next to symlinks of setup.py, setup.cfg, the packages and the data files but without
pyproject.toml; the metadata is then read from the source tree's pyproject.toml and given
to ``setup()`` directly.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

from setuptools import find_namespace_packages, setup

PACKAGE = "rover_hil"
PYTHON_REQUIRES = ">=3.10"
"""Here, not in pyproject.toml (where it is declared dynamic): setuptools keeps a
``python_requires`` given to ``setup()`` as the string it is, which colcon's
``ast.literal_eval`` of the metadata can read (a SpecifierSet made from pyproject.toml
cannot be)."""
SOURCE = Path(__file__).resolve().parent  # the source tree, even through a symlink
ROS_DIR = Path("bridge") / "ros"


def _files(folder: Path, pattern: str) -> list[str]:
    """Data files in a folder of the source tree, relative to it, sorted."""
    return sorted(
        str(path.relative_to(SOURCE))
        for path in (SOURCE / folder).glob(pattern)
        if path.is_file() and not path.name.startswith(".")
    )


DATA_FILES = [
    ("share/ament_index/resource_index/packages", [str(ROS_DIR / "resource" / PACKAGE)]),
    (f"share/{PACKAGE}", ["package.xml"]),
    (f"share/{PACKAGE}/launch", _files(ROS_DIR / "launch", "*_launch.py")),
    (f"share/{PACKAGE}/config", _files(ROS_DIR / "config", "*.yaml")),
    (f"share/{PACKAGE}/systemd", _files(ROS_DIR / "systemd", "*.service")),
    (f"share/{PACKAGE}/layouts", _files(ROS_DIR / "layouts", "*")),
    # udev/ holds its tooling's code (the udev package) beside the rules: code is no data.
    (f"share/{PACKAGE}/udev", [f for f in _files(Path("udev"), "*") if not f.endswith(".py")]),
]


def _metadata_from_pyproject() -> dict[str, Any]:
    """setup() arguments from the source tree's pyproject.toml (symlink-install only)."""
    # Imported here: only this path needs it, and tomli only exists where pyproject asks.
    if sys.version_info >= (3, 11):
        import tomllib  # noqa: PLC0415
    else:  # pragma: no cover
        import tomli as tomllib  # noqa: PLC0415

    doc = tomllib.loads((SOURCE / "pyproject.toml").read_text(encoding="utf-8"))
    project = doc["project"]
    tool = doc["tool"]["setuptools"]
    entry_points = {"console_scripts": [f"{k} = {v}" for k, v in project["scripts"].items()]}
    for group, items in project.get("entry-points", {}).items():
        entry_points[group] = [f"{k} = {v}" for k, v in items.items()]
    return {
        "name": project["name"],
        "version": project["version"],
        "description": project["description"],
        "packages": find_namespace_packages(where=".", include=tool["packages"]["find"]["include"]),
        "package_data": tool.get("package-data", {}),
        "entry_points": entry_points,
    }


setup(
    data_files=DATA_FILES,
    python_requires=PYTHON_REQUIRES,
    **({} if Path("pyproject.toml").exists() else _metadata_from_pyproject()),
)
