"""The runner's reading of the port's RAM (``emulator.pil.view``) and the package's names."""

from __future__ import annotations

import pytest

import emulator.pil
from emulator.pil.errors import PilError
from emulator.pil.registry import target_class
from emulator.pil.view import HOOKS, STATS, VIEW, PilStats, PortView, hooks_bytes


def test_public_names_are_pinned() -> None:
    assert emulator.pil.__all__ == [
        "IMAGES",
        "TARGETS",
        "Image",
        "PilError",
        "PilToolMissingError",
        "build_image",
        "target_class",
    ]


def test_the_layouts_are_those_of_pil_port_h() -> None:
    assert (STATS.size, VIEW.size, HOOKS.size) == (40, 40, 8)


def test_a_view_decodes_state_latch_and_faults() -> None:
    raw = VIEW.pack(
        -150000, 150000, 150000, 150000, 1234, -56, -900, 0xBEEF, 7, 3, 5, 0b1100, 2, 4321
    )
    view = PortView.decode(raw)
    assert view.commanded_um_s == (-150000, 150000)
    assert (view.x_mm, view.y_mm, view.yaw_ddeg) == (1234, -56, -900)
    assert view.state_name == "STOP_LATCHED"
    assert view.latch_names == ("fault", "stop")
    assert view.fault_names == ("STALL_RIGHT", "ENCODER")
    assert (view.boot_nonce, view.rx_errors, view.queue_depth) == (0xBEEF, 7, 2)
    assert view.travel_mm == 4321
    assert PortView.decode(VIEW.pack(*([0] * 9), 99, 0, 0, 0, 0)).state_name == "STATE_99"


def test_stats_decode_in_order() -> None:
    stats = PilStats.decode(STATS.pack(1, 2, 3, 4, 5, 6, 16_000_000, 7, 8, 9))
    assert (stats.ticks, stats.tick_max, stats.tx_drops, stats.tick_unit_hz) == (
        1,
        3,
        6,
        16_000_000,
    )
    assert (stats.stop_ack_last, stats.stop_ack_max, stats.ident_last) == (7, 8, 9)


def test_hooks_carry_stall_dropout_and_slip_per_mille() -> None:
    raw = hooks_bytes((False, True), (True, False), (0.3, 1.0))
    assert HOOKS.unpack(raw) == (0, 1, 1, 0, 300, 1000)
    assert HOOKS.unpack(hooks_bytes((False, False), (False, False), (0.0001, 2.0)))[4:] == (1, 1000)


def test_an_unknown_target_names_the_known_ones() -> None:
    with pytest.raises(PilError, match="known: microbit, atmega2560"):
        target_class("pdp11")
