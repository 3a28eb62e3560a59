"""Render ``docs/protocol.md``: hand-written prose from ``protocol.md.tmpl`` with the
message, CAN identifier, enum and timing tables filled in from the spec model."""

from __future__ import annotations

from pathlib import Path
from string import Template

from firmware_proto.model.rover import RoverDescription, load_rover
from firmware_proto.wire.spec import FieldSpec, MessageSpec, ProtocolSpec

__all__ = ["render_markdown"]


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def _field_type(f: FieldSpec) -> str:
    return f"{f.type_name} ({f.enum})" if f.enum else f.type_name


def _field_range(f: FieldSpec) -> str:
    parts = []
    if f.checks_range:
        parts.append(f"{f.min}..{f.max}")
    if f.limit:
        parts.append(f"limit {f.limit[0]}..{f.limit[1]}")
    return ", ".join(parts) or "-"


def _unit(f: FieldSpec) -> str:
    if not f.unit:
        return "-"
    return f"{f.scale:g} {f.unit}" if f.scale != 1 else f.unit


def _message_table(spec: ProtocolSpec) -> str:
    rows = ["| id | name | direction | class | bytes | sent |", "|---:|---|---|---|---:|---|"]
    for m in spec.messages:
        arrow = "host -> ctrl" if m.direction == "host_to_controller" else "ctrl -> host"
        rows.append(
            f"| {m.id} | [{m.name}](#{m.name.lower()}) | {arrow} | {m.priority} | "
            f"{m.length} | {_cell(m.rate)} |"
        )
    return "\n".join(rows)


def _can_table(spec: ProtocolSpec) -> str:
    bits = int(spec.framing["can_node_bits"])
    default = int(spec.framing["default_node"])
    rows = [
        f"| class | message | CAN id, node n | node {default} | node 15 |",
        "|---|---|---|---:|---:|",
    ]
    for m in spec.messages:
        rows.append(
            f"| {m.priority} | {m.name} | `0x{m.id << bits:03X} + n` | "
            f"`0x{(m.id << bits) | default:03X}` | `0x{(m.id << bits) | 15:03X}` |"
        )
    return "\n".join(rows)


def _details(m: MessageSpec) -> str:
    lines = [
        f"### {m.name}",
        "",
        f"id {m.id}, {m.direction.replace('_', ' ')}, class "
        f"{m.priority}, {m.length} bytes; sent {m.rate}.",
        "",
        m.doc,
        "",
    ]
    lines += ["| bits | field | type | unit | range | meaning |", "|---|---|---|---|---|---|"]
    for f in m.fields:
        span = f"{f.start_bit}..{f.start_bit + f.bits - 1}"
        meaning = "reserved, send 0" if f.reserved else _cell(f.doc)
        lines.append(
            f"| {span} | `{f.name}` | {_field_type(f)} | {_unit(f)} | "
            f"{_field_range(f)} | {meaning} |"
        )
    return "\n".join(lines)


def _enum_tables(spec: ProtocolSpec) -> str:
    out = []
    for e in spec.enums:
        members = ", ".join(
            f"{name} = {code}" for name, code in sorted(e.values, key=lambda kv: kv[1])
        )
        out.append(f"- **{e.name}**: {members}. {e.doc}")
    return "\n".join(out)


def _timing_table(spec: ProtocolSpec) -> str:
    rows = ["| constant | value |", "|---|---:|"]
    rows += [f"| `{key.upper()}` | {value} |" for key, value in spec.timing.items()]
    return "\n".join(rows)


def _g(value: float) -> str:
    return f"{value:g}"


def _drive_values(rover: RoverDescription) -> dict[str, str]:
    """The rover description's numbers that the "Units and drive" section quotes."""
    d, g = rover.drive, rover.geometry
    return {
        "wheel_radius_m": _g(g.wheel_radius_m),
        "speed_scale_rad_s": _g(d.wheel_velocity_scale_rad_s),
        "speed_unit_mps": _g(rover.speed_to_mps(1)),
        "max_speed": str(d.max_speed),
        "max_speed_mps": _g(round(rover.speed_to_mps(d.max_speed), 6)),
        "max_speed_rad_s": _g(round(rover.speed_to_omega(d.max_speed), 6)),
        "units_per_m": str(d.distance_units_per_m),
        "max_distance": str(d.max_distance),
        "max_distance_m": f"{d.max_distance / d.distance_units_per_m:.3f}",
        "accel_mps2": _g(d.wheel_accel_limit_mps2),
        "track_width_m": _g(g.track_width_m),
        "left_sign": f"{d.left_wheel_sign:+d}",
        "right_sign": f"{d.right_wheel_sign:+d}",
        "turn_efficiency": _g(rover.traction.turn_efficiency),
    }


def render_markdown(spec: ProtocolSpec) -> str:
    """The full text of ``docs/protocol.md`` (the units section quotes the packaged rover
    description, so it is regenerated, and checked stale, when that file changes)."""
    template = Template(
        (Path(__file__).resolve().parent / "protocol.md.tmpl").read_text(encoding="utf-8")
    )
    return template.substitute(
        protocol_version=spec.protocol_version,
        schema_hash=f"0x{spec.schema_hash:04X}",
        message_table=_message_table(spec),
        can_table=_can_table(spec),
        message_details="\n\n".join(_details(m) for m in spec.messages),
        enum_tables=_enum_tables(spec),
        timing_table=_timing_table(spec),
        **{key: value for key, value in spec.timing.items()},
        **_drive_values(load_rover()),
    )
