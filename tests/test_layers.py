"""The arrows between the parts point down (docs/architecture.md, Parts and layers).

Read from the sources' import statements (every ``import``, at module level or inside a
function), so a lazy import counts as much as a top-level one:

- ``firmware_proto.wire`` (the wire protocol) and ``firmware_proto.model`` (the mission
  models) are pure: no python-can, pyserial, threads, sockets, ROS, HTTP, and none of the
  base's I/O folders (``linkio``, ``http``, ``runtime``, ``cli``); every module of the
  base sits in one of these six folders, but its exceptions and lazy exports;
- ``firmware_proto.linkio`` (both ends of the wire) and ``firmware_proto.http``
  (the HTTP stack of the gate and the live view) import no part above them, not each
  other, and not the command host;
- ``firmware_proto.runtime`` (scheduling, stall detection) imports nothing of ours but
  the pure protocol;
- the planner reaches the gate over HTTP only and the bridge through its ROS port only:
  of the parts above ``firmware_proto`` it imports ``bridge.ros.rosport`` and nothing else;
- the emulator and the bridge never import each other; the gate imports neither the
  bridge nor the planner; the rover's device tooling (``udev``) imports none of them;
- the simulator (``sim``) sits on top of every part but ``udev``: the wire simulator
  imports the bridge and the emulator, a whole mission in virtual time the planner and
  the gate too; no part imports it;
- no module imports itself back through others: the modules of all seven parts form no
  import circle (an import for type checking only counts too).
"""

from __future__ import annotations

import ast
import functools
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

IMPURE = {"can", "serial", "threading", "socket", "select", "rclpy", "asyncio", "subprocess"}
"""What the pure protocol must not import."""


def _modules(package: str) -> dict[str, Path]:
    base = ROOT / package
    found = {}
    for path in sorted(base.rglob("*.py")):
        parts = path.relative_to(ROOT).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        found[name] = path
    return found


@functools.cache
def _imports(path: Path) -> frozenset[str]:
    """Every module name an import statement in ``path`` names (absolute imports only:
    the project uses no relative ones outside tests). Read once per run (the tests below
    ask of the same files many times)."""
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            names.add(node.module)
            names.update(f"{node.module}.{alias.name}" for alias in node.names)
    return frozenset(names)


def _under(name: str, prefix: str) -> bool:
    return name == prefix or name.startswith(prefix + ".")


FIRMWARE_PROTO = _modules("firmware_proto")
PURE_FOLDERS = ("firmware_proto.wire", "firmware_proto.model")
"""The pure folders of the base: the wire protocol and the mission models."""
IO_FOLDERS = (
    "firmware_proto.linkio",
    "firmware_proto.http",
    "firmware_proto.runtime",
    "firmware_proto.cli",
)
"""The folders of the base that do I/O or system calls."""
TOP = {"firmware_proto", "firmware_proto.errors", "firmware_proto.lazyexports"}
"""The package's own modules: its exceptions and its lazy exports, pure too."""
PURE = {
    name: path
    for name, path in FIRMWARE_PROTO.items()
    if name in TOP or any(_under(name, folder) for folder in PURE_FOLDERS)
}


def test_every_module_of_the_base_is_in_one_folder() -> None:
    # A module left at the top, or in a folder of no rule, would pass every other test.
    folders = PURE_FOLDERS + IO_FOLDERS
    loose = sorted(
        name
        for name in FIRMWARE_PROTO
        if name not in TOP and not any(_under(name, f) for f in folders)
    )
    assert loose == []
    assert "firmware_proto.wire.framing" in PURE and "firmware_proto.model.verdict" in PURE
    assert not any(_under(name, f) for name in PURE for f in IO_FOLDERS)


@pytest.mark.parametrize("name", sorted(PURE))
def test_the_protocol_is_pure(name: str) -> None:
    wrong = sorted(
        imported
        for imported in _imports(PURE[name])
        if imported.split(".")[0] in IMPURE | {"uvicorn", "starlette", "h11"}
        or any(_under(imported, folder) for folder in IO_FOLDERS)
        or imported.split(".")[0] in {"bridge", "emulator", "gate", "planner", "sim"}
    )
    assert not wrong, f"{name} imports {wrong}"


def test_importing_the_protocol_loads_no_io_library() -> None:
    code = (
        "import sys\n"
        + "".join(f"import {name}\n" for name in sorted(PURE))
        + "print(sorted(m for m in ('can', 'serial', 'rclpy') if m in sys.modules))\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=60
    ).stdout
    assert out.strip() == "[]"


def test_a_serial_link_never_loads_python_can() -> None:
    code = (
        "import sys\n"
        "import bridge.link.controllerlink, bridge.link.serial_transport\n"
        "import emulator.serial_frontend\n"
        "import firmware_proto.linkio.serial_endpoint, firmware_proto.linkio.replay_peer\n"
        "import firmware_proto.linkio.host, firmware_proto.linkio.media, emulator.lockstep\n"
        "import bridge.tools.conformance, bridge.tools.cli_conformance\n"
        "print('can' in sys.modules)\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=60
    ).stdout
    assert out.strip() == "False"


@pytest.mark.parametrize(
    ("package", "forbidden"),
    [
        (
            "firmware_proto/linkio",
            (
                "bridge",
                "emulator",
                "gate",
                "planner",
                "firmware_proto.cli",
                "firmware_proto.http",
            ),
        ),
        (
            "firmware_proto/runtime",
            (
                "bridge",
                "emulator",
                "gate",
                "planner",
                "firmware_proto.cli",
                "firmware_proto.linkio",
                "firmware_proto.http",
            ),
        ),
        (
            "firmware_proto/http",
            (
                "bridge",
                "emulator",
                "gate",
                "planner",
                "firmware_proto.cli",
                "firmware_proto.linkio",
            ),
        ),
        ("emulator", ("bridge", "gate", "planner", "sim")),
        ("bridge", ("emulator", "gate", "planner", "sim")),
        ("gate", ("bridge", "planner", "sim")),
        ("planner", ("gate", "emulator", "udev", "sim")),
        ("udev", ("firmware_proto", "emulator", "bridge", "gate", "planner", "sim")),
        ("sim", ("udev",)),
    ],
)
def test_arrows_point_down(package: str, forbidden: tuple[str, ...]) -> None:
    wrong = {
        name: sorted(i for i in _imports(path) if any(_under(i, f) for f in forbidden))
        for name, path in _modules(package).items()
    }
    assert not {k: v for k, v in wrong.items() if v}


def test_the_planner_uses_only_the_bridges_ros_port() -> None:
    wrong = {
        name: sorted(
            i for i in _imports(path) if _under(i, "bridge") and not _under(i, "bridge.ros.rosport")
        )
        for name, path in _modules("planner").items()
    }
    assert not {k: v for k, v in wrong.items() if v}


PACKAGES = ("firmware_proto", "emulator", "bridge", "gate", "planner", "udev", "sim")


@functools.cache
def _targets(path: Path) -> frozenset[str]:
    """The modules an import statement in ``path`` loads: ``from a.b import c`` loads
    module ``a.b.c`` where there is one, else ``a.b`` (its package is loaded either
    way, but importing from a package is no import of the package's own name). Read once
    per run."""
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            for alias in node.names:
                full = f"{node.module}.{alias.name}"
                where = ROOT / full.replace(".", "/")
                is_module = where.is_dir() or where.with_suffix(".py").is_file()
                names.add(full if is_module else node.module)
    return frozenset(names)


def _circles() -> list[list[str]]:
    """Every set of two or more of our modules that import each other in a circle."""
    modules = {name: path for package in PACKAGES for name, path in _modules(package).items()}
    graph = {
        name: {target for target in _targets(path) if target in modules and target != name}
        for name, path in modules.items()
    }
    order: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found: list[list[str]] = []

    def visit(v: str) -> None:  # Tarjan's strongly connected components
        order[v] = low[v] = len(order)
        stack.append(v)
        for w in graph[v]:
            if w not in order:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], order[w])
        if low[v] == order[v]:
            component = []
            while True:
                w = stack.pop()
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for name in sorted(graph):
        if name not in order:
            visit(name)
    return found


def test_no_import_circle() -> None:
    assert _circles() == []


def test_the_circle_check_sees_a_circle(monkeypatch: pytest.MonkeyPatch) -> None:
    real = _targets

    def with_a_circle(path: Path) -> frozenset[str]:
        extra = {"planner.plan.orchestrator"} if path == ROOT / "planner" / "errors.py" else set()
        return real(path) | extra

    monkeypatch.setattr(sys.modules[__name__], "_targets", with_a_circle)
    assert any("planner.errors" in c and "planner.plan.orchestrator" in c for c in _circles())
