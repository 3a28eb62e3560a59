"""The rover's pose on board: an extended Kalman filter of its map pose, fed by the
bridge's odometry (encoder travel along the integrated IMU heading, ``odom``) and
corrected by the ground-seeing POSE (``odom_ground``) (docs/onboard.md, "The estimate").

State ``[x, y, yaw]`` (map frame: metres, radians) and its 3x3 covariance.

- **Predict** with every ``odom`` sample: the motion since the previous one, taken in
  the rover's own frame (forward, left, turn), applied at the estimate's heading.
  Process noise grows with the motion (``forward_sigma_per_m``, ``lateral_sigma_per_m``
  of the distance, ``yaw_sigma_per_rad`` of the turn, plus floors): encoders cannot see
  slip.
- **Correct** with every POSE at its own stamp (older than the last ``odom``: the
  sensor's latency): the filter goes back to its state at that stamp (a short history
  is kept), applies the correction there, and replays the motion since. A POSE between
  two ``odom`` samples splits the motion at its stamp; one newer than the newest
  ``odom`` waits for the odometry to pass its stamp (:meth:`PoseEkf._wait`); one older
  than the history is dropped and counted.
  An innovation over ``gate_chi2`` (squared Mahalanobis distance) is a slip or one bad
  fix: it is held, and the next POSE decides. One that agrees with it confirms the slip
  (the covariance is inflated by the innovation first, so the estimate goes to the
  sensor at once); one that agrees with the filter makes the held fix an outlier,
  dropped and counted (:attr:`PoseEkf.outliers`). So one bad fix never moves the
  estimate, and a slip costs one POSE period.
- Until the first POSE (or :meth:`PoseEkf.reset` with a known pose) the filter has no
  map pose; it only follows ``odom`` to be ready.
- **Bad input loses nothing.** An ``odom`` sample or a POSE that is not finite, a POSE
  covariance that is not symmetric positive definite, is refused and counted
  (:attr:`PoseEkf.rejected`) and changes nothing (not even the POSE's age). Should the
  state itself ever stop being finite, the filter forgets its map pose
  (:attr:`PoseEkf.poisoned`): no estimate is better than a wrong one.

Plain float arithmetic on 3-vectors and row-major 3x3 tuples, not numpy or filterpy:
docs/onboard.md, "The estimate", says why. Numpy arrays are taken as input (POSE and
reset covariances).

Pure: no I/O, no clock (stamps come with the samples), no thread; not thread-safe.
"""

from __future__ import annotations

import bisect
import math
from collections import deque
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from firmware_proto.model.geometry import wrap_rad

__all__ = ["EkfConfig", "Estimate", "PoseEkf"]

Matrix = npt.NDArray[np.float64]
Vec = tuple[float, float, float]
"""A state ``(x, y, yaw)`` or an innovation."""
Mat = tuple[float, float, float, float, float, float, float, float, float]
"""A 3x3 matrix, row-major."""


@dataclass(frozen=True)
class EkfConfig:
    """Noise model and history of :class:`PoseEkf`.

    Attributes:
        forward_sigma_per_m: 1-sigma error of the forward motion, per metre driven.
        lateral_sigma_per_m: 1-sigma sideways motion per metre driven.
        yaw_sigma_per_rad: 1-sigma heading error per radian turned (gyro scale).
        floor_m, floor_rad: noise added to every prediction (m, rad).
        gate_chi2: squared Mahalanobis distance of a POSE innovation above which the
            covariance is inflated by it first (3 degrees of freedom; 16.3 is 99.9 %).
        history_s: how far back a POSE may be applied, s: at least the wire's oldest
            POSE (``age_4ms`` field) plus the delivery. An older POSE is dropped and
            counted (:attr:`PoseEkf.too_old`).
        max_step_m, max_turn_rad: an ``odom`` motion larger than these between two
            samples is no motion but a new odometry frame (the bridge restarted): the
            filter re-bases on it.
        future_hold_s: how far a POSE may run ahead of the newest ``odom`` while it
            waits for the odometry to pass its stamp, s; further, the odometry is taken
            for silent and the waiting POSEs are applied at the newest state.
        max_waiting: at most this many POSEs wait (more: the oldest is applied at the
            newest state).
    """

    forward_sigma_per_m: float = 0.25
    lateral_sigma_per_m: float = 0.15
    yaw_sigma_per_rad: float = 0.05
    floor_m: float = 0.0005
    floor_rad: float = 0.0005
    gate_chi2: float = 16.3
    history_s: float = 1.5
    max_step_m: float = 0.5
    max_turn_rad: float = 1.0
    future_hold_s: float = 1.0
    max_waiting: int = 32


@dataclass(frozen=True)
class Estimate:
    """The rover's pose as the filter has it at ``stamp_s``.

    Attributes:
        stamp_s: the time of the estimate (the latest ``odom`` or POSE), s.
        x_m, y_m, yaw_deg: the pose in the map frame.
        covariance: row-major 3x3 covariance of ``x, y, yaw`` (m^2, m rad, rad^2).
        v_mps, yaw_rate_rad_s: the rover's motion from ``odom``'s twist (encoder speed,
            gyro rate): zero means the wheels stand.
        pose_stamp_s: the stamp of the last POSE taken (``-inf``: none yet).
        unseen_m: the distance the odometry moved after ``pose_stamp_s`` by the
            samples' own stamps (not the order they were read in), m: the motion no
            ground-seeing sensor has checked yet. A lower bound when that POSE is older
            than the history (the history's whole distance).
    """

    stamp_s: float
    x_m: float
    y_m: float
    yaw_deg: float
    covariance: tuple[float, ...]
    v_mps: float = 0.0
    yaw_rate_rad_s: float = 0.0
    pose_stamp_s: float = -math.inf
    unseen_m: float = 0.0

    @property
    def finite(self) -> bool:
        """Every number of the pose, its covariance and its twist is finite."""
        pose = (self.stamp_s, self.x_m, self.y_m, self.yaw_deg, self.unseen_m)
        values = (*pose, self.v_mps, self.yaw_rate_rad_s, *self.covariance)
        return all(math.isfinite(v) for v in values)

    @property
    def pose_age_s(self) -> float:
        """How old the last POSE in it is, s (``inf``: none)."""
        return self.stamp_s - self.pose_stamp_s

    @property
    def sigma_xy_m(self) -> float:
        """1-sigma position error (the larger axis), m."""
        cov = self.covariance
        a, b, c = cov[0], cov[1], cov[4]
        return math.sqrt(max(0.0, (a + c) / 2.0 + math.sqrt(((a - c) / 2.0) ** 2 + b * b)))


_EYE: Mat = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
_ZERO: Vec = (0.0, 0.0, 0.0)


class _SingularError(ArithmeticError):
    """A 3x3 matrix that has no inverse (as numpy's ``LinAlgError``)."""


def _mul(a: Mat, b: Mat) -> Mat:
    """``a @ b``."""
    a0, a1, a2, a3, a4, a5, a6, a7, a8 = a
    b0, b1, b2, b3, b4, b5, b6, b7, b8 = b
    return (
        a0 * b0 + a1 * b3 + a2 * b6,
        a0 * b1 + a1 * b4 + a2 * b7,
        a0 * b2 + a1 * b5 + a2 * b8,
        a3 * b0 + a4 * b3 + a5 * b6,
        a3 * b1 + a4 * b4 + a5 * b7,
        a3 * b2 + a4 * b5 + a5 * b8,
        a6 * b0 + a7 * b3 + a8 * b6,
        a6 * b1 + a7 * b4 + a8 * b7,
        a6 * b2 + a7 * b5 + a8 * b8,
    )


def _mul_t(a: Mat, b: Mat) -> Mat:
    """``a @ b.T``."""
    a0, a1, a2, a3, a4, a5, a6, a7, a8 = a
    b0, b1, b2, b3, b4, b5, b6, b7, b8 = b
    return (
        a0 * b0 + a1 * b1 + a2 * b2,
        a0 * b3 + a1 * b4 + a2 * b5,
        a0 * b6 + a1 * b7 + a2 * b8,
        a3 * b0 + a4 * b1 + a5 * b2,
        a3 * b3 + a4 * b4 + a5 * b5,
        a3 * b6 + a4 * b7 + a5 * b8,
        a6 * b0 + a7 * b1 + a8 * b2,
        a6 * b3 + a7 * b4 + a8 * b5,
        a6 * b6 + a7 * b7 + a8 * b8,
    )


def _add(a: Mat, b: Mat) -> Mat:
    """``a + b``."""
    return (
        a[0] + b[0],
        a[1] + b[1],
        a[2] + b[2],
        a[3] + b[3],
        a[4] + b[4],
        a[5] + b[5],
        a[6] + b[6],
        a[7] + b[7],
        a[8] + b[8],
    )


def _inv(m: Mat) -> Mat:
    """The inverse of ``m`` (the adjugate over the determinant).

    Raises:
        _SingularError: the determinant is zero.
    """
    m0, m1, m2, m3, m4, m5, m6, m7, m8 = m
    c0 = m4 * m8 - m5 * m7
    c1 = m5 * m6 - m3 * m8
    c2 = m3 * m7 - m4 * m6
    det = m0 * c0 + m1 * c1 + m2 * c2
    if det == 0.0:
        raise _SingularError("a singular matrix")
    d = 1.0 / det
    return (
        c0 * d,
        (m2 * m7 - m1 * m8) * d,
        (m1 * m5 - m2 * m4) * d,
        c1 * d,
        (m0 * m8 - m2 * m6) * d,
        (m2 * m3 - m0 * m5) * d,
        c2 * d,
        (m1 * m6 - m0 * m7) * d,
        (m0 * m4 - m1 * m3) * d,
    )


def _quadratic(v: Vec, m: Mat) -> float:
    """``v @ inv(m) @ v``.

    Raises:
        _SingularError: ``m`` has no inverse.
    """
    i = _inv(m)
    a, b, c = v
    return (
        a * (i[0] * a + i[1] * b + i[2] * c)
        + b * (i[3] * a + i[4] * b + i[5] * c)
        + c * (i[6] * a + i[7] * b + i[8] * c)
    )


def _finite(values: tuple[float, ...]) -> bool:
    return all(math.isfinite(v) for v in values)


def _close(a: float, b: float) -> bool:
    """numpy's ``isclose(a, b, rtol=1e-6, atol=1e-12)`` for finite numbers."""
    return abs(a - b) <= 1e-12 + 1e-6 * abs(b)


def _covariance(value: Matrix | object) -> Mat | None:
    """A 3x3 covariance as a row-major tuple, ``None`` when it is not one: not 3x3
    numbers, not finite, not symmetric, or not positive definite (no Cholesky factor)."""
    try:
        if type(value) is tuple and len(value) == 9:  # a Mat: no numpy on the way
            flat = [float(v) for v in value]
        else:
            flat = np.asarray(value, dtype=float).reshape(9).tolist()
    except (TypeError, ValueError):
        return None
    p: Mat = tuple(flat)  # type: ignore[assignment]
    if not _finite(p) or not (_close(p[1], p[3]) and _close(p[2], p[6]) and _close(p[5], p[7])):
        return None
    # The Cholesky factor of the lower triangle (numpy's), pivot by pivot.
    d0 = p[0]
    if not d0 > 0.0:
        return None
    l00 = math.sqrt(d0)
    l10, l20 = p[3] / l00, p[6] / l00
    d1 = p[4] - l10 * l10
    if not d1 > 0.0:
        return None
    l21 = (p[7] - l20 * l10) / math.sqrt(d1)
    if not p[8] - l20 * l20 - l21 * l21 > 0.0:
        return None
    return p


@dataclass
class _Entry:
    stamp: float
    x: Vec
    p: Mat
    motion: tuple[float, float, float]
    """The motion applied to reach this entry (forward, left, turn)."""


class PoseEkf:
    """See the module docstring."""

    def __init__(self, config: EkfConfig | None = None) -> None:
        self.config = config or EkfConfig()
        self._x: Vec = _ZERO
        self._p: Mat = _EYE
        self._ready = False
        self._stamp = -math.inf
        self._odom: tuple[float, float, float] | None = None
        self._history: deque[_Entry] = deque()
        self._motion = (0.0, 0.0)
        self._pose_stamp = -math.inf
        self._waiting: list[tuple[float, Vec, Mat]] = []
        """POSEs newer than the newest ``odom``: (stamp, measurement, covariance), oldest first."""
        self._taken: Estimate | None = None
        self.corrections = 0
        """POSE samples applied."""
        self.inflations = 0
        """POSE samples that inflated the covariance first (a slip, confirmed by two)."""
        self.outliers = 0
        """POSE samples held outside the gate and not confirmed by the next: dropped."""
        self._held: tuple[Vec, Mat] | None = None
        """A POSE outside the gate awaiting the next to confirm it: (innovation, covariance)."""
        self.too_old = 0
        """POSE samples older than the history, dropped (applied late, they move the rover back)."""
        self.rejected = 0
        """Samples refused: not finite, or a POSE covariance not positive definite."""
        self.poisoned = 0
        """Times the state stopped being finite and the map pose was forgotten."""
        self.rebased = 0
        """``odom`` jumps taken for a new odometry frame (no motion applied)."""

    @property
    def ready(self) -> bool:
        """The filter has a map pose (a POSE came, or :meth:`reset`)."""
        return self._ready

    def reset(
        self, x_m: float, y_m: float, yaw_rad: float, covariance: Matrix | Mat, stamp_s: float
    ) -> None:
        """Start at a known pose with its covariance.

        Raises:
            ValueError: the pose or stamp is not finite, or the covariance is not
                symmetric positive definite.
        """
        p = _covariance(covariance)
        if p is None or not all(math.isfinite(v) for v in (x_m, y_m, yaw_rad, stamp_s)):
            raise ValueError("reset: a pose, stamp or covariance that is not usable")
        self._x = (float(x_m), float(y_m), wrap_rad(yaw_rad))
        self._p = p
        self._stamp = stamp_s
        self._history.clear()
        self._history.append(_Entry(stamp_s, self._x, self._p, (0.0, 0.0, 0.0)))
        self._held = None
        self._waiting.clear()
        self._ready = True

    # -- predict ---------------------------------------------------------------------------
    def predict(
        self,
        stamp_s: float,
        odom_x_m: float,
        odom_y_m: float,
        odom_yaw_rad: float,
        v_mps: float = 0.0,
        yaw_rate_rad_s: float = 0.0,
    ) -> None:
        """One ``odom`` sample (its pose in the odometry frame and its twist); refused
        (counted, nothing changes) when any of it is not finite."""
        values = (stamp_s, odom_x_m, odom_y_m, odom_yaw_rad, v_mps, yaw_rate_rad_s)
        if not all(math.isfinite(v) for v in values):
            self.rejected += 1
            return
        previous, self._odom = self._odom, (odom_x_m, odom_y_m, odom_yaw_rad)
        self._motion = (v_mps, yaw_rate_rad_s)
        if previous is None:
            self._stamp = max(self._stamp, stamp_s)
            return
        px, py, pyaw = previous
        dx, dy = odom_x_m - px, odom_y_m - py
        c, s = math.cos(pyaw), math.sin(pyaw)
        motion = (c * dx + s * dy, -s * dx + c * dy, wrap_rad(odom_yaw_rad - pyaw))
        cfg = self.config
        if math.hypot(dx, dy) > cfg.max_step_m or abs(motion[2]) > cfg.max_turn_rad:
            # Not motion: the odometry frame started over (the bridge restarted).
            self.rebased += 1
            self._stamp = max(self._stamp, stamp_s)
            return
        if not self._ready:
            self._stamp = max(self._stamp, stamp_s)
            return
        self._x, self._p = self._apply(self._x, self._p, motion)
        self._stamp = max(self._stamp, stamp_s)
        self._history.append(_Entry(stamp_s, self._x, self._p, motion))
        self._trim()
        self._check_state()
        while self._ready and self._waiting and self._waiting[0][0] <= stamp_s:
            self._take(*self._waiting.pop(0))  # the odometry has passed it

    def _apply(self, x: Vec, p: Mat, motion: tuple[float, float, float]) -> tuple[Vec, Mat]:
        """The state and covariance after ``motion`` (an overflow is caught by
        :meth:`_check_state`)."""
        cfg = self.config
        fwd, left, turn = motion
        yaw = x[2]
        c, s = math.cos(yaw), math.sin(yaw)
        new = (x[0] + c * fwd - s * left, x[1] + s * fwd + c * left, wrap_rad(yaw + turn))
        # F = [[1, 0, f02], [0, 1, f12], [0, 0, 1]]: the motion's Jacobian in the state.
        f: Mat = (1.0, 0.0, -s * fwd - c * left, 0.0, 1.0, c * fwd - s * left, 0.0, 0.0, 1.0)
        dist = math.hypot(fwd, left)
        q0 = cfg.forward_sigma_per_m * dist + cfg.floor_m
        q1 = cfg.lateral_sigma_per_m * dist + cfg.floor_m
        q2 = cfg.yaw_sigma_per_rad * abs(turn) + cfg.floor_rad
        q0, q1, q2 = q0 * q0, q1 * q1, q2 * q2
        # G Q G.T, G the rotation of the body frame into the map's, Q = diag(q0, q1, q2).
        q01 = c * q0 * s - s * q1 * c
        q: Mat = (
            c * q0 * c + s * q1 * s,
            q01,
            0.0,
            q01,
            s * q0 * s + c * q1 * c,
            0.0,
            0.0,
            0.0,
            q2,
        )
        return new, _add(_mul_t(_mul(f, p), f), q)

    def _trim(self) -> None:
        horizon = self._stamp - self.config.history_s
        while len(self._history) > 1 and self._history[1].stamp <= horizon:
            self._history.popleft()

    # -- correct ---------------------------------------------------------------------------
    def correct(
        self, stamp_s: float, x_m: float, y_m: float, yaw_rad: float, covariance: Matrix | Mat
    ) -> None:
        """One POSE, measured at ``stamp_s``, with its 3x3 covariance (x, y, yaw);
        refused (counted, nothing changes) when it is not finite or its covariance is
        not symmetric positive definite."""
        r = _covariance(covariance)
        if r is None or not all(math.isfinite(v) for v in (stamp_s, x_m, y_m, yaw_rad)):
            self.rejected += 1
            return
        z = (float(x_m), float(y_m), wrap_rad(yaw_rad))
        if not self._ready:
            self.reset(x_m, y_m, yaw_rad, r, max(stamp_s, self._stamp))
            self._pose_stamp = max(self._pose_stamp, stamp_s)
            self.corrections += 1
            return
        if stamp_s > self._history[-1].stamp:
            self._wait(stamp_s, z, r)
        else:
            self._take(stamp_s, z, r)

    def _wait(self, stamp_s: float, z: Vec, r: Mat) -> None:
        """A POSE newer than the newest ``odom`` waits for the odometry to pass it (a
        backlog may hand it over first), within ``future_hold_s`` and ``max_waiting``."""
        waiting = self._waiting
        bisect.insort(waiting, (stamp_s, z, r), key=lambda w: w[0])
        cfg = self.config
        silent = waiting[-1][0] - self._history[-1].stamp > cfg.future_hold_s
        while self._ready and waiting and (silent or len(waiting) > cfg.max_waiting):
            self._take(*waiting.pop(0))

    def _take(self, stamp_s: float, z: Vec, r: Mat) -> None:
        """Apply one POSE at its stamp (at the newest state when it is newer still)."""
        history = self._history
        # The last entry at or before the measurement; the motions after it are replayed.
        index = len(history) - 1
        while index > 0 and history[index].stamp > stamp_s:
            index -= 1
        if history[index].stamp > stamp_s:
            self.too_old += 1
            return
        if index + 1 < len(history) and history[index].stamp < stamp_s:
            index = self._split(index, stamp_s)
        base = history[index]
        try:
            updated = self._update(base.x, base.p, z, r)
        except _SingularError:
            self.rejected += 1
            return
        if updated is None:
            return  # held for the next POSE to confirm
        x, p = updated
        self._pose_stamp = max(self._pose_stamp, stamp_s)
        history[index] = _Entry(base.stamp, x, p, base.motion)
        for i in range(index + 1, len(history)):
            entry = history[i]
            x, p = self._apply(x, p, entry.motion)
            history[i] = _Entry(entry.stamp, x, p, entry.motion)
        self._x, self._p = x, p
        self._stamp = max(self._stamp, stamp_s)
        self.corrections += 1
        self._check_state()

    def _split(self, index: int, stamp_s: float) -> int:
        """Split the motion of the entry after ``index`` at ``stamp_s`` (in proportion to
        the time); returns the index of the new entry, at ``stamp_s``."""
        history = self._history
        before, after = history[index], history[index + 1]
        share = (stamp_s - before.stamp) / (after.stamp - before.stamp)
        first = (
            after.motion[0] * share,
            after.motion[1] * share,
            after.motion[2] * share,
        )
        rest = (after.motion[0] - first[0], after.motion[1] - first[1], after.motion[2] - first[2])
        x, p = self._apply(before.x, before.p, first)
        history[index + 1] = _Entry(after.stamp, after.x, after.p, rest)
        history.insert(index + 1, _Entry(stamp_s, x, p, first))
        return index + 1

    def _check_state(self) -> None:
        """A state that is not finite is forgotten: no map pose until the next POSE."""
        if _finite(self._x) and _finite(self._p):
            return
        self.poisoned += 1
        self._ready = False
        self._x = _ZERO
        self._p = _EYE
        self._history.clear()
        self._waiting.clear()

    def _update(self, x: Vec, p: Mat, z: Vec, r: Mat) -> tuple[Vec, Mat] | None:
        """The correction by ``z``; ``None`` when ``z`` is held (the module docstring).
        An overflow is caught by :meth:`_check_state`.

        Raises:
            _SingularError: the innovation's covariance has no inverse.
        """
        y = (z[0] - x[0], z[1] - x[1], wrap_rad(z[2] - x[2]))
        s = _add(p, r)
        nis = _quadratic(y, s)
        gate = self.config.gate_chi2
        held, self._held = self._held, None
        if nis > gate:
            if held is None or not self._agree(held, (y, r), p, gate):
                self._held = (y, r)  # one fix is no slip yet: wait for the next
                if held is not None:
                    self.outliers += 1
                return None
            # Two fixes agree the rover moved where the odometry could not see (slip):
            # trust the sensor.
            self.inflations += 1
            y0, y1, y2 = y
            p = _add(
                p, (y0 * y0, y0 * y1, y0 * y2, y1 * y0, y1 * y1, y1 * y2, y2 * y0, y2 * y1, y2 * y2)
            )
            s = _add(p, r)
        elif held is not None:
            self.outliers += 1  # the fix held was one bad fix
        k = _mul(p, _inv(s))
        new = (
            x[0] + (k[0] * y[0] + k[1] * y[1] + k[2] * y[2]),
            x[1] + (k[3] * y[0] + k[4] * y[1] + k[5] * y[2]),
            wrap_rad(x[2] + (k[6] * y[0] + k[7] * y[1] + k[8] * y[2])),
        )
        i_k: Mat = (
            1.0 - k[0],
            -k[1],
            -k[2],
            -k[3],
            1.0 - k[4],
            -k[5],
            -k[6],
            -k[7],
            1.0 - k[8],
        )
        # Joseph form: stays symmetric, positive.
        p = _add(_mul_t(_mul(i_k, p), i_k), _mul_t(_mul(k, r), k))
        return new, p

    @staticmethod
    def _agree(a: tuple[Vec, Mat], b: tuple[Vec, Mat], p: Mat, gate: float) -> bool:
        """Two innovations tell the same story: their difference within ``gate`` of the
        filter's and both fixes' covariance.

        Raises:
            _SingularError: the summed covariance has no inverse.
        """
        d = (b[0][0] - a[0][0], b[0][1] - a[0][1], wrap_rad(b[0][2] - a[0][2]))
        return _quadratic(d, _add(_add(p, a[1]), b[1])) <= gate

    # -- read ------------------------------------------------------------------------------
    def estimate(self) -> Estimate | None:
        """The current estimate, ``None`` before the filter has a map pose."""
        if not self._ready:
            return None
        x, p = self._x, self._p
        return Estimate(
            self._stamp,
            x[0],
            x[1],
            math.degrees(x[2]),
            p,
            self._motion[0],
            self._motion[1],
            self._pose_stamp,
            self._unseen_m(),
        )

    def take_estimate(self) -> Estimate | None:
        """The estimate when it changed since the last one taken, else ``None``: a POSE
        that waits, is held or is refused changes nothing, and a guard that counts
        estimates towards its persistence must not count one twice."""
        estimate = self.estimate()
        if estimate is None or estimate == self._taken:
            return None
        self._taken = estimate
        return estimate

    def _unseen_m(self) -> float:
        """The distance of the motions stamped after the last POSE's stamp, m."""
        total = 0.0
        for entry in reversed(self._history):
            if entry.stamp <= self._pose_stamp:
                break
            total += math.hypot(entry.motion[0], entry.motion[1])
        return total
