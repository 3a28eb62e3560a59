"""``rover pil``: the firmware image in emulated silicon, over a pty, in real time
(docs/firmware.md, "Processor in the loop"). Each test skips, naming the packages, where
the target's tools are missing (fails under ``ROVER_REQUIRE_CROSS=1``)."""

from __future__ import annotations

import json
import socket
import time
from pathlib import Path
from typing import Any

import pytest

from .pil_helpers import pil_process, rover

TARGETS = ["microbit", "atmega2560"]


def _control(address: str, *commands: str) -> list[dict[str, Any]]:
    host, port = address.rsplit(":", 1)
    with socket.create_connection((host, int(port)), timeout=10) as sock:
        stream = sock.makefile("rw", encoding="utf-8")
        answers = []
        for command in commands:
            stream.write(command + "\n")
            stream.flush()
            answers.append(json.loads(stream.readline()))
    return answers


@pytest.mark.parametrize("target", TARGETS)
def test_the_image_passes_every_conformance_rule_over_its_uart(target: str, tmp_path: Path) -> None:
    """Every rule, the control port's included (reboot as a real reset of the MCU; stall
    and encoder dropout through the plant or the image's hooks)."""
    with pil_process(tmp_path, target) as (device, control):
        out = rover("conformance", "--device", device, "--control", control, "--json")
    assert out.returncode == 0, out.stdout + out.stderr
    doc = json.loads(out.stdout)
    outcomes = {r["id"]: r["outcome"] for r in doc["rules"]}
    assert set(outcomes.values()) == {"pass"}, outcomes
    assert len(outcomes) >= 37


@pytest.mark.parametrize("target", TARGETS)
def test_the_stop_bench_loses_no_trial(target: str, tmp_path: Path) -> None:
    with pil_process(tmp_path, target) as (device, _control_address):
        out = rover(
            "bench", "stop", "--serial", device, "--trials", "10", "--seed", "7",
            "--out", str(tmp_path / "bench"),
        )  # fmt: skip
    assert out.returncode == 0, out.stdout + out.stderr
    doc = json.loads((tmp_path / "bench" / "stop_trials.json").read_text())
    trials = doc["trials"]
    assert len(trials) == 10 and all(t["ok"] for t in trials), trials
    assert "trials passed: 10/10" in out.stdout


@pytest.mark.parametrize("target", TARGETS)
def test_the_control_port_applies_what_the_image_can_and_refuses_the_rest(
    target: str, tmp_path: Path
) -> None:
    with pil_process(tmp_path, target) as (_device, control):
        status, stall, bias, region, later, clear, after, boom = _control(
            control,
            "status",
            "inject stall:right",
            "inject imu-bias=0.1",
            "inject slip:left=0.5@region=sand",
            "inject slip:left=0.5@t=0.3",
            "inject clear:stall",
            "status",
            "inject nonsense",
        )
        fired = _wait_for_schedule(control)
    assert status["ok"] and status["status"]["state"] == "BOOT"
    assert stall["ok"] and stall["fault"] == "stall:right"
    assert not bias["ok"] and "cannot apply on the" in bias["error"]
    assert not region["ok"] and "no map regions" in region["error"]
    assert later["ok"] and "scheduled_s" in later and "t=0.3" in later["fires"]
    assert clear["ok"]
    assert "stall:right" not in after["status"]["injected"]
    assert not boom["ok"] and "unknown fault" in boom["error"]
    assert fired["fault"] == "slip:left=0.5@t=0.3" and fired["time_s"] >= 0.3


def _wait_for_schedule(control: str) -> dict[str, Any]:
    """The injection the schedule applied (polled: the trigger is on the target's clock)."""
    for _ in range(200):
        (answer,) = _control(control, "injections")
        done = [r for r in answer["injections"] if r["source"] == "schedule"]
        if done:
            return dict(done[0])
        time.sleep(0.05)
    raise AssertionError("the scheduled fault never fired")


def test_an_unknown_target_is_refused_with_the_known_ones() -> None:
    out = rover("pil", "--target", "pdp11")
    assert out.returncode == 2 and "invalid choice" in out.stderr and "microbit" in out.stderr
