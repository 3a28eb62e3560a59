"""What ``rover bridge`` says about a link that keeps failing (``bridge/link/linklines.py``),
fed the bridge's ``/diagnostics`` every 0.5 s of virtual time while the wire simulator
plays the failures: "wrong baud suspected" only when bytes that do not frame come with
the losses (issue #40, 9b: it was said in every run with cuts or freezes, also when the
bridge itself was frozen)."""

from __future__ import annotations

from bridge.link.linklines import LinkNarrator
from sim.rig import Rig
from sim.scenario import DEFAULT_TICK_S, Scenario, ScenarioFault

POLL_S = 0.5
"""How often ``rover bridge`` asks its narrator (cli_bridge's poll)."""


def _narrate(*faults: ScenarioFault) -> tuple[list[str], Rig]:
    scenario = Scenario(
        seed=0,
        controller="python",
        medium="serial",
        mutants=(),
        leak_samples=False,
        zero_steps=False,
        tick_s=DEFAULT_TICK_S,
        queue_depth=8,
        faults=faults,
        actions=(),
        quiet_s=max(f.end_s for f in faults),
    )
    rig = Rig(scenario)
    narrator = LinkNarrator("/dev/ttyUSB0", 115200)
    lines: list[str] = []
    rig.every(POLL_S, lambda: lines.extend(narrator.update(rig.diagnostics(), rig.now)))
    outcome = rig.run()
    assert outcome.ok, outcome.violations
    return lines, rig


def _every(kind: str, direction: str = "both", level: float = 1.0) -> list[ScenarioFault]:
    """Six faults of 0.5 s, one every 1.3 s: six link losses in 8 s."""
    return [ScenarioFault(kind, 0.5 + 1.3 * i, 0.5, direction, level) for i in range(6)]


def test_cuts_are_losses_of_a_link_whose_bytes_frame_not_a_wrong_baud() -> None:
    lines, rig = _narrate(*_every("cut", "to_host"))
    assert rig.diagnostics().heartbeat_losses >= 6
    assert not [x for x in lines if "wrong baud" in x], lines
    [flap] = [x for x in lines if "heartbeats come late again and again" in x]
    assert "its bytes frame (the baud is right): the link drops out" in flap


def test_a_frozen_bridge_says_nothing_about_its_link() -> None:
    """The bridge process held 0.5 s six times: every loss is its own stall."""
    lines, rig = _narrate(*_every("host-freeze"))
    diag = rig.diagnostics()
    assert diag.heartbeat_losses >= 6 and diag.stalls == 6
    assert not [x for x in lines if "wrong baud" in x or "again and again" in x], lines


def test_losses_among_bytes_that_do_not_frame_suspect_the_baud() -> None:
    """Nine frames in ten arrive damaged (CRC errors), as at a wrong baud."""
    lines, rig = _narrate(ScenarioFault("corrupt", 0.3, 8.0, "to_host", 0.9))
    diag = rig.diagnostics()
    assert diag.heartbeat_losses >= 3 and diag.crc_errors > diag.rx_frames
    [flap] = [x for x in lines if "again and again" in x]
    assert "with bytes that do not frame" in flap
    assert flap.endswith("wrong baud suspected (the bridge is at 115200 baud: --baud)")


def test_a_link_that_answered_is_not_said_to_be_silent_at_a_later_handshake() -> None:
    """After the handshake, a handshake again (a reboot, a loss) is no controller that
    does not answer: that line is for an open device nobody answers."""
    lines, _ = _narrate(*_every("host-freeze"))
    assert not [x for x in lines if "does not answer" in x or "no controller answers" in x]
    held = [x for x in lines if x.startswith("link lost and back")]
    assert held and all("(this process was held up)" in x for x in held), lines
