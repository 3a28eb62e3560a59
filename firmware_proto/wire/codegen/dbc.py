"""Render the CAN database (``firmware_proto/wire/rover.dbc``) from the spec model: the
frames of one controller node (``render_dbc(spec, node)``; the file holds the spec's
default node). Reserved padding is not a signal; ranges are physical values (raw *
scale); enum fields carry ``VAL_`` tables.
"""

from __future__ import annotations

from firmware_proto.errors import EncodeError
from firmware_proto.wire.spec import MessageSpec, ProtocolSpec

__all__ = ["render_dbc"]


def _text(value: str) -> str:
    return value.replace('"', "'").replace("\\", "/")


def _num(value: float) -> str:
    return f"{value:.6g}" if value != int(value) else str(int(value))


def _frame_id(spec: ProtocolSpec, msg: MessageSpec, node: int) -> int:
    return (msg.id << int(spec.framing["can_node_bits"])) | node


def _controller_nodes(spec: ProtocolSpec) -> range:
    """Node ids a controller may have: the identifier's node values above broadcast (0),
    which is host to controller only."""
    broadcast = int(spec.framing["broadcast_node"])
    return range(broadcast + 1, 1 << int(spec.framing["can_node_bits"]))


def render_dbc(spec: ProtocolSpec, node: int | None = None) -> str:
    """DBC text for the frames of controller ``node`` (default: the spec's default node).

    Raises:
        EncodeError: ``node`` is not a controller node id (1..15: node 0 is broadcast,
            and larger ids do not fit the identifier's node bits).
    """
    node = int(spec.framing["default_node"]) if node is None else node
    nodes = _controller_nodes(spec)
    if node not in nodes:
        raise EncodeError(
            f"controller node id {node} outside {nodes.start}..{nodes.stop - 1} "
            f"(node {spec.framing['broadcast_node']} is broadcast)",
            field="node",
        )
    lines = [
        f'VERSION "rover-proto-v{spec.protocol_version}-{spec.schema_hash:04X}"',
        "",
        "NS_ :",
        "    CM_",
        "    BA_DEF_",
        "    BA_",
        "    VAL_",
        "",
        "BS_:",
        "",
        "BU_: HOST CONTROLLER",
        "",
    ]
    comments = [
        f'CM_ "Rover motor-controller protocol v{spec.protocol_version}, schema hash '
        f"0x{spec.schema_hash:04X}, node {node}. GENERATED from firmware_proto/wire/protocol.toml; "
        'do not edit.";'
    ]
    values = []
    for msg in spec.messages:
        frame_id = _frame_id(spec, msg, node)
        sender, receiver = (
            ("HOST", "CONTROLLER")
            if msg.direction == "host_to_controller"
            else ("CONTROLLER", "HOST")
        )
        lines.append(f"BO_ {frame_id} {msg.name}: {msg.length} {sender}")
        for f in msg.public_fields:
            sign = "-" if f.signed else "+"
            lo, hi = f.min * f.scale, f.max * f.scale
            lines.append(
                f" SG_ {f.name} : {f.start_bit}|{f.bits}@1{sign} ({_num(f.scale)},0) "
                f'[{_num(lo)}|{_num(hi)}] "{_text(f.unit)}" {receiver}'
            )
            if f.doc:
                comments.append(f'CM_ SG_ {frame_id} {f.name} "{_text(f.doc)}";')
            if f.enum:
                members = sorted(spec.enum(f.enum).values, key=lambda kv: kv[1], reverse=True)
                body = " ".join(f'{code} "{name}"' for name, code in members)
                values.append(f"VAL_ {frame_id} {f.name} {body} ;")
        lines.append("")
        comments.append(f'CM_ BO_ {frame_id} "{_text(msg.doc)}";')
    lines += comments
    lines.append("")
    lines += values
    return "\n".join(lines) + "\n"
