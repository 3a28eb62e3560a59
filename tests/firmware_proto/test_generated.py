"""Generated files match the declarative source; the spec checker refuses bad specs."""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path
from typing import Any

import pytest

from firmware_proto.errors import SpecError
from firmware_proto.wire import codegen, messages
from firmware_proto.wire.spec import DEFAULT_SPEC_PATH, load_spec

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib


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


def _crc16_ccitt_false(data: bytes) -> int:
    """CRC-16/CCITT-FALSE bit by bit, as docs/protocol.md states it (not the codec's)."""
    crc = 0xFFFF
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else crc << 1
            crc &= 0xFFFF
    return crc


def _field_from_recipe(raw: dict[str, Any], enums: dict[str, dict[str, int]]) -> list[Any]:
    match = re.fullmatch(r"([ui])(\d+)", raw["type"])
    assert match is not None
    bits = int(match.group(2))
    signed = match.group(1) == "i"
    enum = raw.get("enum")
    if enum is not None:
        lo, hi = min(enums[enum].values()), max(enums[enum].values())
    elif signed:
        lo, hi = -(1 << (bits - 1)), (1 << (bits - 1)) - 1
    else:
        lo, hi = 0, (1 << bits) - 1
    return [
        raw["name"],
        raw["type"],
        raw.get("min", lo),
        raw.get("max", hi),
        list(raw.get("limit", [])),
        enum,
        raw.get("reserved", False),
    ]


def test_schema_hash_is_reproducible_from_the_documented_recipe() -> None:
    """docs/protocol.md ("Definitions and edge cases", the schema hash) is enough to
    compute the hash from protocol.toml: rebuilt here from the TOML alone, without
    firmware_proto's spec model or its CRC."""
    assert _crc16_ccitt_false(b"123456789") == 0x29B1  # the documented check value
    doc = tomllib.loads(DEFAULT_SPEC_PATH.read_text())
    enums = {name: dict(table["values"]) for name, table in doc["enum"].items()}
    obj = {
        "protocol_version": doc["protocol_version"],
        "framing": doc["framing"],
        "enums": enums,
        "messages": [
            {
                "id": m["id"],
                "name": m["name"],
                "direction": m["direction"],
                "fields": [_field_from_recipe(f, enums) for f in m["fields"]],
            }
            for m in sorted(doc["message"], key=lambda m: m["id"])
        ],
    }
    blob = json.dumps(obj, sort_keys=True, separators=(",", ":")).encode()
    assert _crc16_ccitt_false(blob) == messages.SCHEMA_HASH
    protocol_md = (codegen.REPO_ROOT / "docs/protocol.md").read_text()
    assert f"Schema hash **0x{messages.SCHEMA_HASH:04X}**" in protocol_md


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
