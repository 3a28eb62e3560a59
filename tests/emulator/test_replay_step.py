"""The twin step ``rover replay`` plays a traffic log at: the one it was recorded at."""

from __future__ import annotations

import pytest

from emulator.cli_replay import LEGACY_EMULATE_DT_S, recorded_dt_s


@pytest.mark.parametrize(
    ("metadata", "dt_s"),
    [
        ({"role": "emulator", "speed_factor": "4.0", "dt_s": "0.004"}, 0.004),
        # An emulator's log from before the step was recorded: its step then, 1 ms.
        ({"role": "emulator", "seed": "5", "speed_factor": "4.0"}, LEGACY_EMULATE_DT_S),
        # A log that does not say (the bridge's; CAN logs have no header): the default.
        ({"role": "bridge"}, None),
        ({}, None),
    ],
)
def test_a_log_replays_at_the_step_it_was_recorded_at(
    metadata: dict[str, str], dt_s: float | None
) -> None:
    assert recorded_dt_s(metadata) == dt_s
