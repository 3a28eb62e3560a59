"""Render the Python codec (``firmware_proto/wire/messages.py``) from the spec model.

Each message becomes a frozen, slotted dataclass with a ``pack()`` that checks every
field inline, and a module-level decode function that returns ``None`` for a payload
whose values fall outside the wire range (the stream decoders count those). Byte-aligned
layouts use a precompiled ``struct.Struct``; bit-packed ones one integer and shifts.
"""

from __future__ import annotations

import textwrap

from firmware_proto.wire.spec import EnumSpec, FieldSpec, MessageSpec, ProtocolSpec

__all__ = ["render_python"]

_STRUCT_CODES = {
    (False, 8): "B",
    (True, 8): "b",
    (False, 16): "H",
    (True, 16): "h",
    (False, 32): "I",
    (True, 32): "i",
}


def _struct_format(msg: MessageSpec) -> str | None:
    """``struct`` format for byte-aligned layouts, else ``None``."""
    fmt = "<"
    for f in msg.fields:
        if f.start_bit % 8:
            return None
        if f.reserved:
            if f.bits % 8:
                return None
            fmt += "x" * (f.bits // 8)
            continue
        code = _STRUCT_CODES.get((f.signed, f.bits))
        if code is None:
            return None
        fmt += code
    return fmt


def _wrap_doc(text: str, indent: str, width: int = 96, hanging: str = "") -> list[str]:
    return textwrap.wrap(
        text, width=width, initial_indent=indent, subsequent_indent=indent + hanging
    ) or [indent.rstrip()]


def _field_doc(f: FieldSpec) -> str:
    bits = [f.type_name]
    if f.enum:
        bits.append(f"({f.enum})")
    if f.unit:
        bits.append(f"x{f.scale:g} {f.unit}" if f.scale != 1 else f.unit)
    if f.checks_range:
        bits.append(f"range {f.min}..{f.max}")
    if f.limit:
        bits.append(f"limit {f.limit[0]}..{f.limit[1]}")
    head = " ".join(bits)
    return f"{f.name}: {head}. {f.doc}".rstrip(" .") + "."


def _isort_key(name: str) -> tuple[int, str]:
    """Order of ruff's RUF022: SCREAMING_CASE, then CamelCase, then the rest."""
    group = 0 if name.isupper() else 1 if name[:1].isupper() else 2
    return group, name


def _render_enum(e: EnumSpec) -> list[str]:
    lines = ["", "", f"class {e.name}(IntEnum):", f'    """{e.doc}"""', ""]
    lines += [f"    {name} = {code}" for name, code in sorted(e.values, key=lambda kv: kv[1])]
    return lines


def _render_pack(msg: MessageSpec, fmt: str | None) -> list[str]:
    out = [
        "    def pack(self, strict: bool = True) -> bytes:",
        '        """Encode the payload; see :meth:`Message.pack`."""',
    ]
    pub = msg.public_fields
    for f in pub:
        out.append(f"        {f.name} = self.{f.name}")
    for f in pub:
        out.append(
            f"        if not (isinstance({f.name}, int) and {f.min} <= {f.name} <= {f.max}):"
        )
        out.append(
            f'            raise field_error("{msg.name}", "{f.name}", {f.name}, {f.min}, {f.max})'
        )
    limited = [f for f in pub if f.limit]
    if limited:
        out.append("        if strict:")
        for f in limited:
            lo, hi = f.limit or (0, 0)
            out.append(f"            if not {lo} <= {f.name} <= {hi}:")
            out.append(
                f'                raise field_error("{msg.name}", "{f.name}", {f.name}, '
                f"{lo}, {hi}, limit=True)"
            )
    if not pub:
        out.append('        return b""')
    elif fmt is not None:
        args = ", ".join(f.name for f in pub)
        out.append(f"        return _S_{msg.name}.pack({args})")
    else:
        terms = []
        for f in pub:
            value = f"({f.name} & 0x{(1 << f.bits) - 1:X})" if f.signed else f.name
            terms.append(value if f.start_bit == 0 else f"({value} << {f.start_bit})")
        out.append("        value = (")
        for i, term in enumerate(terms):
            out.append(f"            {'| ' if i else ''}{term}")
        out.append("        )")
        out.append(f'        return value.to_bytes({msg.length}, "little")')
    return out


def _render_decode(msg: MessageSpec, fmt: str | None) -> list[str]:
    pub = msg.public_fields
    out = ["", "", f"def _decode_{msg.c_name}(payload: bytes) -> {msg.class_name} | None:"]
    if not pub:
        out.append(f"    return {msg.class_name}()")
        return out
    checked = [f for f in pub if f.checks_range]
    if fmt is not None and not checked:
        out.append(f"    return _new({msg.class_name}, _S_{msg.name}.unpack(payload))")
        return out
    if fmt is not None:
        out.append(f"    values = _S_{msg.name}.unpack(payload)")
        for f in checked:
            out.append(f"    {f.name} = values[{pub.index(f)}]")
    else:
        out.append('    value = int.from_bytes(payload, "little")')
        total = 8 * msg.length
        for f in pub:
            mask = f"0x{(1 << f.bits) - 1:X}" if f.start_bit + f.bits < total else ""
            if f.start_bit and mask:
                expr = f"(value >> {f.start_bit}) & {mask}"
            elif f.start_bit:
                expr = f"value >> {f.start_bit}"
            else:
                expr = f"value & {mask}" if mask else "value"
            if f.signed:  # branch-free sign extension
                sign = f"0x{1 << (f.bits - 1):X}"
                expr = f"(({expr}) ^ {sign}) - {sign}"
            out.append(f"    {f.name} = {expr}")
    if checked:
        cond = " and ".join(f"{f.min} <= {f.name} <= {f.max}" for f in checked)
        out.append(f"    if not ({cond}):")
        out.append("        return None")
    if fmt is not None:
        out.append(f"    return _new({msg.class_name}, values)")
    else:
        args = ", ".join(f.name for f in pub)
        trailing = "," if len(pub) == 1 else ""
        out.append(f"    return _new({msg.class_name}, ({args}{trailing}))")
    return out


def _render_message(msg: MessageSpec, fmt: str | None) -> list[str]:
    out = ["", ""]
    if fmt is not None:
        out += [f'_S_{msg.name} = struct.Struct("{fmt}")', "", ""]
    out += [f"class _{msg.class_name}Fields(NamedTuple):"]
    if msg.public_fields:
        out += [f"    {f.name}: int" for f in msg.public_fields]
    else:
        out += ["    pass"]
    out += ["", "", f"class {msg.class_name}(Message, _{msg.class_name}Fields):"]
    doc_lines = _wrap_doc(
        f"{msg.name} (id {msg.id}, {msg.direction.replace('_', ' ')}, {msg.priority}). {msg.doc}",
        "    ",
        width=93,
    )
    out.append('    """' + doc_lines[0].lstrip())
    out += doc_lines[1:]
    out.append("")
    out.append(f"    Sent: {msg.rate}.")
    if msg.public_fields:
        out.append("")
        out.append("    Attributes:")
        for f in msg.public_fields:
            out += _wrap_doc(_field_doc(f), "        ", hanging="    ")
    out.append('    """')
    out.append("")
    out.append("    __slots__ = ()")
    out.append(f"    MSG_ID: ClassVar[int] = {msg.id}")
    out.append(f'    NAME: ClassVar[str] = "{msg.name}"')
    out.append(f"    LENGTH: ClassVar[int] = {msg.length}")
    out.append(f'    DIRECTION: ClassVar[str] = "{msg.direction}"')
    out.append(f'    PRIORITY: ClassVar[str] = "{msg.priority}"')
    names = "".join(f'"{f.name}", ' for f in msg.public_fields).rstrip(", ")
    trailing = "," if len(msg.public_fields) == 1 else ""
    out.append(f"    FIELDS: ClassVar[tuple[str, ...]] = ({names}{trailing})")
    enums = ", ".join(f'"{f.name}": {f.enum}' for f in msg.public_fields if f.enum)
    out.append(f"    ENUMS: ClassVar[dict[str, type[IntEnum]]] = {{{enums}}}")
    out.append("")
    out += _render_pack(msg, fmt)
    out.append("")
    out.append("    @classmethod")
    out.append(f"    def unpack(cls, payload: bytes) -> {msg.class_name}:")
    out.append('        """Strict decode of one payload.')
    out.append("")
    out.append("        Raises:")
    out.append("            DecodeError: wrong length, or a value outside the wire range.")
    out.append('        """')
    out.append(f"        if len(payload) != {msg.length}:")
    out.append(
        f'            raise DecodeError(f"{msg.name} payload is {{len(payload)}} bytes, '
        f'expected {msg.length}")'
    )
    out.append(f"        decoded = _decode_{msg.c_name}(bytes(payload))")
    out.append("        if decoded is None:")
    out.append(f'            raise DecodeError("{msg.name} payload has a value outside its range")')
    out.append("        return decoded")
    out += _render_decode(msg, fmt)
    return out


def render_python(spec: ProtocolSpec) -> str:
    """The full text of ``messages.py``."""
    classes = sorted(m.class_name for m in spec.messages)
    enums = sorted(e.name for e in spec.enums)
    timing = sorted(k.upper() for k in spec.timing)
    exported = sorted(
        [
            *classes,
            *enums,
            *timing,
            "BY_NAME",
            "DECODERS",
            "LENGTHS",
            "MESSAGE_TYPES",
            "PROTOCOL_VERSION",
            "SCHEMA_HASH",
            "MAX_PAYLOAD_BYTES",
            "CAN_NODE_BITS",
            "BROADCAST_NODE",
            "DEFAULT_NODE",
        ],
        key=_isort_key,
    )
    out = [
        '"""Protocol messages, GENERATED from ``firmware_proto/wire/protocol.toml``. Do not edit.',
        "",
        "Regenerate with ``rover frame generate``. Every class is an immutable named tuple of",
        "raw integer fields (see :mod:`firmware_proto.wire.message` for why); ``pack()``",
        "checks each field and ``unpack()`` is the strict decoder.",
        "The stream decoders use :data:`DECODERS`, which return ``None`` for out-of-range data.",
        '"""',
        "",
        "from __future__ import annotations",
        "",
        "import struct",
        "from collections.abc import Callable",
        "from enum import IntEnum",
        "from typing import ClassVar, NamedTuple",
        "",
        "from firmware_proto.errors import DecodeError",
        "from firmware_proto.wire.message import Message, field_error",
        "",
        "__all__ = [",
    ]
    out += [f'    "{name}",' for name in exported]
    out += [
        "]",
        "",
        f"PROTOCOL_VERSION = {spec.protocol_version}",
        f"SCHEMA_HASH = 0x{spec.schema_hash:04X}",
        f"MAX_PAYLOAD_BYTES = {spec.framing['max_payload_bytes']}",
        f"CAN_NODE_BITS = {spec.framing['can_node_bits']}",
        f"BROADCAST_NODE = {spec.framing['broadcast_node']}",
        f"DEFAULT_NODE = {spec.framing['default_node']}",
        "",
        "_new = tuple.__new__",
        "",
    ]
    out += [f"{key.upper()} = {spec.timing[key]}" for key in spec.timing]
    for e in spec.enums:
        out += _render_enum(e)
    for msg in spec.messages:
        out += _render_message(msg, _struct_format(msg))
    out += ["", ""]
    out.append("MESSAGE_TYPES: dict[int, type[Message]] = {")
    out += [f"    {m.id}: {m.class_name}," for m in spec.messages]
    out.append("}")
    out.append('"""Message class by id."""')
    out.append("")
    out.append(
        "BY_NAME: dict[str, type[Message]] = {cls.NAME: cls for cls in MESSAGE_TYPES.values()}"
    )
    out.append('"""Message class by protocol name."""')
    out.append("")
    out.append("LENGTHS: dict[int, int] = {")
    out += [f"    {m.id}: {m.length}," for m in spec.messages]
    out.append("}")
    out.append('"""Payload length by id."""')
    out.append("")
    out.append("DECODERS: dict[int, Callable[[bytes], Message | None]] = {")
    out += [f"    {m.id}: _decode_{m.c_name}," for m in spec.messages]
    out.append("}")
    out.append(
        '"""Fast decoder by id: payload of the right length -> message, or None if out of range."""'
    )
    return "\n".join(out) + "\n"
