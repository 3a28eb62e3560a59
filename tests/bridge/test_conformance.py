"""``rover conformance`` against the emulator: as a real subprocess on a pty, on
python-can's ``virtual`` bus, without a control port, and against a controller that
breaks a rule (the suite must say which, with the frames).

One suite, two implementations: every run is made against the Python controller model
and against the C firmware core (``--firmware c``, emulator/firmware.py), and once more
against the C core built with ASan and UBSan. The other cases select a few rules.
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

from bridge.cli_conformance import main
from bridge.conformance import RULES, Outcome, exit_status, render_json, select_rules
from bridge.conformance.suite import RuleResult
from bridge.errors import ConformanceError
from emulator.can_frontend import CanFrontEnd
from emulator.control import ControlServer
from emulator.controller import ControllerConfig, ControllerModel
from emulator.engine import Emulator
from emulator.firmware import FirmwareController, sanitizer_env
from emulator.serial_frontend import SerialFrontEnd
from emulator.twin import Twin
from firmware_proto.messages import FaultCode, Heartbeat
from firmware_proto.rover import RoverDescription
from tests.firmware_proto.c_harness import compiler

REPO = Path(__file__).resolve().parents[2]


def _rover(*args: str, timeout: float = 120.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "firmware_proto.cli", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        check=False,
    )


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
    tmp_path: Path, firmware: str, env: dict[str, str] | None = None
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


@pytest.mark.slow
def test_the_emulator_passes_every_rule_over_a_pty(emulate_process: tuple[str, str]) -> None:
    _passes_every_rule(*emulate_process)


@pytest.mark.slow
@pytest.mark.firmware
@pytest.mark.timeout(300)
def test_the_c_firmware_passes_every_rule_under_asan_and_ubsan(tmp_path: Path) -> None:
    """The sanitizer build of the core, loaded by the emulator with libasan preloaded:
    any memory error or undefined behaviour aborts it, and the suite then fails."""
    _need_compiler("c")
    cache = tmp_path / "cache"
    env = sanitizer_env()
    env["ROVER_FIRMWARE_CACHE"] = str(cache)
    with _emulate(tmp_path, "c", env) as (device, control):
        # A sanitizer build is a slow controller: the suite's waits get the margin its
        # --timeout-scale is for (order and content are checked as always).
        _passes_every_rule(device, control, "--timeout-scale", "3")
    # It was the sanitizer build that ran (built into this test's own cache).
    assert [p.name.endswith("-san.so") for p in cache.iterdir()] == [True]
    err = (tmp_path / "emulate.err").read_text()
    assert "AddressSanitizer" not in err and "runtime error" not in err, err


def _passes_every_rule(device: str, control: str, *extra: str) -> None:
    out = _rover("conformance", "--device", device, "--control", control, "--json", *extra)
    assert out.returncode == 0, out.stdout + out.stderr
    doc = json.loads(out.stdout)
    assert _outcomes(doc) == dict.fromkeys(RULES, "pass")
    assert (doc["passed"], doc["failed"], doc["not_run"]) == (len(RULES), 0, 0)
    # Every verdict carries the frames exchanged, both ways.
    for rule in doc["rules"]:
        directions = {f["direction"] for f in rule["frames"]}
        assert directions == {"H>C", "C>H"}, rule["id"]
    rx = next(r for r in doc["rules"] if r["id"] == "rx-errors")
    assert "bad CRC, wrong direction: 4 counted" in rx["detail"]


def test_without_a_control_port_those_rules_are_not_run_never_passed(
    emulate_process: tuple[str, str],
) -> None:
    device, _ = emulate_process
    out = _rover("conformance", "--device", device, "--rule", "handshake,reboot", "--rule", "stall")
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
def test_the_emulator_passes_every_rule_on_a_virtual_can_bus(
    firmware: str, rover: RoverDescription, can_channel: str, capsys: pytest.CaptureFixture[str]
) -> None:
    _need_compiler(firmware)
    cls = FirmwareController if firmware == "c" else ControllerModel
    model = cls(rover, Twin(rover), ControllerConfig(), seed=2)
    with _serve(model, "can", can_channel) as emu:
        status, out = _run(emu, capsys, "--json")
    doc = json.loads(out)
    assert status == 0, [(r["id"], r["detail"]) for r in doc["rules"] if r["outcome"] != "pass"]
    assert _outcomes(doc) == dict.fromkeys(RULES, "pass")
    rx = next(r for r in doc["rules"] if r["id"] == "rx-errors")
    assert rx["detail"] == "unknown id, bad length: 2 counted"  # CAN: no CRC or direction


class _WatchdogBitUntilClear(ControllerModel):
    """A controller that breaks 'Latch and faults': its HEARTBEAT keeps the WATCHDOG
    bit until CLEAR_STOP, as the emulator did before protocol v2, although it sent
    FAULT active 0 (the condition and the latch mixed up)."""

    def heartbeat(self) -> Heartbeat:
        hb = super().heartbeat()
        if self.latch_causes and any(c.value == "watchdog" for c in self.latch_causes):
            return hb._replace(fault_bits=hb.fault_bits | 1 << (FaultCode.WATCHDOG - 1))
        return hb


def test_a_broken_rule_fails_with_its_frames(
    rover: RoverDescription, capsys: pytest.CaptureFixture[str]
) -> None:
    model = _WatchdogBitUntilClear(rover, Twin(rover), ControllerConfig(), seed=2)
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
        assert f"{rule.id}{' [needs control]' if rule.needs else ''} ({rule.section})" in out


def test_every_rule_is_documented_in_protocol_md() -> None:
    text = (REPO / "docs" / "protocol.md").read_text(encoding="utf-8")
    section = text[text.index("## Conformance suite") :]
    for rule in RULES.values():
        assert f"| `{rule.id}` |" in section, rule.id
        assert f"## {rule.section}" in text, rule.section


def test_exit_status_is_zero_only_when_every_rule_passed() -> None:
    rule = RULES["handshake"]

    def result(outcome: Outcome) -> RuleResult:
        return RuleResult(rule, outcome, "", (), 0, 0.0)

    assert exit_status([result(Outcome.PASS)] * 2) == 0
    assert exit_status([result(Outcome.PASS), result(Outcome.NOT_RUN)]) == 3
    assert exit_status([result(Outcome.NOT_RUN), result(Outcome.FAIL)]) == 1
    doc = json.loads(render_json([result(Outcome.NOT_RUN)], url="x"))
    assert (doc["passed"], doc["not_run"], doc["rules"][0]["outcome"]) == (0, 1, "not run")


@pytest.mark.parametrize(
    ("args", "complaint"),
    [
        ([], "give --device URL or --can IFACE:CH"),
        (["--device", "warp://x"], "unknown transport scheme"),
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
    import bridge.conformance

    assert bridge.conformance.__all__ == [
        "RULES",
        "Context",
        "ControlClient",
        "FrameRecord",
        "Outcome",
        "Rule",
        "RuleResult",
        "WireHost",
        "exit_status",
        "render_json",
        "render_list",
        "render_table",
        "run_suite",
        "select_rules",
    ]
