"""Generated files match the declarative source; the spec checker refuses bad specs."""

from __future__ import annotations

from pathlib import Path

import pytest

from firmware_proto.errors import SpecError
from firmware_proto.wire import codegen, messages
from firmware_proto.wire.spec import DEFAULT_SPEC_PATH, load_spec


def test_no_generated_file_is_stale() -> None:
    stale = [str(p.relative_to(codegen.REPO_ROOT)) for p in codegen.stale()]
    assert stale == [], f"run 'rover frame generate': stale {stale}"


def test_stale_check_notices_an_edit(tmp_path: Path) -> None:
    text = DEFAULT_SPEC_PATH.read_text().replace("max = 1800", "max = 1799")
    spec_file = tmp_path / "protocol.toml"
    spec_file.write_text(text)
    edited = load_spec(spec_file)
    assert edited.schema_hash != messages.SCHEMA_HASH
    assert codegen.REPO_ROOT / "firmware_proto/wire/messages.py" in codegen.stale(edited)


def test_schema_hash_ignores_documentation(tmp_path: Path) -> None:
    text = DEFAULT_SPEC_PATH.read_text().replace('doc = "who asked"', 'doc = "who wanted it"')
    spec_file = tmp_path / "protocol.toml"
    spec_file.write_text(text)
    assert load_spec(spec_file).schema_hash == messages.SCHEMA_HASH


@pytest.mark.parametrize(
    ("old", "new", "complaint"),
    [
        ('name = "STOP_ACK"\nid = 1', 'name = "STOP_ACK"\nid = 0', "must be unique"),
        ('name = "MOTION"\nid = 8', 'name = "MOTION"\nid = 40', "outside class motion"),
        ('{ name = "left", type = "i24"', '{ name = "left", type = "i40"', "uN or iN"),
        (
            '{ name = "speed", type = "u8", limit = [0, 60]',
            '{ name = "speed", type = "u8", limit = [0, 300]',
            "limit",
        ),
        (
            '{ name = "t_ms", type = "u16", unit = "ms", doc = "controller clock',
            '{ name = "t_ms", type = "u32", unit = "ms", doc = "controller clock',
            "exceed",
        ),
        ('enum = "StopSource"', 'enum = "Nope"', "unknown enum"),
    ],
)
def test_spec_checker_refuses(tmp_path: Path, old: str, new: str, complaint: str) -> None:
    text = DEFAULT_SPEC_PATH.read_text()
    assert old in text
    spec_file = tmp_path / "protocol.toml"
    spec_file.write_text(text.replace(old, new, 1))
    with pytest.raises(SpecError, match=complaint):
        load_spec(spec_file)


def test_every_payload_fits_one_classic_can_frame() -> None:
    for cls in messages.MESSAGE_TYPES.values():
        assert 0 <= cls.LENGTH <= 8, cls.NAME
