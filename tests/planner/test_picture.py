"""The mission picture (``planner/record/picture.py``): a drift STOP and a rejected plan's
collision are told apart, obstacles are named, and a scale bar gives the metres."""

from __future__ import annotations

from typing import Any

from PIL import Image

from firmware_proto.model.pose import Pose
from planner.record import picture


def _pixel(image: Image.Image, at: tuple[float, float]) -> tuple[int, ...]:
    value: Any = image.getpixel((round(at[0]), round(at[1])))
    return tuple(value)


def test_drift_stop_and_collision_are_distinct_marks_with_a_legend_and_a_scale(
    worlds: dict[str, Any],
) -> None:
    world = worlds["lab"]
    drift, hit = (3.0, 1.5), (5.0, 4.5)  # open floor, away from every obstacle and path
    shown = picture.MissionPicture(
        world,
        Pose(6.2, 3.0, 0.0),
        world.start,
        drift_stops=[drift],
        collisions=[(hit, "table")],
        title="test",
    )
    px_per_m, margin = 80.0, 20
    image = picture.draw(shown, px_per_m=px_per_m, margin_px=margin)
    b = world.bounds

    def px(p: tuple[float, float]) -> tuple[float, float]:
        return (margin + (p[0] - b.min_x) * px_per_m, 22 + margin + (b.max_y - p[1]) * px_per_m)

    assert _pixel(image, px(drift)) == picture._DRIFT  # the octagon is filled at its centre
    assert _pixel(image, px(hit)) == picture._COLLISION  # the X crosses at its centre
    assert picture._DRIFT != picture._COLLISION
    # The scale bar: a black line 1 m (80 px) long ending at the right margin, in the
    # legend band below the map.
    y = image.height - 18 + 6
    right = image.width - margin
    assert _pixel(image, (right - 1, y)) == (0, 0, 0)
    assert _pixel(image, (right - px_per_m + 1, y)) == (0, 0, 0)
    assert _pixel(image, (right - px_per_m - 3, y)) != (0, 0, 0)
    # Obstacles carry their names: white text inside the table's grey.
    table = next(o for o in world.obstacles if o.id == "table")
    xs = [p[0] for p in table.points]
    ys = [p[1] for p in table.points]
    left, top = px((min(xs), max(ys)))
    right_, bottom = px((max(xs), min(ys)))
    inside = image.crop((round(left), round(top), round(right_), round(bottom)))
    colours = {c for _, c in inside.getcolors(maxcolors=10_000) or []}
    assert any(isinstance(c, tuple) and min(c) > 220 for c in colours), colours  # white label


def test_the_gate_pictures_legend_band_is_drawn(tmp_path: Any) -> None:
    import subprocess
    import sys

    plan = tmp_path / "plan.json"
    plan.write_text(
        '{"goal": {"x": 2.2, "y": 3.0, "yaw_deg": 0}, '
        '"commands": [{"command": "FWD", "speed": 60, "distance": 23000}]}'
    )
    png = tmp_path / "v.png"
    done = subprocess.run(
        [sys.executable, "-m", "firmware_proto.cli", "gate", "check", str(plan), "--png", str(png)],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert png.exists(), done.stderr
    from gate.render import LEGEND_PX

    image = Image.open(png).convert("RGB")
    band = image.crop((0, image.height - LEGEND_PX, image.width, image.height))
    colours = {c for _, c in band.getcolors(maxcolors=100_000) or []}
    assert (40, 90, 200) in colours and (235, 120, 20) in colours  # planned, predicted
    assert (20, 20, 20) in colours  # the labels and the scale bar


def test_a_concave_obstacles_name_is_drawn_on_it(worlds: dict[str, Any]) -> None:
    """Issue #41: the lab's L-shaped workbench was named at the mean of its corners,
    which lies in the notch of the L: white letters on the floor, unreadable. Its name
    now sits inside it, outlined, clear of the legend band."""
    world = worlds["lab"]
    bench = next(o for o in world.obstacles if o.id == "workbench")
    mean = picture._mean(bench.points)
    assert not picture._inside(mean, bench.points)  # why it went wrong
    at = picture.label_point(bench.points)
    assert picture._inside(at, bench.points)
    assert picture._edge_distance(at, bench.points) >= 0.2  # in the L's thick part
    shown = picture.MissionPicture(world, Pose(6.2, 3.0, 0.0), world.start, title="t")
    px_per_m, margin = 80.0, 20
    image = picture.draw(shown, px_per_m=px_per_m, margin_px=margin)
    b = world.bounds
    x = margin + (at[0] - b.min_x) * px_per_m
    y = 22 + margin + (b.max_y - at[1]) * px_per_m
    assert y + 8 < image.height - 18  # above the legend band
    # The letters (white, outlined dark) are drawn around that point.
    around = image.crop((round(x - 30), round(y - 8), round(x + 30), round(y + 8)))
    colours = {c for _, c in around.getcolors(maxcolors=10_000) or []}
    assert any(isinstance(c, tuple) and min(c) > 220 for c in colours), colours  # white
    assert picture._LABEL_EDGE in colours  # its outline


def test_a_missions_picture_never_overwrites_the_last_ones(tmp_path: Any) -> None:
    """Issue #41: ``rover go`` wrote ``./mission.png`` over the last mission's."""
    import time

    wall = time.mktime((2026, 11, 28, 12, 0, 1, 0, 0, -1))
    first = picture.fresh_path("mission", tmp_path, wall)
    assert first == tmp_path / "mission-20261128-120001.png"
    first.write_bytes(b"x")
    second = picture.fresh_path("mission", tmp_path, wall)  # the same second
    assert second == tmp_path / "mission-20261128-120001-2.png"
    second.write_bytes(b"y")
    assert picture.fresh_path("mission", tmp_path, wall).name == "mission-20261128-120001-3.png"
    assert first.read_bytes() == b"x"
