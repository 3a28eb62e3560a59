"""Parse the declarative protocol source (``protocol.toml``) into a small, checked model.

The model is what the code generators render (:mod:`firmware_proto.wire.codegen`); the
running codec never reads the TOML. The schema hash (:attr:`ProtocolSpec.schema_hash`) is
a CRC-16 over the canonical form of everything that decides the bytes on the wire or
their meaning, not over documentation; host and controller compare it at HELLO, so
mismatched definitions are refused instead of decoded as garbage.
"""

from __future__ import annotations

import binascii
import json
import keyword
import re
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from firmware_proto.errors import SpecError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

__all__ = [
    "DEFAULT_SPEC_PATH",
    "DIRECTIONS",
    "EnumSpec",
    "FieldSpec",
    "MessageSpec",
    "PriorityClass",
    "ProtocolSpec",
    "load_spec",
]

DEFAULT_SPEC_PATH = Path(__file__).resolve().parent / "protocol.toml"
DIRECTIONS = ("host_to_controller", "controller_to_host")
_TYPE_RE = re.compile(r"^([ui])([0-9]{1,2})$")
_NAME_RE = re.compile(r"^[a-z_][a-z0-9_]*$")
_UPPER_RE = re.compile(r"^[A-Z][A-Z0-9_]*$")


@dataclass(frozen=True)
class EnumSpec:
    """A named set of integer codes."""

    name: str
    doc: str
    values: tuple[tuple[str, int], ...]

    @property
    def span(self) -> tuple[int, int]:
        """Smallest and largest code."""
        codes = [v for _, v in self.values]
        return min(codes), max(codes)

    def name_of(self, value: int) -> str | None:
        """Member name for a code, or None."""
        for name, code in self.values:
            if code == value:
                return name
        return None


@dataclass(frozen=True)
class FieldSpec:
    """One bit-packed field of a payload."""

    name: str
    signed: bool
    bits: int
    start_bit: int
    min: int
    max: int
    limit: tuple[int, int] | None
    enum: str | None
    unit: str
    scale: float
    reserved: bool
    doc: str

    @property
    def type_name(self) -> str:
        """``uN`` or ``iN``."""
        return f"{'i' if self.signed else 'u'}{self.bits}"

    @property
    def type_min(self) -> int:
        """Smallest value the type holds."""
        return -(1 << (self.bits - 1)) if self.signed else 0

    @property
    def type_max(self) -> int:
        """Largest value the type holds."""
        return (1 << (self.bits - 1)) - 1 if self.signed else (1 << self.bits) - 1

    @property
    def checks_range(self) -> bool:
        """Whether the wire range is narrower than the type (decode must check it)."""
        return (self.min, self.max) != (self.type_min, self.type_max)


@dataclass(frozen=True)
class MessageSpec:
    """One message type."""

    name: str
    id: int
    direction: str
    priority: str
    rate: str
    doc: str
    fields: tuple[FieldSpec, ...]
    python_class: str = ""
    """The Python class name where the spec gives one (``class``): where the CamelCase name
    would clash with another class of ours (``POSE``: ``PoseMsg``, not the map's ``Pose``)."""

    @property
    def length(self) -> int:
        """Payload length in bytes."""
        bits = sum(f.bits for f in self.fields)
        return (bits + 7) // 8

    @property
    def class_name(self) -> str:
        """The Python class: the spec's ``class``, else CamelCase (``STOP_ACK`` -> ``StopAck``)."""
        return self.python_class or "".join(part.capitalize() for part in self.name.split("_"))

    @property
    def c_name(self) -> str:
        """snake_case name for C identifiers, e.g. ``stop_ack``."""
        return self.name.lower()

    @property
    def public_fields(self) -> tuple[FieldSpec, ...]:
        """Fields other than reserved padding."""
        return tuple(f for f in self.fields if not f.reserved)


@dataclass(frozen=True)
class PriorityClass:
    """A band of ids; lower ids win CAN arbitration."""

    name: str
    lo: int
    hi: int
    doc: str


@dataclass(frozen=True)
class ProtocolSpec:
    """The whole protocol, as parsed and checked."""

    protocol_version: int
    framing: dict[str, int | str]
    timing: dict[str, int]
    priorities: tuple[PriorityClass, ...]
    enums: tuple[EnumSpec, ...]
    messages: tuple[MessageSpec, ...]
    source_text: str

    def enum(self, name: str) -> EnumSpec:
        """The enum called ``name``."""
        for e in self.enums:
            if e.name == name:
                return e
        raise KeyError(name)

    def canonical(self) -> dict[str, Any]:
        """Everything that decides wire bytes and meaning, in a stable form."""
        return {
            "protocol_version": self.protocol_version,
            "framing": {k: self.framing[k] for k in sorted(self.framing)},
            "enums": {e.name: dict(sorted(e.values, key=lambda kv: kv[1])) for e in self.enums},
            "messages": [
                {
                    "id": m.id,
                    "name": m.name,
                    "direction": m.direction,
                    "fields": [
                        [f.name, f.type_name, f.min, f.max, list(f.limit or ()), f.enum, f.reserved]
                        for f in m.fields
                    ],
                }
                for m in sorted(self.messages, key=lambda m: m.id)
            ],
        }

    @property
    def schema_hash(self) -> int:
        """CRC-16/CCITT-FALSE of :meth:`canonical` as compact JSON."""
        blob = json.dumps(self.canonical(), sort_keys=True, separators=(",", ":")).encode()
        return binascii.crc_hqx(blob, 0xFFFF)


def _python_class(table: dict[str, Any], where: str) -> str:
    name = table.get("class", "")
    if not isinstance(name, str) or (name and not re.fullmatch(r"[A-Z][A-Za-z0-9]*", name)):
        raise SpecError(f"{where}: class must be a CamelCase Python name, got {name!r}")
    return name


def _need(table: dict[str, Any], key: str, kind: type | tuple[type, ...], where: str) -> Any:
    if key not in table:
        raise SpecError(f"{where}: missing '{key}'")
    value = table[key]
    if not isinstance(value, kind) or (isinstance(value, bool) and kind is not bool):
        raise SpecError(f"{where}: '{key}' has the wrong type ({type(value).__name__})")
    return value


def _parse_enums(doc: dict[str, Any]) -> tuple[EnumSpec, ...]:
    enums = []
    for name, table in doc.get("enum", {}).items():
        where = f"enum {name}"
        if not re.match(r"^[A-Z][A-Za-z0-9]*$", name):
            raise SpecError(f"{where}: enum names are CamelCase")
        values = _need(table, "values", dict, where)
        if not values:
            raise SpecError(f"{where}: no values")
        seen: dict[int, str] = {}
        for member, code in values.items():
            if not _UPPER_RE.match(member):
                raise SpecError(f"{where}: member {member!r} must be UPPER_CASE")
            if not isinstance(code, int) or isinstance(code, bool) or code < 0:
                raise SpecError(f"{where}: {member} must be a non-negative integer")
            if code in seen:
                raise SpecError(f"{where}: {member} and {seen[code]} share code {code}")
            seen[code] = member
        enums.append(EnumSpec(name, str(table.get("doc", "")), tuple(values.items())))
    return tuple(enums)


def _parse_field(
    raw: dict[str, Any], start_bit: int, enums: dict[str, EnumSpec], where: str
) -> FieldSpec:
    known = {"name", "type", "unit", "scale", "min", "max", "limit", "enum", "reserved", "doc"}
    unknown = sorted(set(raw) - known)
    if unknown:
        raise SpecError(f"{where}: unknown key(s) {unknown}")
    name = _need(raw, "name", str, where)
    reserved = bool(raw.get("reserved", False))
    if reserved != name.startswith("_"):
        raise SpecError(f"{where}: reserved fields, and only they, have names starting with '_'")
    if not _NAME_RE.match(name) or keyword.iskeyword(name):
        raise SpecError(f"{where}: field name {name!r} must be a lower_case identifier")
    match = _TYPE_RE.match(_need(raw, "type", str, where))
    if not match or not 1 <= int(match.group(2)) <= 32:
        raise SpecError(f"{where}: type must be uN or iN with 1 <= N <= 32")
    signed, bits = match.group(1) == "i", int(match.group(2))
    type_min = -(1 << (bits - 1)) if signed else 0
    type_max = (1 << (bits - 1)) - 1 if signed else (1 << bits) - 1
    enum_name = raw.get("enum")
    if enum_name is not None and enum_name not in enums:
        raise SpecError(f"{where}: unknown enum {enum_name!r}")
    default_min, default_max = enums[enum_name].span if enum_name else (type_min, type_max)
    lo = raw.get("min", default_min)
    hi = raw.get("max", default_max)
    if not (type_min <= lo <= hi <= type_max):
        raise SpecError(f"{where}: range [{lo}, {hi}] does not fit {match.group(0)}")
    limit = raw.get("limit")
    if limit is not None:
        if len(limit) != 2 or not (lo <= limit[0] <= limit[1] <= hi):
            raise SpecError(f"{where}: limit {limit} must lie inside [{lo}, {hi}]")
        limit = (int(limit[0]), int(limit[1]))
    scale = raw.get("scale", 1)
    if not isinstance(scale, (int, float)) or scale <= 0:
        raise SpecError(f"{where}: scale must be a positive number")
    return FieldSpec(
        name=name,
        signed=signed,
        bits=bits,
        start_bit=start_bit,
        min=int(lo),
        max=int(hi),
        limit=limit,
        enum=enum_name,
        unit=str(raw.get("unit", "")),
        scale=float(scale),
        reserved=reserved,
        doc=str(raw.get("doc", "")),
    )


def _parse_messages(
    doc: dict[str, Any],
    enums: dict[str, EnumSpec],
    priorities: dict[str, PriorityClass],
    max_payload: int,
) -> tuple[MessageSpec, ...]:
    messages: list[MessageSpec] = []
    names: set[str] = set()
    ids: set[int] = set()
    for index, table in enumerate(doc.get("message", [])):
        name = _need(table, "name", str, f"message #{index}")
        where = f"message {name}"
        if not _UPPER_RE.match(name) or name in names:
            raise SpecError(f"{where}: name must be UPPER_CASE and unique")
        names.add(name)
        msg_id = _need(table, "id", int, where)
        if not 0 <= msg_id <= 127 or msg_id in ids:
            raise SpecError(f"{where}: id {msg_id} must be unique and in 0..127")
        ids.add(msg_id)
        direction = _need(table, "direction", str, where)
        if direction not in DIRECTIONS:
            raise SpecError(f"{where}: direction must be one of {DIRECTIONS}")
        prio = priorities.get(_need(table, "priority", str, where))
        if prio is None:
            raise SpecError(f"{where}: unknown priority class {table['priority']!r}")
        if not prio.lo <= msg_id <= prio.hi:
            raise SpecError(
                f"{where}: id {msg_id} outside class {prio.name} [{prio.lo}, {prio.hi}]"
            )
        fields: list[FieldSpec] = []
        bit = 0
        for raw in _need(table, "fields", list, where):
            field = _parse_field(raw, bit, enums, f"{where}.{raw.get('name', '?')}")
            if any(f.name == field.name for f in fields):
                raise SpecError(f"{where}: duplicate field {field.name}")
            fields.append(field)
            bit += field.bits
        if bit > 8 * max_payload:
            raise SpecError(f"{where}: {bit} bits exceed the {max_payload}-byte payload")
        if bit % 8:
            raise SpecError(f"{where}: {bit} bits; pad with a reserved field to a whole byte")
        messages.append(
            MessageSpec(
                name=name,
                id=msg_id,
                direction=direction,
                priority=prio.name,
                rate=str(table.get("rate", "")),
                doc=str(table.get("doc", "")),
                fields=tuple(fields),
                python_class=_python_class(table, where),
            )
        )
    if not messages:
        raise SpecError("no messages defined")
    return tuple(sorted(messages, key=lambda m: m.id))


def load_spec(path: str | Path | None = None) -> ProtocolSpec:
    """Read and check the protocol source (``path``; ``None``: the packaged
    ``protocol.toml``). SpecError, naming the message and field, when it is unreadable or
    breaks a rule: duplicate names or ids, an id outside its priority class, a payload over
    8 bytes, a range the type cannot hold."""
    source = Path(path) if path is not None else DEFAULT_SPEC_PATH
    try:
        text = source.read_text(encoding="utf-8")
        doc = tomllib.loads(text)
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise SpecError(f"cannot read protocol spec {source}: {exc}") from exc
    version = _need(doc, "protocol_version", int, "spec")
    if not 0 < version < 256:
        raise SpecError("spec: protocol_version must be 1..255")
    framing = dict(_need(doc, "framing", dict, "spec"))
    timing = dict(_need(doc, "timing", dict, "spec"))
    for key, value in timing.items():
        if not isinstance(value, int) or value <= 0:
            raise SpecError(f"timing.{key} must be a positive integer")
    priorities: dict[str, PriorityClass] = {}
    for name, table in _need(doc, "priority", dict, "spec").items():
        lo, hi = _need(table, "ids", list, f"priority {name}")
        priorities[name] = PriorityClass(name, lo, hi, str(table.get("doc", "")))
    enums = _parse_enums(doc)
    max_payload = int(framing.get("max_payload_bytes", 8))
    messages = _parse_messages(doc, {e.name: e for e in enums}, priorities, max_payload)
    return ProtocolSpec(
        protocol_version=version,
        framing=framing,
        timing=timing,
        priorities=tuple(sorted(priorities.values(), key=lambda p: p.lo)),
        enums=enums,
        messages=messages,
        source_text=text,
    )
