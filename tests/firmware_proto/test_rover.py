"""Rover description: the default loads; bad files are refused with the key named."""

from __future__ import annotations

from pathlib import Path

import pytest

from firmware_proto.errors import DescriptionError
from firmware_proto.model.rover import DEFAULT_ROVER_PATH, load_rover


def test_default_description_loads_with_the_contract_values() -> None:
    rover = load_rover()
    assert rover.drive.distance_units_per_m == 23000
    assert (rover.drive.left_wheel_sign, rover.drive.right_wheel_sign) == (-1, 1)
    assert rover.safety.drift_linear_m == 0.25
    assert rover.safety.drift_angular_deg == 12.0
    assert rover.safety.max_repair_attempts == 4
    assert rover.m_to_units(1.0) == 23000
    assert rover.units_to_m(23000) == 1.0
    assert rover.speed_to_mps(60) == pytest.approx(rover.max_speed_mps)
    assert len(rover.digest()) == 64


@pytest.mark.parametrize(
    ("old", "new", "complaint"),
    [
        ("mass_kg = 25.0", "mass_kg = -1.0", "mass.mass_kg must be > 0"),
        ("left_wheel_sign = -1", "left_wheel_sign = 2", "left_wheel_sign"),
        ("mass_kg = 25.0", "mass_kg = 25.0\nmass_g = 1", "unknown key"),
        ("wheelbase_m = 0.40\n", "", "missing key"),
        ("max_speed = 60", 'max_speed = "60"', "max_speed"),
        ("max_speed = 60", "max_speed = 60.5", "max_speed"),
        ("schema_version = 1", "schema_version = 2", "schema_version"),
        ("[safety]", "[safety]\n[extra]", "unknown table"),
        ('name = "rassor-lab"', "name = [", "not valid TOML"),
    ],
)
def test_bad_descriptions_are_refused(tmp_path: Path, old: str, new: str, complaint: str) -> None:
    text = DEFAULT_ROVER_PATH.read_text()
    assert old in text
    path = tmp_path / "rover.toml"
    path.write_text(text.replace(old, new, 1))
    with pytest.raises(DescriptionError, match=complaint):
        load_rover(path)


def test_missing_file_is_a_description_error(tmp_path: Path) -> None:
    with pytest.raises(DescriptionError, match="cannot read"):
        load_rover(tmp_path / "nope.toml")
