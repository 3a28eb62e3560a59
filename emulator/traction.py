"""Wheel-ground force model of the twin: pure functions, no physics engine.

Body frame: ``x`` forward, ``y`` left, origin at the centre of mass. A wheel at
``(x_i, y_i)`` with surface speed ``u`` on a body moving at ``(vx, vy, w)`` has contact
ground velocity ``g = (vx - w*y_i, vy + w*x_i)`` and slip ``s = (u - g_x, -g_y)``; its
force ``(mu_long, mu_lat) * N * tanh(sigma) / sigma * s / S`` (``sigma = |s| / S``,
``S = s0 + kappa * |u|``, ``N = m * g / 4``) saturates as a friction ellipse, less the
rolling resistance ``Crr * N * tanh(g_x / v_rr)`` along the wheel.
:meth:`TractionModel.step_wrench` integrates it linearly-implicitly on the diagonal, so
steady states do not depend on the step. docs/twin.md ("Wheel forces", "Integration")
explains the model and its parameters.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from firmware_proto.model.rover import RoverDescription

__all__ = [
    "ROLLING_SPEED_SCALE_MPS",
    "WHEEL_COUNT",
    "TractionModel",
    "ideal_spin_yaw_rad",
    "saturation_slip_mps",
    "steady_slip_mps",
    "wheel_force",
    "wheel_load_n",
]

WHEEL_COUNT = 4
"""Wheels on the ground, in the order front-left, rear-left, front-right, rear-right."""

ROLLING_SPEED_SCALE_MPS = 0.005
"""Ground speed below which rolling resistance fades out (``tanh(g_x / v_rr)``), m/s: one
speed unit: it only removes the discontinuity at rest, which would make the force chatter."""

_TINY_SIGMA = 1e-9


def wheel_load_n(mass_kg: float, gravity_mps2: float, wheels: int = WHEEL_COUNT) -> float:
    """Normal force on one wheel, N, with the weight shared equally."""
    return mass_kg * gravity_mps2 / wheels


def saturation_slip_mps(wheel_speed_mps: float, floor_mps: float, ratio: float) -> float:
    """Slip speed scale of the saturation for a wheel turning at ``wheel_speed_mps``:
    ``S = s0 + kappa * |u|``, m/s."""
    return floor_mps + ratio * abs(wheel_speed_mps)


def wheel_force(
    slip_long_mps: float,
    slip_lat_mps: float,
    ground_long_mps: float,
    *,
    normal_n: float,
    mu_long: float,
    mu_lat: float,
    saturation_mps: float,
    rolling_resistance: float,
    rolling_speed_scale_mps: float = ROLLING_SPEED_SCALE_MPS,
) -> tuple[float, float]:
    """Force of the ground on one wheel in the wheel frame, ``(F_long, F_lat)`` in N.

    Args:
        slip_long_mps: wheel surface speed minus ground speed along the wheel.
        slip_lat_mps: minus the ground speed across the wheel.
        ground_long_mps: ground speed of the contact along the wheel (the rolling
            resistance opposes it).
        normal_n: wheel load, N.
        mu_long, mu_lat: friction coefficients along and across the wheel (already
            multiplied by any traction scale).
        saturation_mps: ``S`` of :func:`saturation_slip_mps` for this wheel.
        rolling_resistance: rolling resistance coefficient ``Crr`` (force / load).
        rolling_speed_scale_mps: speed below which rolling resistance fades out.

    The reference form; :meth:`TractionModel.wrench` must give the same for four wheels.
    """
    sx = slip_long_mps / saturation_mps
    sy = slip_lat_mps / saturation_mps
    sigma = math.sqrt(sx * sx + sy * sy)
    gain = math.tanh(sigma) / sigma if sigma > _TINY_SIGMA else 1.0
    rolling = rolling_resistance * normal_n * math.tanh(ground_long_mps / rolling_speed_scale_mps)
    return mu_long * normal_n * gain * sx - rolling, mu_lat * normal_n * gain * sy


def ideal_spin_yaw_rad(arc_travel_m: float, track_width_m: float) -> float:
    """Yaw of an in-place spin without slip when each side travels ``arc_travel_m``."""
    return 2.0 * arc_travel_m / track_width_m


def steady_slip_mps(mu: float, rolling_resistance: float, saturation_mps: float) -> float:
    """Steady longitudinal slip speed, m/s, cruising straight on level ground:
    ``S * atanh(Crr / mu)``; ``inf`` when ``mu <= Crr`` (the wheels just spin).
    """
    ratio = rolling_resistance / mu
    if ratio >= 1.0:
        return math.inf
    return saturation_mps * math.atanh(ratio)


def _wheel(
    nx: float, ny: float, limit_x: float, limit_y: float, inv_s: float
) -> tuple[float, float, float, float, float, float]:
    """One wheel's friction force and its slip derivatives.

    Args:
        nx, ny: slip velocity divided by the saturation slip speed ``S``.
        limit_x, limit_y: ``mu_long * N`` and ``mu_lat * N``.
        inv_s: ``1 / S``.

    Returns:
        ``(Fx, Fy, dFx/dsx, dFy/dsy, dFx/dsy + dFy/dsx, a/S)`` with ``s`` in m/s and
        ``a = tanh(sigma)/sigma``; ``mu*N * a/S`` is the secant stiffness ``F/s``.
    """
    sig2 = nx * nx + ny * ny
    if sig2 > _TINY_SIGMA * _TINY_SIGMA:
        sig = math.sqrt(sig2)
        th = math.tanh(sig)
        a = th / sig
        b = 1.0 - th * th
        cx2 = nx * nx / sig2
        cxy = nx * ny / sig2
    else:
        a = b = 1.0
        cx2 = 1.0
        cxy = 0.0
    cy2 = 1.0 - cx2
    return (
        limit_x * a * nx,
        limit_y * a * ny,
        limit_x * inv_s * (a * cy2 + b * cx2),
        limit_y * inv_s * (a * cx2 + b * cy2),
        (limit_x + limit_y) * inv_s * (b - a) * cxy,
        a * inv_s,
    )


@dataclass(frozen=True)
class TractionModel:
    """The force model's parameters for one rover, SI units.

    Wheel contact points are at ``(+-half_wheelbase_m, +-half_track_m)``. Build it from
    the rover description with :meth:`from_rover`.
    """

    normal_n: float
    mu_longitudinal: float
    mu_lateral: float
    slip_saturation_mps: float
    slip_saturation_ratio: float
    rolling_resistance: float
    half_track_m: float
    half_wheelbase_m: float
    mass_kg: float
    inertia_kg_m2: float
    rolling_speed_scale_mps: float = ROLLING_SPEED_SCALE_MPS

    @classmethod
    def from_rover(cls, rover: RoverDescription) -> TractionModel:
        """Parameters from the rover description; yaw inertia of a uniform chassis box."""
        g, t, m = rover.geometry, rover.traction, rover.mass.mass_kg
        return cls(
            normal_n=wheel_load_n(m, rover.environment.gravity_mps2),
            mu_longitudinal=t.mu_longitudinal,
            mu_lateral=t.mu_lateral,
            slip_saturation_mps=t.slip_saturation_mps,
            slip_saturation_ratio=t.slip_saturation_ratio,
            rolling_resistance=t.rolling_resistance,
            half_track_m=g.track_width_m / 2.0,
            half_wheelbase_m=g.wheelbase_m / 2.0,
            mass_kg=m,
            inertia_kg_m2=m * (g.chassis_length_m**2 + g.chassis_width_m**2) / 12.0,
        )

    @property
    def wheel_positions_m(self) -> tuple[tuple[float, float], ...]:
        """Contact points in the body frame, in wheel order FL, RL, FR, RR."""
        hx, hy = self.half_wheelbase_m, self.half_track_m
        return ((hx, hy), (-hx, hy), (hx, -hy), (-hx, -hy))

    def friction_limits_n(self, mu_scales: tuple[float, ...]) -> tuple[float, ...]:
        """``(mu_long*N, mu_lat*N)`` per wheel (FL, RL, FR, RR), flattened to 8 floats,
        for :meth:`wrench`.

        Args:
            mu_scales: one friction scale per wheel, in wheel order.
        """
        n = self.normal_n
        out: list[float] = []
        for scale in mu_scales:
            out += [self.mu_longitudinal * n * scale, self.mu_lateral * n * scale]
        return tuple(out)

    def wrench(
        self,
        vx_mps: float,
        vy_mps: float,
        yaw_rate_rad_s: float,
        left_mps: float,
        right_mps: float,
        limits_n: tuple[float, ...],
    ) -> tuple[float, float, float, float, float, float, float, float, float]:
        """Total ground force and torque on the body and their damping, body frame.

        Args:
            vx_mps, vy_mps, yaw_rate_rad_s: body velocity in the body frame.
            left_mps, right_mps: wheel surface speed of each side, forward positive.
            limits_n: :meth:`friction_limits_n` for the current friction scales.

        Returns:
            ``(Fx, Fy, Tz, Cx, Cy, Cz, Kx, Ky, Kz)``: force (N), torque (N*m); the
            Jacobian's diagonal ``C = -dF/dv`` (N per m/s, N*m per rad/s); and the
            secant stiffness ``K`` summed over the wheels (for :meth:`step_wrench`).
        """
        hx = self.half_wheelbase_m
        hy = self.half_track_m
        s0 = self.slip_saturation_mps
        kappa = self.slip_saturation_ratio
        rr = self.rolling_resistance * self.normal_n
        inv_vrr = 1.0 / self.rolling_speed_scale_mps
        inv_sl = 1.0 / (s0 + kappa * (left_mps if left_mps >= 0.0 else -left_mps))
        inv_sr = 1.0 / (s0 + kappa * (right_mps if right_mps >= 0.0 else -right_mps))
        # Ground speed along each side's wheels; lateral slip at the front and rear axle.
        gl = vx_mps - yaw_rate_rad_s * hy
        gr = vx_mps + yaw_rate_rad_s * hy
        lat_f = -(vy_mps + yaw_rate_rad_s * hx)
        lat_b = -(vy_mps - yaw_rate_rad_s * hx)
        lxf, lyf, lxb, lyb, rxf, ryf, rxb, ryb = limits_n
        fl = _wheel((left_mps - gl) * inv_sl, lat_f * inv_sl, lxf, lyf, inv_sl)
        bl = _wheel((left_mps - gl) * inv_sl, lat_b * inv_sl, lxb, lyb, inv_sl)
        fr = _wheel((right_mps - gr) * inv_sr, lat_f * inv_sr, rxf, ryf, inv_sr)
        br = _wheel((right_mps - gr) * inv_sr, lat_b * inv_sr, rxb, ryb, inv_sr)
        xl = gl * inv_vrr
        xr = gr * inv_vrr
        tl = math.tanh(xl)
        tr = math.tanh(xr)
        fx_l = fl[0] + bl[0] - 2.0 * rr * tl
        fx_r = fr[0] + br[0] - 2.0 * rr * tr
        fy_f = fl[1] + fr[1]
        fy_b = bl[1] + br[1]
        rr_slope = 2.0 * rr * inv_vrr
        cx = fl[2] + bl[2] + fr[2] + br[2] + rr_slope * ((1.0 - tl * tl) + (1.0 - tr * tr))
        cy = fl[3] + bl[3] + fr[3] + br[3]
        # dT/dw = -(y_i^2 kx + x_i^2 ky) + x_i*y_i*kxy; cross terms: + FL, RR; - RL, FR.
        cross = fl[4] + br[4] - bl[4] - fr[4]
        cz = hy * hy * cx + hx * hx * cy - hx * hy * cross
        # Secant stiffness F/v (what an explicit step would apply), for the overshoot guard.
        kx = lxf * fl[5] + lxb * bl[5] + rxf * fr[5] + rxb * br[5]
        kx += rr_slope * (
            (tl / xl if abs(xl) > _TINY_SIGMA else 1.0)
            + (tr / xr if abs(xr) > _TINY_SIGMA else 1.0)
        )
        ky = lyf * fl[5] + lyb * bl[5] + ryf * fr[5] + ryb * br[5]
        return (
            fx_l + fx_r,
            fy_f + fy_b,
            hy * (fx_r - fx_l) + hx * (fy_f - fy_b),
            cx,
            cy,
            cz if cz > 0.0 else 0.0,
            kx,
            ky,
            hy * hy * kx + hx * hx * ky,
        )

    def step_wrench(
        self,
        vx_mps: float,
        vy_mps: float,
        yaw_rate_rad_s: float,
        left_mps: float,
        right_mps: float,
        limits_n: tuple[float, ...],
        dt_s: float,
    ) -> tuple[float, float, float]:
        """Force and torque to apply for one step of ``dt_s``, body frame (N, N, N*m).

        :meth:`wrench` made linearly implicit on the diagonal: each component divided by
        ``1 + dt * C / M`` (``M`` = mass, mass, yaw inertia), with ``C`` raised to
        ``K - M/dt`` where an explicit step would carry the slip past zero. Exact in
        steady state; stable and monotone at any step the twin accepts.
        """
        fx, fy, tz, cx, cy, cz, kx, ky, kz = self.wrench(
            vx_mps, vy_mps, yaw_rate_rad_s, left_mps, right_mps, limits_n
        )
        m = self.mass_kg
        inertia = self.inertia_kg_m2
        m_dt = m / dt_s
        i_dt = inertia / dt_s
        cx = max(cx, kx - m_dt)
        cy = max(cy, ky - m_dt)
        cz = max(cz, kz - i_dt)
        return (
            fx * m / (m + dt_s * cx),
            fy * m / (m + dt_s * cy),
            tz * inertia / (inertia + dt_s * cz),
        )
