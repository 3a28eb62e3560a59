"""The physical figures of a drift stop from stamped poses (planner/ground/overshoot.py)."""

from __future__ import annotations

import math

import pytest

from planner.ground.overshoot import off_path_m, overshoot

PATH = [(0.0, 0.0), (2.0, 0.0)]


def _veer(stop_at_s: float) -> list[tuple[float, float, float]]:
    """Along x at 0.5 m/s, drifting sideways at 0.2 m/s from t = 1 s, at rest from
    ``stop_at_s`` on; 10 Hz."""
    poses = []
    for i in range(60):
        t = 0.1 * i
        moving = min(t, stop_at_s)
        y = 0.2 * max(0.0, moving - 1.0)
        poses.append((t, 0.5 * moving, y))
    return poses


def test_the_distance_to_the_path() -> None:
    assert off_path_m(PATH, 1.0, 0.3) == pytest.approx(0.3)
    assert off_path_m(PATH, 3.0, 0.0) == pytest.approx(1.0)


def test_past_the_limit_to_rest() -> None:
    figure = overshoot(PATH, _veer(3.0))
    assert figure is not None and figure.crossed
    # 0.25 m off the path at t = 2.25 s (first sample past it at 2.3 s); at rest at 3.0 s
    assert figure.crossed_s == pytest.approx(2.3)
    assert figure.time_to_rest_s == pytest.approx(0.7)
    assert figure.past_limit_m == pytest.approx(0.7 * math.hypot(0.5, 0.2), abs=1e-6)
    assert figure.rest_off_path_m == pytest.approx(0.4)
    assert "driven past 0.25 m off the approved path" in figure.line()


def test_from_the_moment_drift_control_saw_it() -> None:
    figure = overshoot(PATH, _veer(3.0), crossing_s=1.5)
    assert figure is not None and figure.crossed_s == pytest.approx(1.5)
    assert figure.time_to_rest_s == pytest.approx(1.5)


def test_never_past_the_limit_and_noise_at_rest() -> None:
    poses = _veer(1.5)
    # POSE noise of a centimetre at rest is rest
    poses = [
        (t, x, y + (0.01 if i % 2 else -0.01) * (t > 1.5)) for i, (t, x, y) in enumerate(poses)
    ]
    figure = overshoot(PATH, poses)
    assert figure is not None and not figure.crossed
    assert figure.worst_off_path_m < 0.25 and not math.isnan(figure.rest_s)
    assert "never 0.25 m off the approved path" in figure.line()
    assert overshoot(PATH, []) is None
