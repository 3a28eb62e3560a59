"""The geometry helpers: angles, segments, polygons."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from firmware_proto.model.geometry import (
    closest_point_on_segment,
    convex_parts,
    point_in_polygon,
    point_segment_distance,
    polygon_crossing,
    segment_polygon_distance,
    segment_segment_distance,
    segments_intersect,
    signed_area,
    wrap_deg,
    wrap_rad,
)

finite = st.floats(-1e6, 1e6, allow_nan=False)


@given(finite)
def test_wrap_deg_lands_in_range_and_keeps_the_angle(angle: float) -> None:
    w = wrap_deg(angle)
    assert -180.0 <= w < 180.0
    assert math.isclose(math.cos(math.radians(w)), math.cos(math.radians(angle)), abs_tol=1e-6)
    assert math.isclose(math.sin(math.radians(w)), math.sin(math.radians(angle)), abs_tol=1e-6)


def test_wrap_examples() -> None:
    assert wrap_deg(180.0) == -180.0
    assert wrap_deg(-190.0) == 170.0
    assert wrap_deg(720.0 + 30.0) == 30.0
    assert wrap_rad(3 * math.pi / 2) == pytest.approx(-math.pi / 2)
    assert wrap_rad(math.pi) == -math.pi


@given(st.floats(-math.pi, math.pi, exclude_max=True))
def test_wrap_rad_leaves_an_angle_in_range_bit_for_bit(angle: float) -> None:
    assert wrap_rad(angle) == angle


def test_point_segment_distance() -> None:
    assert point_segment_distance((0, 1), (-1, 0), (1, 0)) == pytest.approx(1.0)
    assert point_segment_distance((3, 4), (0, 0), (0, 0)) == pytest.approx(5.0)
    assert point_segment_distance((2, 1), (-1, 0), (1, 0)) == pytest.approx(math.sqrt(2))


def test_segments() -> None:
    assert segments_intersect((0, 0), (2, 2), (0, 2), (2, 0))
    assert segments_intersect((0, 0), (1, 0), (1, 0), (2, 5))  # touching ends
    assert not segments_intersect((0, 0), (1, 0), (0, 1), (1, 1))
    assert segment_segment_distance((0, 0), (1, 0), (0, 1), (1, 1)) == pytest.approx(1.0)
    assert segment_segment_distance((0, 0), (2, 2), (0, 2), (2, 0)) == 0.0
    # collinear within rounding: decimal map coordinates are not exact in binary
    assert segments_intersect((0.1, 0.1), (0.3, 0.3), (0.2, 0.2), (0.7, 0.7))
    assert closest_point_on_segment((1, 1), (0, 0), (2, 0)) == ((1, 0), 0.5)


def test_point_in_polygon_concave() -> None:
    ell = [(0, 0), (2, 0), (2, 1), (1, 1), (1, 2), (0, 2)]
    assert point_in_polygon((0.5, 1.5), ell)
    assert not point_in_polygon((1.5, 1.5), ell)


def test_polygons() -> None:
    square = [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)]
    assert signed_area(square) == 1.0
    assert signed_area(square[::-1]) == -1.0
    assert polygon_crossing(square) is None
    bow_tie = [(0.0, 0.0), (1.0, 1.0), (1.0, 0.0), (0.0, 1.0)]
    assert polygon_crossing(bow_tie) == (0, 2)
    assert segment_polygon_distance((2, 0.5), (3, 0.5), square) == pytest.approx(1.0)
    assert segment_polygon_distance((0.2, 0.2), (0.3, 0.3), square) == 0.0  # inside


@given(
    radii=st.lists(st.floats(0.3, 2.0), min_size=3, max_size=14),
    phase=st.floats(0.0, 1.0),
)
def test_convex_parts_cover_a_star_polygon_exactly(radii: list[float], phase: float) -> None:
    """Star-shaped polygons (simple, often concave) split into convex, counter-clockwise
    pieces whose areas sum to the polygon's."""
    n = len(radii)
    points = tuple(
        (r * math.cos(2 * math.pi * (i + phase) / n), r * math.sin(2 * math.pi * (i + phase) / n))
        for i, r in enumerate(radii)
    )
    parts = convex_parts(points)
    assert sum(signed_area(p) for p in parts) == pytest.approx(signed_area(points), rel=1e-9)
    for part in parts:
        assert signed_area(part) > 0
        k = len(part)
        for i in range(k):
            (ax, ay), (bx, by), (cx, cy) = part[i], part[(i + 1) % k], part[(i + 2) % k]
            assert (bx - ax) * (cy - ay) - (by - ay) * (cx - ax) >= -1e-12


def test_concave_obstacle_collides_where_the_polygon_is() -> None:
    ell = ((0.0, 0.0), (2.0, 0.0), (2.0, 0.5), (0.5, 0.5), (0.5, 2.0), (0.0, 2.0))
    parts = convex_parts(ell)
    assert len(parts) > 1
    assert point_in_polygon((0.25, 1.5), ell)
    assert not point_in_polygon((1.5, 1.5), ell)
    assert convex_parts(ell) == parts  # deterministic
