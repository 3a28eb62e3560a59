"""Render the C message codec (``firmware_proto/wire/c/rover_msgs.h`` and ``rover_msgs.c``).

C99 for the firmware: fixed-width integers, no floats, no heap, no stdio, no libc. Each
message becomes a struct of raw integer fields, a ``pack`` that checks the wire range
(and, with ``strict``, the semantic limit) of every field in wire order and names the
first bad one in its error code, and an ``unpack`` that checks the length, unpacks the
bits (sign-extending) and refuses values outside the wire range. A table by id drives
``rp_msg_pack`` / ``rp_msg_unpack``. Framing, COBS, CRC and CAN helpers are hand-written
(``wire/c/rover_proto.[ch]``) on top (docs/protocol.md, "C reference codec").
"""

from __future__ import annotations

import re
import textwrap

from firmware_proto.wire.spec import EnumSpec, FieldSpec, MessageSpec, ProtocolSpec

__all__ = ["render_c_header", "render_c_source"]

_BANNER = (
    "/* GENERATED from firmware_proto/wire/protocol.toml by firmware_proto/wire/codegen/c.py\n"
    " * (`rover frame generate`). Do not edit: edit the spec and regenerate. */"
)

_C_KEYWORDS = frozenset(
    (
        *("auto", "break", "case", "char", "const", "continue", "default", "do", "double"),
        *("else", "enum", "extern", "float", "for", "goto", "if", "inline", "int", "long"),
        *("register", "restrict", "return", "short", "signed", "sizeof", "static", "struct"),
        *("switch", "typedef", "union", "unsigned", "void", "volatile", "while", "_Bool"),
        *("_Complex", "_Imaginary"),
    )
)


def _upper(camel: str) -> str:
    """``StopSource`` -> ``STOP_SOURCE``."""
    return re.sub(r"(?<=[a-z0-9])(?=[A-Z])", "_", camel).upper()


def _enum_type(e: EnumSpec) -> str:
    return f"rp_{_upper(e.name).lower()}_t"


def _ctype(f: FieldSpec) -> str:
    """Smallest ``stdint`` type holding the wire type."""
    width = 8 if f.bits <= 8 else 16 if f.bits <= 16 else 32
    return f"{'int' if f.signed else 'uint'}{width}_t"


def _ctype_range(f: FieldSpec) -> tuple[int, int]:
    width = 8 if f.bits <= 8 else 16 if f.bits <= 16 else 32
    if f.signed:
        return -(1 << (width - 1)), (1 << (width - 1)) - 1
    return 0, (1 << width) - 1


def _lit(value: int, unsigned: bool) -> str:
    """A literal of at least 32 bits, signed or unsigned, that any C99 compiler accepts."""
    if unsigned:
        return f"UINT32_C({value})"
    if value == -(1 << 31):
        return "INT32_MIN"
    return f"INT32_C({value})"


def _comment(text: str) -> str:
    return text.replace("*/", "* /").replace("/*", "/ *")


def _doc_block(text: str, indent: str = "", width: int = 92) -> list[str]:
    """A Doxygen ``/** ... */`` block."""
    lines = textwrap.wrap(_comment(text), width=width - len(indent) - 3) or [""]
    if len(lines) == 1 and len(lines[0]) + len(indent) + 7 <= width:
        return [f"{indent}/** {lines[0]} */"]
    out = [f"{indent}/**"]
    out += [f"{indent} * {line}".rstrip() for line in lines]
    out.append(f"{indent} */")
    return out


def _field_summary(f: FieldSpec) -> str:
    parts = [f.type_name]
    if f.enum:
        parts.append(f"(rp_{_upper(f.enum).lower()}_t)")
    if f.unit:
        parts.append(f"x{f.scale:g} {f.unit}" if f.scale != 1 else f.unit)
    if f.checks_range:
        parts.append(f"range {f.min}..{f.max}")
    if f.limit:
        parts.append(f"limit {f.limit[0]}..{f.limit[1]}")
    head = " ".join(parts)
    return f"{head}: {f.doc.rstrip('.')}." if f.doc else f"{head}."


def _check_names(spec: ProtocolSpec) -> None:
    """Refuse a spec whose C identifiers would collide or be keywords."""
    seen: dict[str, str] = {}

    def claim(name: str, owner: str) -> None:
        if name in seen:
            raise ValueError(f"C identifier {name} of {owner} collides with {seen[name]}")
        seen[name] = owner

    for fixed in ("RP_MSG_COUNT", "RP_ERR", "RP_DIR", "RP_PRIORITY", "RP_F", "RP_MSG"):
        claim(fixed, "the fixed API")
    for e in spec.enums:
        claim(_enum_type(e), f"enum {e.name}")
        for member, _ in e.values:
            claim(f"RP_{_upper(e.name)}_{member}", f"enum {e.name}")
    for m in spec.messages:
        if m.c_name in _C_KEYWORDS:
            raise ValueError(f"message {m.name}: {m.c_name} is a C keyword")
        claim(f"rp_{m.c_name}_t", f"message {m.name}")
        claim(f"RP_MSG_{m.name}", f"message {m.name}")
        for f in m.public_fields:
            if f.name in _C_KEYWORDS:
                raise ValueError(f"message {m.name}: field {f.name} is a C keyword")
            claim(f"RP_F_{m.name}_{f.name.upper()}", f"message {m.name}")


# ------------------------------------------------------------------------------ header


def _header_enum(e: EnumSpec) -> list[str]:
    prefix = f"RP_{_upper(e.name)}_"
    out = ["", *_doc_block(f"{e.name}: {e.doc}"), "typedef enum {"]
    members = sorted(e.values, key=lambda kv: kv[1])
    for i, (name, code) in enumerate(members):
        comma = "," if i < len(members) - 1 else ""
        out.append(f"    {prefix}{name} = {code}{comma}")
    out.append(f"}} {_enum_type(e)};")
    return out


def _header_message(m: MessageSpec) -> list[str]:
    arrow = m.direction.replace("_", " ")
    out = [
        "",
        f"/* {'-' * 8} {m.name} {'-' * max(4, 78 - len(m.name))} */",
        "",
        *_doc_block(
            f"{m.name} (id {m.id}, {arrow}, class {m.priority}, {m.length} bytes). {m.doc} "
            f"Sent: {m.rate}."
        ),
        "typedef struct {",
    ]
    if not m.public_fields:
        out.append("    uint8_t unused_; /**< no fields; C99 needs a member */")
    for f in m.public_fields:
        out += _doc_block(_field_summary(f), "    ")
        out.append(f"    {_ctype(f)} {f.name};")
    out.append(f"}} rp_{m.c_name}_t;")
    out.append("")
    out.append(f"#define RP_MSG_{m.name} {m.id}u /**< message id of {m.name} */")
    out.append(f"#define RP_MSG_{m.name}_LEN {m.length}u /**< payload bytes of {m.name} */")
    out.append(f'#define RP_MSG_{m.name}_NAME "{m.name}"')
    for i, f in enumerate(m.public_fields):
        out.append(f"#define RP_F_{m.name}_{f.name.upper()} {i} /**< field index of {f.name} */")
    out.append("")
    out += _doc_block(
        f"Pack a {m.name} payload into out[0..{m.length}). Checks every field's wire range in "
        "wire order, then, if strict, every semantic limit. Returns the payload length "
        f"({m.length}) or RP_ERR_NULL, RP_ERR_BUFFER (cap < {m.length}), "
        "RP_ERR_FIELD(i) / RP_ERR_LIMIT(i) for the first offending field index i "
        f"(RP_F_{m.name}_*); out is untouched on error."
    )
    out.append(
        f"int rp_{m.c_name}_pack(const rp_{m.c_name}_t *msg, bool strict, uint8_t *out, "
        "size_t cap);"
    )
    out += _doc_block(
        f"Unpack a {m.name} payload of exactly {m.length} bytes into *msg. Returns RP_OK, "
        "RP_ERR_NULL, RP_ERR_LENGTH, or RP_ERR_FIELD(i) for the first field outside its "
        "wire range (the frame must then be dropped); *msg is untouched on error."
    )
    out.append(
        f"int rp_{m.c_name}_unpack(rp_{m.c_name}_t *msg, const uint8_t *payload, size_t len);"
    )
    return out


def render_c_header(spec: ProtocolSpec) -> str:
    """The full text of ``rover_msgs.h``."""
    _check_names(spec)
    fr = spec.framing
    out = [
        _BANNER,
        "",
        "/**",
        " * @file rover_msgs.h",
        f" * @brief Messages of the rover motor-controller protocol, version "
        f"{spec.protocol_version}.",
        " *",
        " * Payloads are bit-packed least significant bit first, little-endian (DBC Intel);",
        " * fields hold raw integers (docs/protocol.md gives units and scales). Every",
        " * function is reentrant, allocation-free and float-free; errors are negative",
        " * return codes (RP_ERR_*), never asserts. Framing, COBS, CRC and the stream and CAN",
        " * decoders are in rover_proto.h.",
        " */",
        "#ifndef ROVER_MSGS_H",
        "#define ROVER_MSGS_H",
        "",
        "#include <stdbool.h>",
        "#include <stddef.h>",
        "#include <stdint.h>",
        "",
        "#ifdef __cplusplus",
        'extern "C" {',
        "#endif",
        "",
        "/* ------------------------------------------------------------ protocol constants */",
        "",
        f"#define RP_PROTOCOL_VERSION {spec.protocol_version}u /**< sent in HELLO and IDENT */",
        f"#define RP_SCHEMA_HASH 0x{spec.schema_hash:04X}u "
        "/**< CRC-16 of the wire-relevant spec; compared at HELLO */",
        f"#define RP_MAX_PAYLOAD_BYTES {fr['max_payload_bytes']}u "
        "/**< largest payload (one classic CAN frame) */",
        f"#define RP_DELIMITER 0x{int(fr['delimiter']):02X}u /**< serial frame delimiter */",
        f"#define RP_CAN_NODE_BITS {fr['can_node_bits']}u "
        "/**< CAN identifier = id << RP_CAN_NODE_BITS | node */",
        f"#define RP_BROADCAST_NODE {fr['broadcast_node']}u "
        "/**< CAN node of host-to-controller broadcasts */",
        f"#define RP_DEFAULT_NODE {fr['default_node']}u /**< default controller node id */",
        f"#define RP_MSG_COUNT {len(spec.messages)}u /**< number of message types */",
        "",
        "/* Timing (docs/protocol.md, 'Timing'). */",
    ]
    for key, value in spec.timing.items():
        out.append(f"#define RP_{key.upper()} {value}u")
    out += [
        "",
        "/* Priority classes: inclusive message id ranges, lower ids win CAN arbitration. */",
    ]
    for p in spec.priorities:
        out.append(f"#define RP_PRIORITY_{p.name.upper()}_FIRST {p.lo}u")
        out.append(f"#define RP_PRIORITY_{p.name.upper()}_LAST {p.hi}u")
    out += [
        "",
        "/* ------------------------------------------------------------ result codes */",
        "",
        "#define RP_OK 0 /**< success */",
        "#define RP_ERR_NULL (-1) /**< a required pointer was NULL */",
        "#define RP_ERR_UNKNOWN_ID (-2) /**< message id not in the protocol */",
        "#define RP_ERR_LENGTH (-3) /**< payload length differs from the message's */",
        "#define RP_ERR_BUFFER (-4) /**< output buffer too small */",
        "#define RP_ERR_NODE (-5) /**< CAN node id outside 0..15 */",
        "#define RP_ERR_BROADCAST (-6) /**< controller-to-host message to the broadcast node */",
        "#define RP_ERR_FRAMING (-7) /**< input is not valid COBS */",
        "#define RP_ERR_FIELD_BASE (-100) /**< see RP_ERR_FIELD() */",
        "#define RP_ERR_LIMIT_BASE (-200) /**< see RP_ERR_LIMIT() */",
        "/** Field with index i (RP_F_*) outside its wire range, or not representable. */",
        "#define RP_ERR_FIELD(i) (RP_ERR_FIELD_BASE - (int)(i))",
        "/** Field with index i (RP_F_*) outside its semantic limit (strict pack only). */",
        "#define RP_ERR_LIMIT(i) (RP_ERR_LIMIT_BASE - (int)(i))",
        "",
        "/** Index of the field named by an RP_ERR_FIELD/RP_ERR_LIMIT code, else -1. */",
        "int rp_err_field_index(int err);",
        "/** True if err is an RP_ERR_LIMIT code (a semantic limit, not the wire range). */",
        "bool rp_err_is_limit(int err);",
        "",
        "/* ------------------------------------------------------------ enumerations */",
    ]
    for e in spec.enums:
        out += _header_enum(e)
    out += ["", "/* ------------------------------------------------------------ messages */"]
    for m in spec.messages:
        out += _header_message(m)
    members = "\n".join(f"        rp_{m.c_name}_t {m.c_name};" for m in spec.messages)
    out += [
        "",
        "/* ------------------------------------------------------------ any message */",
        "",
        "/** Any message: its id and the matching member of body. */",
        "typedef struct {",
        "    uint8_t id; /**< message id (RP_MSG_*), selects the member of body */",
        "    /** The message's fields; only the member named after id is meaningful. */",
        "    union {",
        members,
        "    } body;",
        "} rp_msg_t;",
        "",
        "/** Direction of a message. */",
        "typedef enum {",
        "    RP_DIR_HOST_TO_CONTROLLER = 0,",
        "    RP_DIR_CONTROLLER_TO_HOST = 1",
        "} rp_direction_t;",
        "",
        "/** Static description of one public field. */",
        "typedef struct {",
        "    const char *name; /**< field name as in protocol.toml */",
        "    uint8_t bits; /**< wire width */",
        "    bool is_signed; /**< two's complement */",
        "    int64_t min; /**< wire range, inclusive */",
        "    int64_t max; /**< wire range, inclusive */",
        "    bool has_limit; /**< a semantic limit is checked by strict pack */",
        "    int64_t limit_lo; /**< semantic limit, inclusive (if has_limit) */",
        "    int64_t limit_hi; /**< semantic limit, inclusive (if has_limit) */",
        "} rp_field_info_t;",
        "",
        "/** Static description of one message type. */",
        "typedef struct {",
        "    uint8_t id; /**< message id */",
        "    uint8_t length; /**< payload bytes */",
        "    rp_direction_t direction; /**< who sends it */",
        '    const char *name; /**< protocol name, e.g. "MOTION" */',
        "    uint8_t n_fields; /**< public fields (reserved padding excluded) */",
        "    const rp_field_info_t *fields; /**< n_fields entries, in wire order */",
        "} rp_msg_info_t;",
        "",
        "/** Every message type, sorted by id. */",
        "extern const rp_msg_info_t rp_msg_table[RP_MSG_COUNT];",
        "",
        "/** Description of message id, or NULL if the id is not in the protocol. O(1). */",
        "const rp_msg_info_t *rp_msg_info(uint32_t id);",
        "/** Description of the message called name (NUL-terminated), or NULL. */",
        "const rp_msg_info_t *rp_msg_by_name(const char *name);",
        "",
        "/**",
        " * Pack msg->body per msg->id into out (capacity cap). Returns the payload length or",
        " * a negative RP_ERR_* code (RP_ERR_UNKNOWN_ID, and those of the per-message pack).",
        " */",
        "int rp_msg_pack(const rp_msg_t *msg, bool strict, uint8_t *out, size_t cap);",
        "/**",
        " * Unpack a payload of message id into *msg (msg->id set on success). Returns RP_OK",
        " * or RP_ERR_UNKNOWN_ID, RP_ERR_LENGTH, RP_ERR_FIELD(i), RP_ERR_NULL; *msg is",
        " * untouched on error.",
        " */",
        "int rp_msg_unpack(rp_msg_t *msg, uint32_t id, const uint8_t *payload, size_t len);",
        "/** Value of public field index of *msg into *value. RP_OK or a negative code. */",
        "int rp_msg_get_field(const rp_msg_t *msg, unsigned index, int64_t *value);",
        "/**",
        " * Set public field index of *msg (msg->id must be set). Returns RP_OK, or",
        " * RP_ERR_FIELD(index) if the struct member cannot hold value (the wire range is",
        " * checked by pack, not here), RP_ERR_UNKNOWN_ID, RP_ERR_NULL.",
        " */",
        "int rp_msg_set_field(rp_msg_t *msg, unsigned index, int64_t value);",
        "",
        "#ifdef __cplusplus",
        "}",
        "#endif",
        "",
        "#endif /* ROVER_MSGS_H */",
    ]
    return "\n".join(out) + "\n"


# ------------------------------------------------------------------------------ source


def _mask(f: FieldSpec) -> str:
    return f"UINT64_C(0x{(1 << f.bits) - 1:X})"


def _pack_fn(m: MessageSpec) -> list[str]:
    pub = m.public_fields
    out = [
        "",
        f"int rp_{m.c_name}_pack(const rp_{m.c_name}_t *msg, bool strict, uint8_t *out, "
        "size_t cap)",
        "{",
    ]
    if not pub or not any(f.limit for f in pub):
        out.append("    (void)strict;")
    out += [
        "    if (msg == NULL || out == NULL) {",
        "        return RP_ERR_NULL;",
        "    }",
    ]
    if m.length:
        out += [f"    if (cap < {m.length}u) {{", "        return RP_ERR_BUFFER;", "    }"]
    else:
        out.append("    (void)cap;")
    for i, f in enumerate(pub):
        conds = _range_conds(f"msg->{f.name}", f, f.min, f.max)
        if conds:
            out += [
                f"    if ({' || '.join(conds)}) {{",
                f"        return RP_ERR_FIELD({i});",
                "    }",
            ]
    limited = [(i, f) for i, f in enumerate(pub) if f.limit]
    if limited:
        out.append("    if (strict) {")
        for i, f in limited:
            lo, hi = f.limit or (0, 0)
            conds = _range_conds(f"msg->{f.name}", f, lo, hi)
            if conds:
                out += [
                    f"        if ({' || '.join(conds)}) {{",
                    f"            return RP_ERR_LIMIT({i});",
                    "        }",
                ]
        out.append("    }")
    if pub:
        out.append("    uint64_t w = 0;")
        for f in pub:
            shift = f" << {f.start_bit}" if f.start_bit else ""
            out.append(f"    w |= ((uint64_t)msg->{f.name} & {_mask(f)}){shift};")
        for i in range(m.length):
            shift = f" >> {8 * i}" if i else ""
            out.append(f"    out[{i}] = (uint8_t)(w{shift});")
    else:
        out.append("    (void)msg;")
        out += [f"    out[{i}] = 0u;" for i in range(m.length)]
    out += [f"    return {m.length};", "}"]
    return out


def _range_conds(expr: str, f: FieldSpec, lo: int, hi: int) -> list[str]:
    """Comparisons of a struct member against [lo, hi], omitting those its type makes vacuous."""
    tlo, thi = _ctype_range(f)
    unsigned = not f.signed and f.bits > 16
    conds = []
    if lo > tlo:
        conds.append(f"{expr} < {_lit(lo, unsigned)}")
    if hi < thi:
        conds.append(f"{expr} > {_lit(hi, unsigned)}")
    return conds


def _unpack_fn(m: MessageSpec) -> list[str]:
    pub = m.public_fields
    out = [
        "",
        f"int rp_{m.c_name}_unpack(rp_{m.c_name}_t *msg, const uint8_t *payload, size_t len)",
        "{",
        "    if (msg == NULL || (payload == NULL && len > 0u)) {",
        "        return RP_ERR_NULL;",
        "    }",
        f"    if (len != {m.length}u) {{",
        "        return RP_ERR_LENGTH;",
        "    }",
    ]
    if not pub:
        out += ["    msg->unused_ = 0u;", "    return RP_OK;", "}"]
        return out
    out.append("    uint64_t w = 0;")
    for i in range(m.length):
        shift = f" << {8 * i}" if i else ""
        out.append(f"    w |= (uint64_t)payload[{i}]{shift};")
    for f in pub:
        shifted = f"(w >> {f.start_bit})" if f.start_bit else "w"
        raw = f"({shifted} & {_mask(f)})"
        if f.signed:
            sign = f"(UINT64_C(1) << {f.bits - 1})"
            out.append(
                f"    const int64_t f_{f.name} = (int64_t){raw} - "
                f"(int64_t)(({shifted} & {sign}) << 1);"
            )
        else:
            out.append(f"    const int64_t f_{f.name} = (int64_t){raw};")
    for i, f in enumerate(pub):
        conds = []
        if f.min != f.type_min:
            conds.append(f"f_{f.name} < {f.min}")
        if f.max != f.type_max:
            conds.append(f"f_{f.name} > {f.max}")
        if conds:
            out += [
                f"    if ({' || '.join(conds)}) {{",
                f"        return RP_ERR_FIELD({i});",
                "    }",
            ]
    for f in pub:
        out.append(f"    msg->{f.name} = ({_ctype(f)})f_{f.name};")
    out += ["    return RP_OK;", "}"]
    return out


def _field_table(m: MessageSpec) -> list[str]:
    if not m.public_fields:
        return []
    out = ["", f"static const rp_field_info_t fields_{m.c_name}[] = {{"]
    for f in m.public_fields:
        lo, hi = f.limit if f.limit else (0, 0)
        out.append(
            f'    {{"{f.name}", {f.bits}u, {"true" if f.signed else "false"}, '
            f"INT64_C({f.min}), INT64_C({f.max}), {'true' if f.limit else 'false'}, "
            f"INT64_C({lo}), INT64_C({hi})}},"
        )
    out.append("};")
    return out


def _accessors(spec: ProtocolSpec) -> list[str]:
    get = [
        "",
        "int rp_msg_get_field(const rp_msg_t *msg, unsigned index, int64_t *value)",
        "{",
        "    if (msg == NULL || value == NULL) {",
        "        return RP_ERR_NULL;",
        "    }",
        "    switch (msg->id) {",
    ]
    put = [
        "",
        "int rp_msg_set_field(rp_msg_t *msg, unsigned index, int64_t value)",
        "{",
        "    if (msg == NULL) {",
        "        return RP_ERR_NULL;",
        "    }",
        "    switch (msg->id) {",
    ]
    for m in spec.messages:
        get.append(f"    case RP_MSG_{m.name}:")
        put.append(f"    case RP_MSG_{m.name}:")
        get.append("        switch (index) {")
        put.append("        switch (index) {")
        for i, f in enumerate(m.public_fields):
            member = f"msg->body.{m.c_name}.{f.name}"
            get.append(f"        case {i}u: *value = (int64_t){member}; return RP_OK;")
            tlo, thi = _ctype_range(f)
            put += [
                f"        case {i}u:",
                f"            if (value < INT64_C({tlo}) || value > INT64_C({thi})) {{",
                f"                return RP_ERR_FIELD({i});",
                "            }",
                f"            {member} = ({_ctype(f)})value;",
                "            return RP_OK;",
            ]
        get += ["        default: return RP_ERR_FIELD(index);", "        }"]
        put += ["        default: return RP_ERR_FIELD(index);", "        }"]
    tail = ["    default:", "        return RP_ERR_UNKNOWN_ID;", "    }", "}"]
    return get + tail + put + tail


def render_c_source(spec: ProtocolSpec) -> str:
    """The full text of ``rover_msgs.c``."""
    _check_names(spec)
    out = [
        _BANNER,
        "",
        '#include "rover_msgs.h"',
        "",
        "int rp_err_field_index(int err)",
        "{",
        "    if (err <= RP_ERR_FIELD_BASE && err > RP_ERR_FIELD_BASE - 64) {",
        "        return RP_ERR_FIELD_BASE - err;",
        "    }",
        "    if (err <= RP_ERR_LIMIT_BASE && err > RP_ERR_LIMIT_BASE - 64) {",
        "        return RP_ERR_LIMIT_BASE - err;",
        "    }",
        "    return -1;",
        "}",
        "",
        "bool rp_err_is_limit(int err)",
        "{",
        "    return err <= RP_ERR_LIMIT_BASE && err > RP_ERR_LIMIT_BASE - 64;",
        "}",
    ]
    for m in spec.messages:
        out += _pack_fn(m)
        out += _unpack_fn(m)
    out += [
        "",
        "/* RP_NO_FIELD_INFO leaves out the field descriptions (names, ranges, limits: about",
        " * 3.4 KiB on a Cortex-M0+) that firmware which only packs and unpacks never reads;",
        " * rp_msg_info() then gives n_fields 0 and fields NULL. */",
        "#ifdef RP_NO_FIELD_INFO",
        "#define RP_FIELDS(n, table) 0u, NULL",
        "#else",
    ]
    for m in spec.messages:
        out += _field_table(m)
    out += [
        "#define RP_FIELDS(n, table) n, table",
        "#endif",
        "",
        "const rp_msg_info_t rp_msg_table[RP_MSG_COUNT] = {",
    ]
    for m in spec.messages:
        direction = f"RP_DIR_{m.direction.upper()}"
        fields = f"fields_{m.c_name}" if m.public_fields else "NULL"
        out.append(
            f'    {{RP_MSG_{m.name}, RP_MSG_{m.name}_LEN, {direction}, "{m.name}", '
            f"RP_FIELDS({len(m.public_fields)}u, {fields})}},"
        )
    out.append("};")
    index = {m.id: i for i, m in enumerate(spec.messages)}
    out += [
        "",
        "/* Index into rp_msg_table by message id; 0xFF: not in the protocol. */",
        "static const uint8_t table_index[128] = {",
    ]
    cells = [f"{index[i]}" if i in index else "0xFF" for i in range(128)]
    for row in range(0, 128, 16):
        out.append("    " + ", ".join(cells[row : row + 16]) + ",")
    out += [
        "};",
        "",
        "const rp_msg_info_t *rp_msg_info(uint32_t id)",
        "{",
        "    if (id >= 128u || table_index[id] == 0xFFu) {",
        "        return NULL;",
        "    }",
        "    return &rp_msg_table[table_index[id]];",
        "}",
        "",
        "const rp_msg_info_t *rp_msg_by_name(const char *name)",
        "{",
        "    if (name == NULL) {",
        "        return NULL;",
        "    }",
        "    for (size_t i = 0; i < RP_MSG_COUNT; ++i) {",
        "        const char *a = rp_msg_table[i].name;",
        "        const char *b = name;",
        "        while (*a != '\\0' && *a == *b) {",
        "            ++a;",
        "            ++b;",
        "        }",
        "        if (*a == *b) {",
        "            return &rp_msg_table[i];",
        "        }",
        "    }",
        "    return NULL;",
        "}",
        "",
        "int rp_msg_pack(const rp_msg_t *msg, bool strict, uint8_t *out, size_t cap)",
        "{",
        "    if (msg == NULL) {",
        "        return RP_ERR_NULL;",
        "    }",
        "    switch (msg->id) {",
    ]
    for m in spec.messages:
        out.append(f"    case RP_MSG_{m.name}:")
        out.append(f"        return rp_{m.c_name}_pack(&msg->body.{m.c_name}, strict, out, cap);")
    out += [
        "    default:",
        "        return RP_ERR_UNKNOWN_ID;",
        "    }",
        "}",
        "",
        "int rp_msg_unpack(rp_msg_t *msg, uint32_t id, const uint8_t *payload, size_t len)",
        "{",
        "    if (msg == NULL) {",
        "        return RP_ERR_NULL;",
        "    }",
        "    int rc;",
        "    switch (id) {",
    ]
    for m in spec.messages:
        out.append(f"    case RP_MSG_{m.name}:")
        out.append(f"        rc = rp_{m.c_name}_unpack(&msg->body.{m.c_name}, payload, len);")
        out.append("        break;")
    out += [
        "    default:",
        "        return RP_ERR_UNKNOWN_ID;",
        "    }",
        "    if (rc == RP_OK) {",
        "        msg->id = (uint8_t)id;",
        "    }",
        "    return rc;",
        "}",
    ]
    out += _accessors(spec)
    return "\n".join(out) + "\n"
