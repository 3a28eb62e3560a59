"""The wheel-ground force model: the unrolled four-wheel wrench equals the sum of the
reference per-wheel forces, forces stay within the friction limit, steady slip."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from emulator.traction import (
    TractionModel,
    ideal_spin_yaw_rad,
    saturation_slip_mps,
    steady_slip_mps,
    wheel_force,
)
from emulator.twin import Twin
from firmware_proto.model.rover import RoverDescription

speeds = st.floats(-0.5, 0.5, allow_nan=False)
rates = st.floats(-3.0, 3.0, allow_nan=False)
scales = st.floats(0.05, 1.0, allow_nan=False)


def reference_wrench(
    model: TractionModel,
    v: tuple[float, float, float],
    wheels: tuple[float, float],
    mu_scales: tuple[float, float, float, float],
) -> tuple[float, float, float]:
    vx, vy, w = v
    fx_total = fy_total = tz = 0.0
    for i, (x, y) in enumerate(model.wheel_positions_m):
        u = wheels[0] if y > 0 else wheels[1]
        gx, gy = vx - w * y, vy + w * x
        fx, fy = wheel_force(
            u - gx,
            -gy,
            gx,
            normal_n=model.normal_n,
            mu_long=model.mu_longitudinal * mu_scales[i],
            mu_lat=model.mu_lateral * mu_scales[i],
            saturation_mps=saturation_slip_mps(
                u, model.slip_saturation_mps, model.slip_saturation_ratio
            ),
            rolling_resistance=model.rolling_resistance,
        )
        fx_total += fx
        fy_total += fy
        tz += x * fy - y * fx
    return fx_total, fy_total, tz


@given(
    v=st.tuples(speeds, speeds, rates),
    wheels=st.tuples(speeds, speeds),
    mu=st.tuples(scales, scales, scales, scales),
)
def test_wrench_is_the_sum_of_the_reference_wheel_forces(
    rover: RoverDescription,
    v: tuple[float, float, float],
    wheels: tuple[float, float],
    mu: tuple[float, float, float, float],
) -> None:
    model = TractionModel.from_rover(rover)
    got = model.wrench(*v, *wheels, model.friction_limits_n(mu))[:3]
    want = reference_wrench(model, v, wheels, mu)
    for g, r in zip(got, want, strict=True):
        assert g == pytest.approx(r, rel=1e-9, abs=1e-9)


@given(slip_long=speeds, slip_lat=speeds, ground=speeds, scale=scales)
def test_wheel_force_stays_within_friction_plus_rolling_resistance(
    rover: RoverDescription, slip_long: float, slip_lat: float, ground: float, scale: float
) -> None:
    model = TractionModel.from_rover(rover)
    mu = model.mu_longitudinal * scale
    fx, fy = wheel_force(
        slip_long,
        slip_lat,
        ground,
        normal_n=model.normal_n,
        mu_long=mu,
        mu_lat=mu,
        saturation_mps=0.01,
        rolling_resistance=model.rolling_resistance,
    )
    limit = (mu + model.rolling_resistance) * model.normal_n
    assert math.hypot(fx, fy) <= limit * (1 + 1e-12)
    # The friction part pushes along the slip.
    assert (fx + model.rolling_resistance * model.normal_n * math.tanh(ground / 0.005)) * (
        slip_long
    ) >= 0.0
    assert fy * slip_lat >= 0.0


def test_no_force_at_rest(rover: RoverDescription) -> None:
    model = TractionModel.from_rover(rover)
    assert model.wrench(0.0, 0.0, 0.0, 0.0, 0.0, model.friction_limits_n((1.0,) * 4))[:3] == (
        0.0,
        0.0,
        0.0,
    )


@given(
    v=st.tuples(speeds, rates),
    wheels=st.tuples(speeds, speeds),
    dt=st.sampled_from([0.001, 0.005, 0.02]),
)
def test_step_wrench_damps_but_never_reverses_the_force(
    rover: RoverDescription, v: tuple[float, float], wheels: tuple[float, float], dt: float
) -> None:
    model = TractionModel.from_rover(rover)
    limits = model.friction_limits_n((1.0,) * 4)
    raw = model.wrench(v[0], 0.0, v[1], *wheels, limits)[:3]
    damped = model.step_wrench(v[0], 0.0, v[1], *wheels, limits, dt)
    for r, d in zip(raw, damped, strict=True):
        assert abs(d) <= abs(r) + 1e-12
        assert r * d >= 0.0


def test_steady_slip_matches_the_twin_at_cruise(rover: RoverDescription) -> None:
    """Cruising straight at a reduced traction, the wheels slip by S * atanh(Crr / mu)."""
    scale = 0.3
    twin = Twin(rover)
    twin.set_traction_scale(scale, scale)
    omega = rover.speed_to_omega(60)
    twin.set_motor_omegas(rover.drive.left_wheel_sign * omega, rover.drive.right_wheel_sign * omega)
    twin.advance(8.0)
    u = rover.max_speed_mps
    t = rover.traction
    expected = steady_slip_mps(
        t.mu_longitudinal * scale,
        t.rolling_resistance,
        saturation_slip_mps(u, t.slip_saturation_mps, t.slip_saturation_ratio),
    )
    slip = u - twin.body_velocity.vx_mps
    assert expected > 0.001  # a real, visible slip
    assert slip == pytest.approx(expected, rel=0.01)


def test_steady_slip_is_infinite_when_friction_cannot_beat_the_resistance() -> None:
    assert steady_slip_mps(0.04, 0.05, 0.01) == math.inf
    assert steady_slip_mps(0.6, 0.05, 0.01) == pytest.approx(0.01 * math.atanh(0.05 / 0.6))


def test_ideal_spin_yaw() -> None:
    assert ideal_spin_yaw_rad(0.21 * math.pi, 0.42) == pytest.approx(math.pi)


@given(
    v=st.tuples(speeds, speeds, rates),
    wheels=st.tuples(speeds, speeds),
    mu=st.tuples(scales, scales, scales, scales),
)
def test_damping_is_the_diagonal_of_the_jacobian(
    rover: RoverDescription,
    v: tuple[float, float, float],
    wheels: tuple[float, float],
    mu: tuple[float, float, float, float],
) -> None:
    """C = -dF/dv per component, checked against central differences."""
    model = TractionModel.from_rover(rover)
    limits = model.friction_limits_n(mu)
    damping = model.wrench(*v, *wheels, limits)[3:6]
    h = 1e-7
    for axis in range(3):
        step = tuple(h if i == axis else 0.0 for i in range(3))
        vx_up, vy_up, w_up = (a + b for a, b in zip(v, step, strict=True))
        vx_dn, vy_dn, w_dn = (a - b for a, b in zip(v, step, strict=True))
        up = model.wrench(vx_up, vy_up, w_up, *wheels, limits)[axis]
        down = model.wrench(vx_dn, vy_dn, w_dn, *wheels, limits)[axis]
        slope = (up - down) / (2 * h)
        assert damping[axis] == pytest.approx(max(0.0, -slope), rel=1e-4, abs=1e-3)
