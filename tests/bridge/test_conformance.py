"""``rover conformance`` against the emulator.

One suite, two implementations (the Python controller model and the C firmware core,
``--firmware c``, emulator/firmware.py), two ways to run:

- in lockstep (virtual time, :mod:`tests.bridge.lockstep_suite`): every rule, against
  both controllers on both media (an in-memory serial line, a python-can ``virtual``
  bus), and the C core built with ASan and UBSan in a process of its own;
- in real time, a smoke run of the rules that touch each part of the path (handshake,
  samples, a stop, receive errors, the watchdog, a fault, a reboot, the frame counter)
  against each controller on each medium: the emulator as its own process on a
  pty, and in process on a python-can ``virtual`` bus; also without a control port, and
  against a mutant served with ``rover emulate --mutant`` (the suite must say which rule
  it broke, with the frames).

Every mutant is run in tests/bridge/test_mutants.py.
"""

from __future__ import annotations

import contextlib
import json
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from bridge.errors import ConformanceError
from bridge.tools.cli_conformance import main
from bridge.tools.conformance import RULES, RuleOutcome, exit_status, render_json, select_rules
from bridge.tools.conformance.suite import RuleResult
from emulator.can_frontend import CanFrontEnd
from emulator.control import ControlServer
from emulator.controller import ControllerConfig, ControllerModel
from emulator.engine import Emulator
from emulator.firmware import FirmwareController, sanitizer_env
from emulator.mutants import make_mutant
from emulator.serial_frontend import SerialFrontEnd
from emulator.twin import Twin
from firmware_proto.model.rover import RoverDescription
from tests.child import run_rover
from tests.firmware_proto.c_harness import compiler

from .lockstep_suite import make, run_lockstep

REPO = Path(__file__).resolve().parents[2]


FIRMWARES = [
    pytest.param("python", id="python"),
    pytest.param("c", id="c", marks=pytest.mark.firmware),
]


def _need_compiler(firmware: str) -> None:
    if firmware != "python" and compiler() is None:
        pytest.skip("gcc not found (set CC): the C firmware core cannot be built here")


@pytest.fixture(params=FIRMWARES)
def emulate_process(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[tuple[str, str]]:
    """``rover emulate --serial --control-port 0 --firmware F`` as its own process, in
    real time, for each firmware: ``(device link, control address)``."""
    with _emulate(tmp_path, request.param) as where:
        yield where


@contextlib.contextmanager
def _emulate(
    tmp_path: Path, firmware: str, env: dict[str, str] | None = None, *extra: str
) -> Iterator[tuple[str, str]]:
    _need_compiler(firmware)
    link = tmp_path / "rover-motor"
    with (tmp_path / "emulate.err").open("w") as err:
        cmd = [sys.executable, "-m", "firmware_proto.cli", "emulate", "--serial"]
        proc = subprocess.Popen(
            [
                *cmd,
                "--link",
                str(link),
                "--control-port",
                "0",
                "--seed",
                "3",
                "--firmware",
                firmware,
                *extra,
            ],
            stdout=subprocess.PIPE,
            stderr=err,
            text=True,
            env=env,
        )
    try:
        assert proc.stdout is not None
        device = proc.stdout.readline().split()
        control = proc.stdout.readline().split()
        assert device[0] == "DEVICE" and control[0] == "CONTROL", (device, control)
        yield str(link), control[1]
    finally:
        proc.terminate()
        try:
            proc.communicate(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.communicate(timeout=5)


def _outcomes(doc: dict[str, Any]) -> dict[str, str]:
    return {r["id"]: r["outcome"] for r in doc["rules"]}


# -- every rule, in lockstep -----------------------------------------------------------


@pytest.mark.parametrize("medium", ["serial", "can"])
@pytest.mark.parametrize("firmware", FIRMWARES)
def test_both_controllers_pass_every_rule_in_lockstep(firmware: str, medium: str) -> None:
    _need_compiler(firmware)
    run = run_lockstep(make(firmware), medium)
    outcomes = {r.rule.id: r.outcome for r in run.results}
    # seq-restart is of the serial frame counter: not run on CAN, never passed there.
    expected = {
        rule_id: RuleOutcome.NOT_RUN
        if medium == "can" and "serial" in rule.needs
        else RuleOutcome.PASS
        for rule_id, rule in RULES.items()
    }
    assert outcomes == expected, run.failed()
    # Every verdict carries the frames exchanged, both ways (the host's clock is virtual).
    for result in run.results:
        if result.outcome is RuleOutcome.PASS:
            assert {f.direction for f in result.frames} == {"H>C", "C>H"}, result.rule.id
            assert result.frames == tuple(sorted(result.frames, key=lambda f: f.t_s))
    rx = next(r for r in run.results if r.rule.id == "rx-errors")
    if medium == "serial":
        assert "wrong direction, short run: 5 counted" in rx.detail
    else:
        assert rx.detail == "unknown id, bad length: 2 counted"  # no CRC or direction


@pytest.mark.firmware
@pytest.mark.timeout(300)
def test_the_c_firmware_passes_every_rule_under_asan_and_ubsan(tmp_path: Path) -> None:
    """The sanitizer build of the core, in lockstep, in a process of its own with
    libasan preloaded: any memory error or undefined behaviour aborts it."""
    _need_compiler("c")
    cache = tmp_path / "cache"
    env = sanitizer_env()
    env["ROVER_FIRMWARE_CACHE"] = str(cache)
    env["PYTHONPATH"] = str(REPO)
    done = subprocess.run(
        [sys.executable, "-m", "tests.bridge.lockstep_suite", "--firmware", "c"],
        capture_output=True,
        text=True,
        timeout=300,
        env=env,
        cwd=REPO,
        check=False,
    )
    assert done.returncode == 0, done.stdout + done.stderr[-3000:]
    doc = json.loads(done.stdout)
    assert doc["outcomes"] == dict.fromkeys(RULES, "pass")
    assert doc["virtual_s"] > 20
    # It was the sanitizer build that ran (built into this test's own cache).
    assert [p.name.endswith("-san.so") for p in cache.iterdir()] == [True]
    assert "AddressSanitizer" not in done.stderr and "runtime error" not in done.stderr


# -- real time: a smoke run per medium and controller --------------------------------------

SMOKE = "handshake,samples-in-session,stop,rx-errors,watchdog,fault-persists,reboot"
"""Rules that together touch every part of the real-time path: the host's clock and
heartbeats, samples, motion and a stop, the medium's framing and errors, the control
port, a reboot (the pty adds seq-restart)."""


@pytest.mark.slow
def test_the_emulator_passes_the_smoke_rules_over_a_pty_in_real_time(
    emulate_process: tuple[str, str],
) -> None:
    device, control = emulate_process
    out = run_rover(
        "conformance", "--device", device, "--control", control, "--json",
        "--rule", SMOKE + ",seq-restart",
    )  # fmt: skip
    assert out.returncode == 0, out.stdout + out.stderr
    doc = json.loads(out.stdout)
    assert _outcomes(doc) == dict.fromkeys([*SMOKE.split(","), "seq-restart"], "pass")
    for rule in doc["rules"]:
        directions = {f["direction"] for f in rule["frames"]}
        assert directions == {"H>C", "C>H"}, rule["id"]
    rx = next(r for r in doc["rules"] if r["id"] == "rx-errors")
    assert "wrong direction, short run: 5 counted" in rx["detail"]


def test_without_a_control_port_those_rules_are_not_run_never_passed(
    emulate_process: tuple[str, str],
) -> None:
    device, _ = emulate_process
    out = run_rover(
        "conformance", "--device", device, "--rule", "handshake,reboot", "--rule", "stall"
    )
    assert out.returncode == 3, out.stdout + out.stderr
    rows = {line.split()[0]: line for line in out.stdout.splitlines()[3:6]}
    assert rows["handshake"].split()[1] == "PASS"
    for rule_id in ("reboot", "stall"):
        assert rows[rule_id].split()[1:3] == ["NOT", "RUN"], rows[rule_id]
        assert "needs the device's control port (--control HOST:PORT)" in rows[rule_id]
    assert "1 passed, 0 failed, 2 not run, of 3 rules" in out.stdout


# -- in process: a CAN bus, and a controller that breaks a rule ---------------------------


def _serve(model: ControllerModel, kind: str, channel: str) -> Emulator:
    if kind == "pty":
        return Emulator(model, SerialFrontEnd(seed=2))
    return Emulator(model, CanFrontEnd(interface="virtual", channel=channel, node=3, seed=2))


def _run(
    emu: Emulator, capsys: pytest.CaptureFixture[str], *args: str, control: bool = True
) -> tuple[int, str]:
    front = emu.frontend
    if isinstance(front, SerialFrontEnd):
        where = ["--device", front.device]
    else:
        assert isinstance(front, CanFrontEnd)
        where = ["--can", f"virtual:{front.channel}", "--node", str(front.node)]
    server = ControlServer(emu, 0).start() if control else None
    try:
        extra = ["--control", f"127.0.0.1:{server.port}"] if server else []
        status = main([*where, *extra, *args])
    finally:
        if server is not None:
            server.close()
    return status, capsys.readouterr().out


@pytest.mark.slow
@pytest.mark.parametrize("firmware", FIRMWARES)
def test_the_emulator_passes_the_smoke_rules_on_a_virtual_can_bus_in_real_time(
    firmware: str, rover: RoverDescription, can_channel: str, capsys: pytest.CaptureFixture[str]
) -> None:
    _need_compiler(firmware)
    cls = FirmwareController if firmware == "c" else ControllerModel
    model = cls(rover, Twin(rover), ControllerConfig(), seed=2)
    with _serve(model, "can", can_channel) as emu:
        status, out = _run(emu, capsys, "--json", "--rule", SMOKE)
    doc = json.loads(out)
    assert status == 0, [(r["id"], r["detail"]) for r in doc["rules"] if r["outcome"] != "pass"]
    assert _outcomes(doc) == dict.fromkeys(SMOKE.split(","), "pass")
    rx = next(r for r in doc["rules"] if r["id"] == "rx-errors")
    assert rx["detail"] == "unknown id, bad length: 2 counted"  # CAN: no CRC or direction


def test_a_broken_rule_fails_with_its_frames(
    rover: RoverDescription, capsys: pytest.CaptureFixture[str]
) -> None:
    """The mutant whose HEARTBEAT keeps the WATCHDOG bit until CLEAR_STOP (the condition
    and the latch mixed up, as the emulator did before protocol v2), in real time."""
    model = make_mutant("watchdog-bit-until-clear", rover, Twin(rover), ControllerConfig(), seed=2)
    with _serve(model, "pty", "") as emu:
        status, out = _run(emu, capsys, "--rule", "handshake,watchdog", control=False)
    assert status == 1, out
    lines = out.splitlines()
    assert lines[3].split()[:2] == ["handshake", "PASS"]
    assert lines[4].split()[:2] == ["watchdog", "FAIL"]
    assert "expected the latch held, the condition gone" in lines[4]
    # The failing rule's exchange follows the table: what was sent and what came back.
    tail = out[out.index("== watchdog (fail)") :]
    assert "C>H FAULT code=WATCHDOG active=1" in tail
    assert "H>C HOST_HEARTBEAT" in tail and "C>H FAULT code=WATCHDOG active=0" in tail
    assert "fault_bits=1" in tail


@pytest.mark.slow
def test_rover_emulate_serves_a_mutant_and_the_suite_names_its_rule(tmp_path: Path) -> None:
    """Issue #22's first miss, in real time: a controller that sends STOPPED the moment
    STOP arrives (0 mm, 0 ms, the wheels still turning)."""
    with _emulate(tmp_path, "python", None, "--mutant", "stopped-at-once") as (device, _):
        out = run_rover("conformance", "--device", device, "--rule", "stop,stopped-at-rest")
    assert out.returncode == 1, out.stdout + out.stderr
    rows = {line.split()[0]: line for line in out.stdout.splitlines()[3:5]}
    assert rows["stop"].split()[1] == "PASS"
    assert rows["stopped-at-rest"].split()[1] == "FAIL"
    assert "distance_mm=0 duration_ms=0: no time and no distance" in rows["stopped-at-rest"]
    err = (tmp_path / "emulate.err").read_text()
    assert "MUTANT stopped-at-once: breaks: The controller brakes" in err


def test_rover_emulate_refuses_an_unknown_mutant() -> None:
    out = run_rover("emulate", "--serial", "--mutant", "warp", "--duration", "1")
    assert out.returncode != 0
    assert "unknown mutant 'warp'; known: hello-delays-heartbeat" in out.stderr


# -- the pieces --------------------------------------------------------------------------


def test_rules_are_selected_by_id_and_unknown_ids_are_refused() -> None:
    assert [r.id for r in select_rules()] == list(RULES)
    assert [r.id for r in select_rules(["stop,handshake"])] == ["handshake", "stop"]
    with pytest.raises(ConformanceError, match="unknown rule warp; known: handshake"):
        select_rules(["warp"])
    assert main(["--list", "--rule", "warp"]) == 2


def test_list_names_every_rule_and_what_it_needs(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--list"]) == 0
    out = capsys.readouterr().out
    for rule in RULES.values():
        assert f"{rule.id}{f' [needs {rule.needs}]' if rule.needs else ''} ({rule.section})" in out


def test_every_rule_is_documented_in_protocol_md() -> None:
    text = (REPO / "docs" / "protocol.md").read_text(encoding="utf-8")
    section = text[text.index("## Conformance suite") :]
    for rule in RULES.values():
        assert f"| `{rule.id}` |" in section, rule.id
        assert f"## {rule.section}" in text, rule.section


def test_exit_status_is_zero_only_when_every_rule_passed() -> None:
    rule = RULES["handshake"]

    def result(outcome: RuleOutcome) -> RuleResult:
        return RuleResult(rule, outcome, "", (), 0, 0.0)

    assert exit_status([result(RuleOutcome.PASS)] * 2) == 0
    assert exit_status([result(RuleOutcome.PASS), result(RuleOutcome.NOT_RUN)]) == 3
    assert exit_status([result(RuleOutcome.NOT_RUN), result(RuleOutcome.FAIL)]) == 1
    doc = json.loads(render_json([result(RuleOutcome.NOT_RUN)], url="x"))
    assert (doc["passed"], doc["not_run"], doc["rules"][0]["outcome"]) == (0, 1, "not run")


@pytest.mark.parametrize(
    ("args", "complaint"),
    [
        ([], "give --device URL or --can IFACE:CH"),
        (["--device", "warp://x"], "unknown link scheme"),
        (["--device", "/nonexistent/rover-motor"], "cannot open /nonexistent/rover-motor"),
        (["--device", "loop://", "--control", "nowhere"], "control address must be HOST:PORT"),
    ],
)
def test_usage_and_unreachable_devices_exit_2(
    args: list[str], complaint: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(args) == 2
    assert complaint in capsys.readouterr().err


def test_a_node_out_of_range_is_a_usage_error_in_the_shared_words(
    capsys: pytest.CaptureFixture[str],
) -> None:
    with pytest.raises(SystemExit) as exited:
        main(["--can", "virtual:x", "--node", "16"])
    assert exited.value.code == 2
    assert "node must be an integer in 1..15, got '16'" in capsys.readouterr().err


def test_public_names_are_pinned() -> None:
    import bridge.tools.conformance

    assert bridge.tools.conformance.__all__ == [
        "RULES",
        "Context",
        "ControlClient",
        "FrameRecord",
        "Rule",
        "RuleOutcome",
        "RuleResult",
        "WireHost",
        "exit_status",
        "render_json",
        "render_list",
        "render_table",
        "run_suite",
        "select_rules",
    ]
