"""The ROS 2 package: manifest, colcon glue, launch files and parameter files are well
formed and agree with each other and with pyproject.toml. No ROS here: the launch files
run against stand-ins of ``launch``/``launch_ros`` that record what they are given; the
real launch runs in CI (tests/bridge/launch_hil.py)."""

from __future__ import annotations

import argparse
import configparser
import importlib
import io
import os
import re
import runpy
import shutil
import subprocess
import sys
import types
import xml.etree.ElementTree as ET
from collections.abc import Callable
from contextlib import redirect_stdout
from pathlib import Path
from typing import Any

import pytest

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

from bridge.cli_onboard import add_arguments as onboard_arguments
from bridge.ros.params import BridgeParams
from emulator.cli_emulate import add_arguments as emulator_arguments
from gate.cli_gate import add_arguments as gate_arguments
from planner.ground.cli_go import add_arguments as executor_arguments
from planner.ground.cli_link import add_arguments as link_arguments

ROOT = Path(__file__).resolve().parents[2]
ROS_DIR = ROOT / "bridge" / "ros"
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
SCRIPTS: dict[str, str] = PYPROJECT["project"]["scripts"]
PACKAGE = "rover_hil"
LAUNCH_FILES = sorted((ROS_DIR / "launch").glob("*_launch.py"))

ROS_PACKAGES = {
    "rclpy",
    "builtin_interfaces",
    "std_msgs",
    "geometry_msgs",
    "nav_msgs",
    "diagnostic_msgs",
    "launch",
    "launch_ros",
    "launch_testing",
    "launch_testing_ros",
}
"""ROS 2 packages of every Jazzy installation (ros_base)."""
ROSDEP_KEYS = {
    "python3-can",
    "python3-jsonschema",
    "python3-numpy",
    "python3-pil",
    "python3-pytest",
    "python3-serial",
    "python3-yaml",
}
"""rosdep keys checked against ros/rosdistro rosdep/python.yaml (each has an ubuntu entry)."""
PYTHON_DEPENDENCY_KEYS = {
    "pyserial": "python3-serial",
    "python-can": "python3-can",
    "numpy": "python3-numpy",
    "jsonschema": "python3-jsonschema",
    "fastjsonschema": None,  # no rosdep key checked (Debian has python3-fastjsonschema)
    "pillow": "python3-pil",
    "pymunk": None,  # no rosdep key: pip install pymunk (docs/ros2.md)
    "mcap": None,  # no rosdep key checked: pip install, for recordings (docs/ros2.md)
    "mcap-ros2-support": None,  # the same
    # The HTTP stack (gate, live view): pip install, for the tested version range;
    # rosdep has python3-uvicorn (the distribution's, not checked against the range),
    # no key for starlette or h11.
    "starlette": None,
    "uvicorn": None,
    "h11": None,
    "tomli": None,  # Python < 3.11 only; Jazzy has 3.12
}
"""pyproject dependency -> rosdep key in package.xml (None: documented exception)."""

# -- package.xml -------------------------------------------------------------------------


@pytest.fixture(scope="module")
def manifest() -> ET.Element:
    return ET.parse(ROOT / "package.xml").getroot()


def test_manifest_is_format_3_ament_python_named_and_versioned(manifest: ET.Element) -> None:
    assert manifest.tag == "package"
    assert manifest.get("format") == "3"
    assert manifest.findtext("name") == PACKAGE
    assert manifest.findtext("version") == PYPROJECT["project"]["version"]
    assert manifest.findtext("export/build_type") == "ament_python"
    assert (manifest.findtext("description") or "").strip()
    assert manifest.findtext("license") == "Apache-2.0"
    maintainer = manifest.find("maintainer")
    assert maintainer is not None
    assert re.fullmatch(r"[^@\s]+@[^@\s]+\.[a-z]+", maintainer.get("email", ""))
    assert "package_format3.xsd" in (ROOT / "package.xml").read_text(encoding="utf-8")


def test_every_dependency_is_a_ros_package_or_a_known_rosdep_key(manifest: ET.Element) -> None:
    exec_depends = [e.text or "" for e in manifest.findall("exec_depend")]
    test_depends = [e.text or "" for e in manifest.findall("test_depend")]
    for key in exec_depends + test_depends:
        assert key in ROS_PACKAGES | ROSDEP_KEYS, f"{key}: not a ROS package or a checked key"
    assert len(set(exec_depends)) == len(exec_depends)
    assert {"rclpy", "std_msgs", "nav_msgs", "diagnostic_msgs", "geometry_msgs"} <= set(
        exec_depends
    )
    assert {"launch", "launch_ros"} <= set(exec_depends)


def test_every_python_dependency_has_its_rosdep_key(manifest: ET.Element) -> None:
    exec_depends = {e.text for e in manifest.findall("exec_depend")}
    for requirement in PYPROJECT["project"]["dependencies"]:
        name = re.split(r"[<>=;\[ ]", requirement, maxsplit=1)[0].lower()
        assert name in PYTHON_DEPENDENCY_KEYS, f"{name}: add its rosdep key to package.xml"
        key = PYTHON_DEPENDENCY_KEYS[name]
        assert key is None or key in exec_depends


# -- setup.py and setup.cfg -------------------------------------------------------------


def _run_setup_py(monkeypatch: pytest.MonkeyPatch, cwd: Path) -> dict[str, Any]:
    """What setup.py gives setup(), as colcon reads it."""
    captured: dict[str, Any] = {}
    setuptools = importlib.import_module("setuptools")
    monkeypatch.setattr(setuptools, "setup", lambda **kw: captured.update(kw))
    monkeypatch.chdir(cwd)
    runpy.run_path(str(cwd / "setup.py"), run_name="__main__")
    return captured


def test_setup_py_installs_the_marker_manifest_launch_and_config_files(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    kwargs = _run_setup_py(monkeypatch, ROOT)
    # Metadata comes from pyproject.toml, but for python_requires (see setup.py).
    assert set(kwargs) == {"data_files", "python_requires"}
    installed = {
        f"{dest}/{Path(src).name}": src for dest, sources in kwargs["data_files"] for src in sources
    }
    for src in installed.values():
        assert not Path(src).is_absolute()
        assert (ROOT / src).is_file(), src
    assert installed[f"share/ament_index/resource_index/packages/{PACKAGE}"]
    assert installed[f"share/{PACKAGE}/package.xml"] == "package.xml"
    launch = {k for k in installed if k.startswith(f"share/{PACKAGE}/launch/")}
    assert launch == {f"share/{PACKAGE}/launch/{p.name}" for p in LAUNCH_FILES}
    assert {f"share/{PACKAGE}/config/hil.yaml", f"share/{PACKAGE}/config/bridge.yaml"} <= set(
        installed
    )
    assert installed[f"share/{PACKAGE}/systemd/rover-bridge.service"] == str(
        ROS_DIR.relative_to(ROOT) / "systemd" / "rover-bridge.service"
    )
    layouts = {k for k in installed if k.startswith(f"share/{PACKAGE}/layouts/")}
    assert layouts == {
        f"share/{PACKAGE}/layouts/rover.rviz",
        f"share/{PACKAGE}/layouts/mission.foxglove.json",
    }


def test_symlink_install_gets_the_metadata_from_the_source_tree(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """colcon --symlink-install runs setup.py in the build directory, among symlinks and
    without pyproject.toml."""
    for name in ("setup.py", "setup.cfg", "package.xml", "firmware_proto", "bridge", "emulator"):
        (tmp_path / name).symlink_to(ROOT / name)
    kwargs = _run_setup_py(monkeypatch, tmp_path)
    assert kwargs["name"] == PYPROJECT["project"]["name"]
    assert kwargs["version"] == PYPROJECT["project"]["version"]
    assert sorted(kwargs["entry_points"]["console_scripts"]) == sorted(
        f"{k} = {v}" for k, v in SCRIPTS.items()
    )
    assert {"firmware_proto", "bridge", "emulator", "bridge.ros.rosport"} <= set(kwargs["packages"])
    assert kwargs["data_files"][0][1] == [f"bridge/ros/resource/{PACKAGE}"]


UDEV_FILES = sorted(p.name for p in (ROOT / "udev").iterdir() if p.is_file() and p.suffix != ".py")
TOP_PACKAGES = ("firmware_proto", "emulator", "bridge", "gate", "planner", "udev")


def _data_files(kwargs: dict[str, Any]) -> dict[str, str]:
    """Installed path (relative to the install prefix) -> source path, from setup()."""
    return {
        f"{dest}/{Path(src).name}": src for dest, sources in kwargs["data_files"] for src in sources
    }


def _colcon_symlink_build(monkeypatch: pytest.MonkeyPatch, build: Path) -> dict[str, Any]:
    """Lay out a build directory as colcon --symlink-install does (setup.py, setup.cfg,
    the top-level packages and each data file, as symlinks into the source tree; the data
    files as setup.py lists them from the source tree), then run setup.py in it."""
    data = _data_files(_run_setup_py(monkeypatch, ROOT))
    for item in ("setup.py", "setup.cfg", *TOP_PACKAGES, *data.values()):
        if not (build / item).exists():  # e.g. bridge/ros/... inside the bridge symlink
            (build / item).parent.mkdir(parents=True, exist_ok=True)
            (build / item).symlink_to(ROOT / item)
    return _run_setup_py(monkeypatch, build)


def test_setup_py_installs_the_udev_files_plainly_and_with_symlinks(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    want = {f"share/{PACKAGE}/udev/{name}": f"udev/{name}" for name in UDEV_FILES}
    assert {"99-rover-motor.rules", "80-rovercan0.network", "can-up.sh"} <= set(UDEV_FILES)
    plain = _data_files(_run_setup_py(monkeypatch, ROOT))
    assert {k: v for k, v in plain.items() if "/udev/" in k} == want
    linked = _data_files(_colcon_symlink_build(monkeypatch, tmp_path))
    assert {k: v for k, v in linked.items() if "/udev/" in k} == want
    assert all((tmp_path / src).is_file() for src in want.values())


_RUN_INSTALLED = """
import sys
sys.path.insert(0, sys.argv[1])
import udev.install
from firmware_proto.cli import main
print("MODULE", udev.install.__file__)
print("SOURCE", udev.install.source_dir())
sys.exit(main(["udev", "install", "--dry-run", "--no-reload",
               "--rules-dir", sys.argv[2], "--network-dir", sys.argv[3]]))
"""


def _rover_udev_install_from(site: Path, tmp_path: Path) -> dict[str, str]:
    """``rover udev install --dry-run`` run by a Python that imports our packages from
    ``site``, as ``ros2 run`` does from a colcon install; its MODULE and SOURCE lines."""
    env = {k: v for k, v in os.environ.items() if k != "ROVER_UDEV_DIR"}
    etc = tmp_path / "etc"
    argv = [sys.executable, "-c", _RUN_INSTALLED, str(site), str(etc / "rules.d"), str(etc / "net")]
    done = subprocess.run(
        argv, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=60, check=False
    )
    assert done.returncode == 0, done.stderr
    assert "would install" in done.stdout and "99-rover-motor.rules" in done.stdout
    return dict(
        line.split(" ", 1)
        for line in done.stdout.splitlines()
        if line.startswith(("MODULE", "SOURCE"))
    )


def test_rover_udev_install_finds_the_files_of_a_plain_install(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """A colcon build without --symlink-install copies the packages to the prefix's
    site-packages and the data files under share/: no checkout's udev/ is in reach, and
    no --source is needed."""
    prefix = tmp_path / "install" / PACKAGE
    site = prefix / "lib" / f"python{sys.version_info[0]}.{sys.version_info[1]}" / "site-packages"
    for package in TOP_PACKAGES:
        # As pip copies a package: its code and package data, not udev/'s rules.
        shutil.copytree(
            ROOT / package,
            site / package,
            ignore=shutil.ignore_patterns("__pycache__", "*.rules", "*.network", "*.sh"),
        )
    for dest, src in _data_files(_run_setup_py(monkeypatch, ROOT)).items():
        (prefix / dest).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(ROOT / src, prefix / dest)
    found = _rover_udev_install_from(site, tmp_path)
    assert Path(found["MODULE"]).is_relative_to(site)
    assert Path(found["SOURCE"]) == prefix / "share" / PACKAGE / "udev"


def test_rover_udev_install_finds_the_source_udev_of_a_symlink_install(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """With --symlink-install the packages are imported from the build directory, through
    symlinks into the source tree, whose udev/ is the one found."""
    build = tmp_path / "build" / PACKAGE
    build.mkdir(parents=True)
    _colcon_symlink_build(monkeypatch, build)
    found = _rover_udev_install_from(build, tmp_path)
    assert Path(found["MODULE"]).is_relative_to(build)
    assert Path(found["SOURCE"]) == ROOT / "udev"


def test_setup_cfg_puts_executables_where_ros2_run_looks() -> None:
    config = configparser.ConfigParser()
    config.read(ROOT / "setup.cfg")
    assert config["develop"]["script_dir"] == f"$base/lib/{PACKAGE}"
    assert config["install"]["install_scripts"] == f"$base/lib/{PACKAGE}"
    assert "metadata" not in config  # else colcon reads options from here, not setup.py


# -- console scripts -------------------------------------------------------------------


@pytest.mark.parametrize(("script", "target"), sorted(SCRIPTS.items()))
def test_console_scripts_answer_help(
    script: str, target: str, capsys: pytest.CaptureFixture[str]
) -> None:
    module_name, _, func_name = target.partition(":")
    main = getattr(importlib.import_module(module_name), func_name)
    with pytest.raises(SystemExit) as exit_info:
        main(["--help"])
    assert exit_info.value.code == 0
    assert "usage:" in capsys.readouterr().out


# -- launch files ------------------------------------------------------------------------


class _Stub:
    """A stand-in for a launch class: keeps its arguments."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self.args = args
        self.kwargs = kwargs


def _stub_modules() -> dict[str, types.ModuleType]:
    classes = {
        "launch": ["LaunchDescription"],
        "launch.actions": ["DeclareLaunchArgument", "IncludeLaunchDescription"],
        "launch.conditions": ["IfCondition", "UnlessCondition"],
        "launch.substitutions": [
            "LaunchConfiguration",
            "PathJoinSubstitution",
            "PythonExpression",
        ],
        "launch_ros": [],
        "launch_ros.actions": ["Node"],
        "launch_ros.parameter_descriptions": ["ParameterValue"],
        "launch_ros.substitutions": ["FindPackageShare"],
    }
    modules = {}
    for name, class_names in classes.items():
        module = types.ModuleType(name)
        for class_name in class_names:
            setattr(module, class_name, type(class_name, (_Stub,), {}))
        modules[name] = module
    return modules


def _walk(value: Any) -> list[_Stub]:
    """Every stub reachable from ``value`` (arguments, lists, dicts)."""
    found: list[_Stub] = []
    stack = [value]
    while stack:
        item = stack.pop()
        if isinstance(item, _Stub):
            found.append(item)
            stack += [*item.args, *item.kwargs.values()]
        elif isinstance(item, (list, tuple)):
            stack += list(item)
        elif isinstance(item, dict):
            stack += [*item.keys(), *item.values()]
    return found


def _load(path: Path, monkeypatch: pytest.MonkeyPatch) -> dict[str, Any]:
    """Run a launch file's module against the stand-ins; its namespace."""
    for name, module in _stub_modules().items():
        monkeypatch.setitem(sys.modules, name, module)
    return runpy.run_path(str(path), run_name="launch_file")


@pytest.fixture(params=LAUNCH_FILES, ids=lambda p: p.name)
def launched(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> list[_Stub]:
    """Everything one launch file's description holds, run against the stand-ins."""
    path: Path = request.param
    compile(path.read_text(encoding="utf-8"), str(path), "exec")
    namespace = _load(path, monkeypatch)
    description = namespace["generate_launch_description"]()
    assert type(description).__name__ == "LaunchDescription"
    return _walk(description)


def _of(stubs: list[_Stub], kind: str) -> list[_Stub]:
    return [s for s in stubs if type(s).__name__ == kind]


def test_launch_arguments_carry_descriptions(launched: list[_Stub]) -> None:
    declared = _of(launched, "DeclareLaunchArgument")
    assert declared
    for arg in declared:
        assert len(arg.kwargs.get("description", "")) > 10, arg.args
        assert "default_value" in arg.kwargs, arg.args
    names = {a.args[0] for a in declared}
    used = {c.args[0] for c in _of(launched, "LaunchConfiguration")}
    assert used <= names, f"used but not declared: {used - names}"


def test_launched_executables_are_declared_console_scripts(launched: list[_Stub]) -> None:
    nodes = _of(launched, "Node")
    assert nodes
    for node in nodes:
        assert node.kwargs["package"] == PACKAGE
        assert node.kwargs["executable"] in SCRIPTS
        assert node.kwargs["name"] == node.kwargs["executable"]
        assert node.kwargs.get("output") == "screen"


def test_launch_files_name_parameter_files_that_exist(launched: list[_Stub]) -> None:
    shares = _of(launched, "PathJoinSubstitution")
    assert shares
    for join in shares:
        find, *parts = join.args[0]
        assert type(find).__name__ == "FindPackageShare"
        assert find.args == (PACKAGE,)
        assert (ROS_DIR / Path(*parts)).is_file(), parts


def test_the_hil_launch_starts_the_whole_set(monkeypatch: pytest.MonkeyPatch) -> None:
    namespace = _load(ROS_DIR / "launch" / "hil_launch.py", monkeypatch)
    description = namespace["generate_launch_description"]()
    executables = {n.kwargs["executable"] for n in _of(_walk(description), "Node")}
    assert (
        executables
        == set(namespace["NODES"])
        == {
            "rover_emulator",
            "rover_bridge",
            "rover_onboard",
            "rover_gate",
            "rover_link",
            "rover_executor",
        }
    )


def test_the_ci_launch_test_names_a_launch_file_that_exists() -> None:
    source = (ROOT / "tests" / "bridge" / "launch_hil.py").read_text(encoding="utf-8")
    compile(source, "launch_hil.py", "exec")
    match = re.search(r'LAUNCH_FILE = \("rover_hil", "launch", "(\w+\.py)"\)', source)
    assert match is not None
    assert (ROS_DIR / "launch" / match.group(1)).is_file()


# -- parameter files -----------------------------------------------------------------------


def _sections(path: Path) -> dict[str, dict[str, str]]:
    """``section -> {parameter: value}`` of our simple parameter files (no PyYAML here):
    top-level keys, ``ros__parameters``, then one ``name: value`` per line."""
    sections: dict[str, dict[str, str]] = {}
    current: dict[str, str] = {}
    for raw in path.read_text(encoding="utf-8").splitlines():
        line = raw.split(" #", 1)[0].rstrip()
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        indent = len(line) - len(line.lstrip())
        key, _, value = line.strip().partition(":")
        if indent == 0:
            current = sections.setdefault(key, {})
        elif indent == 2:
            assert key == "ros__parameters", raw
        else:
            assert indent == 4, raw
            current[key] = value.strip()
    return sections


OPTIONS: dict[str, Callable[[argparse.ArgumentParser], None]] = {
    "rover_emulator": emulator_arguments,
    "rover_gate": gate_arguments,
    "rover_link": link_arguments,
    "rover_executor": executor_arguments,
    "rover_onboard": onboard_arguments,
}
"""The nodes that are not ROS nodes: their options, which their parameters stand for."""


def _options(add_arguments: Callable[[argparse.ArgumentParser], None]) -> set[str]:
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    return {
        option[2:].replace("-", "_")
        for action in parser._actions
        for option in action.option_strings
        if option.startswith("--")
    }


def test_the_hil_parameters_are_options_or_parameters_of_their_nodes(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    sections = _sections(ROS_DIR / "config" / "hil.yaml")
    namespace = _load(ROS_DIR / "launch" / "hil_launch.py", monkeypatch)
    description = namespace["generate_launch_description"]()
    with_params = {
        n.kwargs["name"] for n in _of(_walk(description), "Node") if n.kwargs.get("parameters")
    }
    assert with_params == set(namespace["NODES"])
    assert set(sections) == {f"/**/{name}" for name in with_params}
    for name, add_arguments in OPTIONS.items():
        assert set(sections[f"/**/{name}"]) <= _options(add_arguments), name
    emulator = sections["/**/rover_emulator"]
    bridge = sections["/**/rover_bridge"]
    assert set(bridge) <= set(BridgeParams.__dataclass_fields__)
    assert bridge["device"] == emulator["link"]  # the bridge opens the emulator's pty


def test_the_bridge_parameters_are_bridge_parameters_and_floats_stay_floats() -> None:
    sections = _sections(ROS_DIR / "config" / "bridge.yaml")
    assert set(sections) == {"/**/rover_bridge"}
    params = sections["/**/rover_bridge"]
    fields = BridgeParams.__dataclass_fields__
    assert set(params) <= set(fields)
    for name, value in params.items():
        if fields[name].type == "float":
            assert "." in value, f"{name}: {value} would be an integer to ROS"
    # The link comes from the launch arguments, not from this file.
    assert not set(params) & {"device", "baud", "can_interface", "can_channel", "node_id"}


def test_the_emulator_takes_its_hil_section_as_options() -> None:
    """What rover_emulator makes of the hil.yaml section (as PyYAML would load it)."""
    from firmware_proto.cli.rosargs import argv_from_ros_args

    section = _sections(ROS_DIR / "config" / "hil.yaml")["/**/rover_emulator"]
    typed = {k: True if v == "true" else v for k, v in section.items()}
    doc = {"/**/rover_emulator": {"ros__parameters": typed}}
    argv = argv_from_ros_args(["--params-file", "hil.yaml"], "rover_emulator", lambda _p: doc)
    parser = argparse.ArgumentParser()
    emulator_arguments(parser)
    with redirect_stdout(io.StringIO()):
        args = parser.parse_args(argv)
    assert args.serial is True
    assert args.link == section["link"]
    assert args.speed_factor == float(section["speed_factor"])


@pytest.mark.parametrize("node", sorted(OPTIONS))
def test_each_program_reads_its_hil_section_with_pyyaml(node: str) -> None:
    """The real file through PyYAML, as the launch file hands it over; options given on
    the command line (what the launch arguments become) win over the file."""
    pytest.importorskip("yaml", reason="PyYAML (the ros-params extra, or ROS 2) is missing")
    from firmware_proto.cli.rosparams import parse_args_with_ros_args

    parser = argparse.ArgumentParser()
    OPTIONS[node](parser)
    section = _sections(ROS_DIR / "config" / "hil.yaml")[f"/**/{node}"]
    given = ["--goal", "2,3,90"] if node == "rover_executor" else []
    argv = [*given, "--ros-args", "--params-file", str(ROS_DIR / "config" / "hil.yaml")]
    args = parse_args_with_ros_args(parser, argv, node)
    for key, text in section.items():
        value = getattr(args, "default_map" if (node, key) == ("rover_gate", "map") else key)
        assert str(value) == text or value == (text == "true"), (key, value, text)
    if node == "rover_link":
        args = parse_args_with_ros_args(parser, ["--seed", "9", *argv], node)
        assert args.seed == 9


@pytest.mark.rclpy
@pytest.mark.parametrize("node", ["rover_link", "rover_executor"])
def test_rcl_reads_the_ros_arguments_of_the_programs_that_load_rclpy(
    node: str, tmp_path: Path
) -> None:
    """Where rclpy is loaded anyway, rcl's own parser reads ``--ros-args`` (issue #41):
    the same options as the pure reader for the shipped file, ``-p`` winning over it,
    ``-r __node:=`` choosing the section, and a malformed argument refused in rcl's
    words (a usage error, exit 2)."""
    from firmware_proto.cli.rosparams import parse_args_with_ros_args

    parser = argparse.ArgumentParser(prog=node)
    OPTIONS[node](parser)
    given = ["--goal", "2,3,90"] if node == "rover_executor" else []
    argv = [*given, "--ros-args", "--params-file", str(ROS_DIR / "config" / "hil.yaml")]
    by_rcl = parse_args_with_ros_args(parser, argv, node, with_rclpy=True)
    assert vars(by_rcl) == vars(parse_args_with_ros_args(parser, argv, node))
    if node == "rover_link":
        assert parse_args_with_ros_args(parser, [*argv, "-p", "seed:=5"], node).seed == 5
        mine = tmp_path / "params.yaml"
        mine.write_text(
            "/**/rover_link:\n  ros__parameters:\n    rtt: 0.5\n"
            "/**/relay_b:\n  ros__parameters:\n    rtt: 0.25\n"
        )
        ros = ["--ros-args", "--params-file", str(mine)]
        read = parse_args_with_ros_args(parser, ros, node, with_rclpy=True)
        assert read.rtt == 0.5
        renamed = [*ros, "-r", "__node:=relay_b"]  # another node name: its section
        assert parse_args_with_ros_args(parser, renamed, node, with_rclpy=True).rtt == 0.25
    with pytest.raises(SystemExit) as refused:
        parse_args_with_ros_args(parser, [*given, "--ros-args", "-p", "bad"], node, with_rclpy=True)
    assert refused.value.code == 2


@pytest.mark.slow
@pytest.mark.parametrize("mode", [[], ["--symlink-install"]], ids=["copy", "symlink"])
def test_colcon_builds_the_package_and_its_executables_start(
    tmp_path: Path, mode: list[str]
) -> None:
    """colcon-core and colcon-ros from PyPI (the colcon extra) build this repository as
    the rover_hil package; the install space has its executables and its ament index."""
    colcon = shutil.which("colcon", path=str(Path(sys.executable).parent))
    if colcon is None:
        pytest.skip("colcon is not installed (the colcon extra)")
    (tmp_path / "src").mkdir()
    (tmp_path / "src" / PACKAGE).symlink_to(ROOT)
    env = {
        k: v for k, v in os.environ.items() if k not in ("AMENT_PREFIX_PATH", "COLCON_PREFIX_PATH")
    }
    done = subprocess.run(
        [colcon, "build", *mode, "--event-handlers", "console_direct+"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
        env=env,
        check=False,
    )
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    prefix = tmp_path / "install" / PACKAGE
    for script in SCRIPTS:
        if script == "rover":
            continue  # not a ROS executable (bin/ in a pip install, lib/ here: setup.cfg)
        exe = prefix / "lib" / PACKAGE / script
        assert exe.is_file(), script
        ran = subprocess.run(
            [str(exe), "--help"], capture_output=True, text=True, timeout=60, check=False
        )
        assert ran.returncode == 0 and "usage:" in ran.stdout, (script, ran.stderr)
    lookup = subprocess.run(
        [
            sys.executable,
            "-c",
            "from ament_index_python.packages import get_package_share_directory as g;"
            f"print(g('{PACKAGE}'))",
        ],
        capture_output=True,
        text=True,
        timeout=60,
        env={**env, "AMENT_PREFIX_PATH": str(prefix)},
        check=False,
    )
    assert lookup.returncode == 0, lookup.stderr
    share = Path(lookup.stdout.strip())
    assert share == prefix / "share" / PACKAGE
    assert {p.name for p in (share / "launch").iterdir()} == {p.name for p in LAUNCH_FILES}
    assert (share / "package.xml").is_file() and (share / "udev" / "99-rover-motor.rules").exists()
    # The Fast DDS profile goes with the Python package (docs/rosport.md, "Discovery"): a
    # copy in the install space; a symlink install runs the sources, where it is.
    if "--symlink-install" not in mode:
        assert list(prefix.rglob("bridge/ros/rosport/fastdds_profile.xml"))


def _documented_colcon_lines() -> list[str]:
    """The colcon and ``source install/...`` lines of docs/ros2.md's workspace recipe,
    as written."""
    text = (ROOT / "docs" / "ros2.md").read_text()
    recipe = text.split("## Building in a Jazzy workspace", 1)[1].split("```", 2)[1]
    return [
        line
        for line in recipe.splitlines()
        if line.startswith("colcon ") or line.startswith("source install/")
    ]


@pytest.mark.slow
def test_the_documented_colcon_commands_run_as_written(tmp_path: Path) -> None:
    """docs/ros2.md's `colcon build --packages-select rover_hil` and `source
    install/setup.bash`, line for line, in a workspace whose src/ holds this checkout;
    the sourced environment finds the package (ament index) and its executables."""
    lines = _documented_colcon_lines()
    assert any(line.startswith("colcon build --packages-select rover_hil") for line in lines)
    assert "source install/setup.bash" in [line.split("#")[0].strip() for line in lines]
    bin_dir = Path(sys.executable).parent
    if shutil.which("colcon", path=str(bin_dir)) is None:
        pytest.skip("colcon is not installed (the colcon extra)")
    (tmp_path / "src").mkdir()
    (tmp_path / "src" / PACKAGE).symlink_to(ROOT)
    script = "\n".join(
        [
            "set -e",
            *lines,
            'test "$AMENT_PREFIX_PATH" = "$PWD/install/rover_hil"',
            f"test -x install/{PACKAGE}/lib/{PACKAGE}/rover_bridge",
            f'{sys.executable} -c "from ament_index_python.packages import '
            f"get_package_share_directory as g; print(g('{PACKAGE}'))\"",
        ]
    )
    env = {
        k: v for k, v in os.environ.items() if k not in ("AMENT_PREFIX_PATH", "COLCON_PREFIX_PATH")
    }
    env["PATH"] = f"{bin_dir}:{env.get('PATH', '')}"
    done = subprocess.run(
        ["bash", "-c", script],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
        env=env,
        check=False,
    )
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    assert done.stdout.strip().splitlines()[-1] == str(
        tmp_path / "install" / PACKAGE / "share" / PACKAGE
    )
