"""A ground of the emulator's own: files, settings, and what applying one changes."""

from __future__ import annotations

import argparse
import math
from dataclasses import replace
from pathlib import Path

import pytest

from emulator.cli_emulate import ground_of
from emulator.errors import GroundError
from emulator.ground import (
    GROUND_PARAMETERS,
    Ground,
    list_grounds,
    load_ground,
    parse_ground_setting,
    solve_mu_lateral,
)
from emulator.playback import measure_turn_efficiency, play
from emulator.twin import Twin
from firmware_proto.model.rover import RoverDescription
from firmware_proto.model.worldmap import WorldMap


def test_the_shipped_grounds_differ_from_the_description(rover: RoverDescription) -> None:
    assert list_grounds() == ("compacted", "dusty", "loose")
    nominal = Ground.of_rover(rover).values()
    for name in list_grounds():
        ground = load_ground(name, rover)
        assert ground.name == name
        assert ground.values() != nominal
        # What the file leaves out comes from the description.
        assert ground.slip_saturation_mps == rover.traction.slip_saturation_mps


def test_no_ground_leaves_the_twin_exactly_as_it_was(
    rover: RoverDescription, lab: WorldMap
) -> None:
    args = argparse.Namespace(ground=None, ground_set=[])
    assert ground_of(args, rover) is None
    same = Ground.of_rover(rover, lab)
    assert same.rover(rover) == rover
    world = same.world(lab)
    assert world is not None and world.digest() == lab.digest()


def test_a_ground_replaces_the_traction_and_the_region_scales(
    rover: RoverDescription, lab: WorldMap
) -> None:
    ground = load_ground("loose", rover).with_values(**{"region.sandbox": 0.3})
    moved = ground.rover(rover)
    assert moved.geometry == rover.geometry and moved.drive == rover.drive
    assert moved.traction.mu_longitudinal == 0.45
    assert moved.traction.turn_efficiency == rover.traction.turn_efficiency
    world = ground.world(lab)
    assert world is not None
    assert [r.mu_scale for r in world.traction_regions] == [0.3]
    # And the twin drives differently on it: the same turn falls short.
    turn = [(3, 30, rover.turn_units_for_yaw(math.pi / 2))]
    nominal = play(Twin(rover, dt_s=0.01), turn).final_pose.yaw_rad
    loose = play(Twin(moved, dt_s=0.01), turn).final_pose.yaw_rad
    assert loose < nominal - math.radians(10)


def test_a_region_the_map_lacks_is_an_error_unless_lenient(
    rover: RoverDescription, lab: WorldMap
) -> None:
    ground = Ground.of_rover(rover).with_values(**{"region.swamp": 0.5})
    with pytest.raises(GroundError, match=r"region\(s\) swamp that map 'lab' lacks"):
        ground.world(lab)
    assert ground.world(lab, strict=False) == lab
    with pytest.raises(GroundError, match="open plane"):
        ground.world(None)


def test_the_file_round_trips(rover: RoverDescription, tmp_path: Path) -> None:
    ground = load_ground("dusty", rover).with_values(**{"region.sandbox": 0.25})
    path = tmp_path / "g.toml"
    path.write_text(ground.to_toml())
    assert load_ground(path, rover) == ground


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("schema_version = 2\nname = 'x'\n", "schema_version must be 1"),
        ("schema_version = 1\nname = 'x'\n[traction]\nmu = 0.5\n", "unknown key.*mu"),
        ("schema_version = 1\nname = 'x'\nextra = 1\n", "unknown key.*extra"),
        ("schema_version = 1\nname = 'x'\n[traction]\nmu_lateral = 'a'\n", "must be a number"),
        ("schema_version = 1\nname = 'x'\n[traction]\nrolling_resistance = -1\n", "> 0"),
        ("schema_version = 1\nname = 'x'\n[regions]\nsandbox = 3\n", r"\(0, 2\]"),
        (
            "schema_version = 1\nname = 'x'\n[traction]\nmu_lateral = 0.5\nturn_efficiency = 0.4\n",
            "mu_lateral 0.5 and turn_efficiency 0.4 disagree: with that mu_lateral this "
            "ground turns at 0.5",
        ),
        (
            "schema_version = 1\nname = 'x'\n[traction]\nmu_lateral = 0.5\nturn_efficiency = 1\n",
            r"turn_efficiency must be in \(0, 1\)",
        ),
        ("schema_version = 1\nname = 'x'\n[traction\n", "not valid TOML"),
    ],
)
def test_a_bad_file_is_refused_naming_the_key(
    rover: RoverDescription, tmp_path: Path, text: str, message: str
) -> None:
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(GroundError, match=message):
        load_ground(path, rover)


def test_a_measured_turn_efficiency_may_stand_beside_the_friction_it_agrees_with(
    rover: RoverDescription, tmp_path: Path
) -> None:
    loose = load_ground("loose", rover)
    efficiency = measure_turn_efficiency(
        loose.rover(rover), distance=rover.turn_units_for_yaw(math.pi / 2)
    )
    path = tmp_path / "measured.toml"
    text = loose.to_toml().replace(
        "[traction]\n", f"[traction]\nturn_efficiency = {efficiency + 0.004:.4f}\n"
    )
    path.write_text(text)
    both = load_ground(path, rover)
    assert both.mu_lateral == loose.mu_lateral  # the friction stays; the efficiency checks it


def test_an_unknown_name_lists_the_shipped_grounds(rover: RoverDescription) -> None:
    with pytest.raises(GroundError, match="known: compacted, dusty, loose"):
        load_ground("moon", rover)


# Seconds of CPU (a root search over twin playbacks): out of the fast lane, in the test
# command's background part.
@pytest.mark.slow
@pytest.mark.virtual
def test_turn_efficiency_solves_the_lateral_friction(rover: RoverDescription) -> None:
    base = load_ground("loose", rover)
    mu = solve_mu_lateral(rover, base, 0.45)
    trial = replace(base, mu_lateral=mu).rover(rover)
    measured = measure_turn_efficiency(trial, distance=rover.turn_units_for_yaw(math.pi / 2))
    assert measured == pytest.approx(0.45, abs=2e-4)
    with pytest.raises(GroundError, match="outside what this ground reaches"):
        solve_mu_lateral(rover, base, 0.99)


def test_settings_on_the_command_line(rover: RoverDescription) -> None:
    args = argparse.Namespace(
        ground="compacted", ground_set=["rolling_resistance=0.07", "region.sandbox=0.4"]
    )
    ground = ground_of(args, rover)
    assert ground is not None
    assert ground.rolling_resistance == 0.07 and ground.mu_longitudinal == 0.7
    assert ground.regions == (("sandbox", 0.4),)
    for bad in ("mu_lateral", "mu_lateral=x", "=3"):
        with pytest.raises(GroundError, match="KEY=NUMBER"):
            parse_ground_setting(bad)
    with pytest.raises(GroundError, match="unknown ground parameter 'mu'"):
        ground_of(argparse.Namespace(ground=None, ground_set=["mu=0.3"]), rover)


def test_values_out_of_range_are_refused() -> None:
    values = dict.fromkeys(GROUND_PARAMETERS, 0.5)
    with pytest.raises(GroundError, match="mu_lateral must be a finite float > 0"):
        Ground("x", **{**values, "mu_lateral": math.nan})  # type: ignore[arg-type]
