"""Small maps built in code for the twin tests."""

from __future__ import annotations

from typing import Any

from firmware_proto.model.worldmap import WorldMap


def make_map(
    obstacles: list[dict[str, Any]] | None = None,
    regions: list[dict[str, Any]] | None = None,
    *,
    bounds: tuple[float, float, float, float] = (-5.0, -5.0, 5.0, 5.0),
    start: tuple[float, float, float] = (0.0, 0.0, 0.0),
) -> WorldMap:
    """A map document built in code (validated like a file)."""
    doc: dict[str, Any] = {
        "name": "test",
        "description": "built by a test",
        "bounds": dict(zip(("min_x", "min_y", "max_x", "max_y"), bounds, strict=True)),
        "obstacles": obstacles or [],
        "traction_regions": regions or [],
        "start": {"x": start[0], "y": start[1], "yaw_deg": start[2]},
    }
    return WorldMap.from_dict(doc)


def box(oid: str, x0: float, y0: float, x1: float, y1: float) -> dict[str, Any]:
    """An axis-aligned rectangular polygon obstacle."""
    return {"id": oid, "type": "polygon", "points": [[x0, y0], [x1, y0], [x1, y1], [x0, y1]]}
