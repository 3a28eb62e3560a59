"""Package hygiene: public names, and the direction of dependencies (docs/architecture.md: the
planner talks to the gate over HTTP and never imports the gate or the emulator)."""

from __future__ import annotations

import importlib
import subprocess
import sys

import pytest

from planner import errors

MODULES = [
    "planner",
    "planner.ground.console",
    "planner.stack.demo",
    "planner.stack.domains",
    "planner.ground.drift",
    "planner.errors",
    "planner.ground.executor",
    "planner.plan.experiment",
    "planner.record.foxlive",
    "planner.plan.gate_client",
    "planner.ground.interrupt",
    "planner.record.markers",
    "planner.record.mcaprec",
    "planner.ground.mission",
    "planner.plan.orchestrator",
    "planner.record.picture",
    "planner.plan.planner",
    "planner.ground.relay",
    "planner.plan.repairs",
    "planner.ground.roverstatus",
    "planner.stack.processes",
    "planner.stack.stackenv",
    "planner.view",
    "planner.view.hub",
    "planner.view.live",
    "planner.view.server",
]


@pytest.mark.parametrize("name", MODULES)
def test_public_names_are_sorted_and_exist(name: str) -> None:
    module = importlib.import_module(name)
    names = module.__all__
    assert names == sorted(names, key=lambda n: (not n.isupper(), n))
    for n in names:
        assert getattr(module, n) is not None


def test_the_package_reexports_the_modules_objects() -> None:
    import planner

    # The pose, the point and the verdict are the shared model of firmware_proto (the gate
    # builds what the planner reads), re-exported here for an operator's script.
    shared = {"Pose": "firmware_proto.model.pose", "Trajectory": "firmware_proto.model.verdict"}
    shared["Point"] = "firmware_proto.model.geometry"
    shared["Verdict"] = "firmware_proto.model.verdict"
    modules = [importlib.import_module(m) for m in MODULES[1:]]
    for name in planner.__all__:
        homes = [m for m in modules if name in m.__all__]
        if name in shared:
            assert not homes, (name, homes)
            homes = [importlib.import_module(shared[name])]
        assert len(homes) == 1, (name, homes)
        assert getattr(homes[0], name) is getattr(planner, name), name


def test_planner_imports_neither_gate_nor_emulator() -> None:
    code = (
        "import sys\n"
        + "".join(f"import {m}\n" for m in MODULES)
        + "bad = sorted(m for m in sys.modules if m.split('.')[0] in ('gate', 'emulator'))\n"
        + "assert not bad, bad\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, timeout=60)


def test_one_exception_root() -> None:
    for name in errors.__all__:
        cls = getattr(errors, name)
        assert issubclass(cls, errors.PlannerError)
    assert issubclass(errors.InvalidPoseError, ValueError)
    assert issubclass(errors.GateUnavailableError, ConnectionError)
    assert issubclass(errors.GateTimeoutError, TimeoutError)
    assert issubclass(errors.GateOverloadedError, errors.GateStatusError)
    for failure in (errors.GateStatusError, errors.GateUnavailableError, errors.GateProtocolError):
        assert issubclass(failure, errors.GateCallError)
    # Distinct names: the gate's root and the planner's errors about reaching it.
    assert not hasattr(errors, "GateError") and not hasattr(errors, "ConfigError")
    assert issubclass(errors.GoalInObstacleError, errors.InvalidPoseError)
