"""A calibrated ground: the fitted parameters, their uncertainty and the fit's residuals.

:func:`emulator.fit.fit_ground` makes a :class:`Calibration` from recorded missions;
:mod:`emulator.twinfile` writes it into a twin description that the gate loads
(``rover gate --twin FILE``) and reads it back.

The parameters are fitted as natural logarithms (they are positive, and their errors are
relative), so :attr:`Calibration.covariance` is the covariance of ``log(value)``: its
diagonal's square roots are relative 1-sigma errors. :meth:`Calibration.sample` draws
grounds from that (log-normal) distribution with a seeded generator, for playbacks that
carry the calibration's uncertainty into a verdict.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from emulator.ground import REGION_SCALE_MAX, Ground

__all__ = [
    "BAND_LEVEL",
    "FIT_PARAMETERS",
    "STEP_ERROR_SCALE",
    "Calibration",
    "Check",
    "Noise",
    "Residuals",
    "band_half_width",
    "mirrored",
]

BAND_LEVEL = 0.90
"""Probability held by each held-out check's band (:class:`Check`)."""
_Z90 = 1.6448536269514722  # the standard normal's 95th percentile

FIT_PARAMETERS = (
    "mu_longitudinal",
    "mu_lateral",
    "slip_saturation_mps",
    "slip_saturation_ratio",
    "rolling_resistance",
)
"""The ground parameters a calibration fits (plus the scale of each map region the
recordings drove on): every traction parameter of the force model
(:mod:`emulator.traction`). ``slip_saturation_mps``, the slip floor near standstill,
shows in slow steps (speeds 10-25: below about 0.15 m/s it outweighs the slip ratio);
docs/twin.md lists what the twin takes from elsewhere, and why."""
STEP_ERROR_SCALE = 0.5
"""1-sigma of the gate's model discrepancy a calibration states, in units of each plan's
step error (:func:`gate.ensemble.step_error`: the nominal twin's final pose at a finer
step minus at the gate's). The fit, made at the gate's step, absorbs that step's bias
for steps from rest, the only ones it measures; how much of it remains in a plan run
back to back (a step starting while the one before brakes) its data cannot say, so the
scale is estimated once, on development grounds: the maximum-likelihood share under the
gate's own model of a final pose (its twins' spread plus this share of the step error,
normal), over held-out back-to-back plans on the lockstep rover, 0.49 +/- 0.11
(docs/twin.md). It is the lockstep rover's; a real rover's is to be estimated the same
way from its own held-out plans."""


@dataclass(frozen=True)
class Residuals:
    """Root-mean-square disagreement between replayed and recorded steps.

    Attributes:
        forward_m, lateral_m: of the position after each step, in the frame of its
            start pose.
        yaw_deg: of each step's yaw change.
        steps: how many steps.
    """

    forward_m: float
    lateral_m: float
    yaw_deg: float
    steps: int

    @classmethod
    def of(cls, errors: np.ndarray) -> Residuals:
        """From an ``(n, 3)`` array of ``(forward_m, lateral_m, yaw_rad)`` errors."""
        if len(errors) == 0:
            return cls(0.0, 0.0, 0.0, 0)
        rms = np.sqrt(np.mean(np.square(errors), axis=0))
        return cls(float(rms[0]), float(rms[1]), math.degrees(float(rms[2])), len(errors))

    def line(self) -> str:
        """``forward 12.3 mm, lateral 4.5 mm, yaw 0.80 deg (RMS over 14 steps)``."""
        return (
            f"forward {self.forward_m * 1e3:.1f} mm, lateral {self.lateral_m * 1e3:.1f} mm, "
            f"yaw {self.yaw_deg:.2f} deg (RMS over {self.steps} steps)"
        )


@dataclass(frozen=True)
class Noise:
    """What the twin cannot predict, estimated by the calibration from its data.

    Attributes:
        slip_sigma: 1-sigma of the logarithm of each side's friction factor (the gate's
            slip spread, :mod:`gate.ensemble`): the process noise the fit's residuals
            hold beyond their measurement errors, estimated by maximum likelihood.
        pose_sigma_m: 1-sigma error of a position averaged at rest (per axis), m: the
            rover's start pose as the ground station measures it.
        heading_sigma_rad: 1-sigma error of a heading averaged at rest.
    """

    slip_sigma: float
    pose_sigma_m: float
    heading_sigma_rad: float


@dataclass(frozen=True)
class Check:
    """One outcome predicted with its :data:`BAND_LEVEL` band: the calibration's report.
    A step check is one measured step left out of the fit (leave-one-out, linearised);
    a plan check is a whole recorded plan, its steps' predicted moves chained from the
    rest before the first (as it ran: each step from rest), against the rest after its
    last.

    Attributes:
        source, index: the recording and the (first) step's index in it.
        steps: ``(command, speed, distance)`` of each step (one for a step check).
        measured: ``(forward_m, lateral_m, yaw_rad)``: a step's move in its start frame;
            a plan's final pose in the frame of the predicted final pose.
        predicted: the same, by the fit (made without the step, for a step check).
        half_width: of each axis's band around ``predicted`` (parameters, process noise,
            the start's and the measurements' errors).
    """

    source: str
    index: int
    steps: tuple[tuple[int, int, int], ...]
    measured: tuple[float, float, float]
    predicted: tuple[float, float, float]
    half_width: tuple[float, float, float]

    @property
    def inside(self) -> tuple[bool, bool, bool]:
        """Whether each axis's outcome fell inside its band."""
        return tuple(  # type: ignore[return-value]
            abs(m - p) <= h
            for m, p, h in zip(self.measured, self.predicted, self.half_width, strict=True)
        )

    def line(self) -> str:
        """``step 3 FWD 60 23000: forward 0.9912 m in 0.9905 +/- 0.0031 (in), ...``."""
        f = lambda v: f"{v * 1e3:.1f} mm"  # noqa: E731
        d = lambda v: f"{math.degrees(v):.2f} deg"  # noqa: E731
        parts = []
        for name, fmt, m, p, h, ok in zip(
            ("forward", "lateral", "yaw"),
            (f, f, d),
            self.measured,
            self.predicted,
            self.half_width,
            self.inside,
            strict=True,
        ):
            parts.append(f"{name} {fmt(m - p)} off, band +/-{fmt(h)} ({'in' if ok else 'OUT'})")
        where = Path(self.source).name
        if len(self.steps) == 1:
            c, sp, dist = self.steps[0]
            what = f"{where} step {self.index} [{c}, {sp}, {dist}]"
        else:
            what = f"{where} plan of {len(self.steps)} steps"
        return f"{what}: " + "; ".join(parts)


def band_half_width(variance: float) -> float:
    """Half-width of the :data:`BAND_LEVEL` band of a normal with ``variance``."""
    return _Z90 * math.sqrt(max(0.0, variance))


@dataclass(frozen=True)
class Calibration:
    """A ground fitted to recorded missions.

    Attributes:
        ground: the fitted ground (parameters not fitted keep their starting values).
        parameters: the names fitted (``GROUND_PARAMETERS`` names, ``region.ID``).
        covariance: covariance of the natural logarithms of ``parameters``' values
            (rows and columns in ``parameters`` order), already scaled by the fit's
            reduced chi-square when that exceeds 1.
        before, after: residuals of the starting ground (the rover description's)
            and of the fitted one, on the steps fitted.
        reduced_chi2: sum of squared normalised residuals per degree of freedom.
        driving_s: nominal duration of the steps fitted, mission seconds.
        sources: the recordings.
        map_name: the map the steps were replayed on (region scales belong to it).
        dt_s: the twin's step in the fit (the gate's).
        turn_efficiency: the fitted ground's calibration spin (docs/twin.md), for the
            planner's turn model.
        fixed_regions: regions of the map not driven on, kept at the map's scale.
        noise: the process and pose noise estimated from the data (``None``: a twin
            file written before they were).
        targets: each parameter's target relative 1-sigma (``parameters`` order;
            :func:`emulator.design.targets`; a region's is its prior's), or empty.
        checks: the held-out checks (:class:`Check`), each step's in the steps' order,
            then each plan's.
        draws: draws from the fit's posterior, ``log(value)`` of each parameter
            (``parameters`` order): the Gaussian's draws weighed by how well each
            explains the measured steps and resampled (:mod:`emulator.fit`); what
            :meth:`sample` and :meth:`interval` use when present.
        step_error_scale: 1-sigma of the model discrepancy the gate adds to each
            twin's final pose, in units of the plan's step error
            (:data:`STEP_ERROR_SCALE` for a fit; 0, none, for a twin file written
            before it was stated).
    """

    ground: Ground
    parameters: tuple[str, ...]
    covariance: tuple[tuple[float, ...], ...]
    before: Residuals
    after: Residuals
    reduced_chi2: float
    driving_s: float
    sources: tuple[str, ...]
    map_name: str | None
    dt_s: float
    turn_efficiency: float
    fixed_regions: tuple[str, ...] = ()
    noise: Noise | None = None
    targets: tuple[float, ...] = ()
    checks: tuple[Check, ...] = ()
    draws: tuple[tuple[float, ...], ...] = ()
    step_error_scale: float = 0.0

    def value(self, name: str) -> float:
        """A fitted parameter's value (``region.ID`` for a region's scale).

        Raises:
            KeyError: not a fitted parameter.
        """
        if name.startswith("region."):
            scale = self.ground.region_scale(name[len("region.") :])
            if scale is None or name not in self.parameters:
                raise KeyError(name)
            return scale
        if name not in self.parameters:
            raise KeyError(name)
        return float(getattr(self.ground, name))

    def relative_sigma(self, name: str) -> float:
        """1-sigma error of ``log(value)``: the relative error of a fitted parameter.

        Raises:
            KeyError: not a fitted parameter.
        """
        i = self.parameters.index(name) if name in self.parameters else -1
        if i < 0:
            raise KeyError(name)
        return math.sqrt(max(0.0, self.covariance[i][i]))

    def interval(self, name: str, level: float = 0.95) -> tuple[float, float]:
        """The ``level`` interval of a fitted parameter (log-normal: ``value`` times
        ``exp(+/- z sigma)``).

        Raises:
            KeyError: not a fitted parameter.
        """
        z = {0.9: _Z90, 0.95: 1.959963984540054, 0.68: 0.994457883209753}.get(level)
        if z is None:
            raise ValueError(f"level must be 0.68, 0.9 or 0.95, got {level}")
        value, sigma = self.value(name), self.relative_sigma(name)
        if self.draws:
            column = np.exp(np.array(self.draws)[:, self.parameters.index(name)])
            tail = (1.0 - level) / 2.0 * 100.0
            lo, hi = np.percentile(column, [tail, 100.0 - tail])
            return float(lo), float(hi)
        return value * math.exp(-z * sigma), value * math.exp(z * sigma)

    @property
    def start_sigma(self) -> tuple[float, float]:
        """``(position_m, heading_rad)`` 1-sigma of a start pose measured at rest (the
        :class:`Noise`'s; zero without one)."""
        if self.noise is None:
            return 0.0, 0.0
        return self.noise.pose_sigma_m, self.noise.heading_sigma_rad

    def sample(
        self, rng: np.random.Generator | int, n: int, *, antithetic: bool = False
    ) -> list[Ground]:
        """``n`` grounds drawn from the calibration's uncertainty: from its posterior
        :attr:`draws` (with replacement) when it has them, else ``log(values)`` normal
        with :attr:`covariance` around the fitted ones; region scales clipped to the
        map format's ``(0, 2]``.

        Args:
            rng: a numpy generator, or a seed for a new one (same seed, same grounds).
            n: how many (>= 0).
            antithetic: for the normal's draws, in pairs mirrored about the fitted
                values (``+d``, ``-d`` in log space): their spread is then centred on the
                fitted ground. Posterior draws are not mirrored (the posterior need not
                be symmetric: a mirrored draw may be one the steps rule out).
        """
        gen = np.random.default_rng(rng) if isinstance(rng, int) else rng
        if not self.parameters or n <= 0:
            return [self.ground] * max(0, n)
        mean = np.log([self.value(p) for p in self.parameters])
        cov = np.array(self.covariance, dtype=np.float64)
        if self.draws:
            table = np.array(self.draws, dtype=np.float64)
            draws = table[gen.integers(0, len(table), size=n)]
        elif antithetic:
            half = gen.multivariate_normal(
                np.zeros(len(mean)), cov, size=(n + 1) // 2, method="eigh"
            )
            draws = mean + mirrored(half)[:n]
        else:
            draws = gen.multivariate_normal(mean, cov, size=n, method="eigh")
        out = []
        for row in np.exp(draws):
            values = {
                p: min(REGION_SCALE_MAX, float(v)) if p.startswith("region.") else float(v)
                for p, v in zip(self.parameters, row, strict=True)
            }
            out.append(self.ground.with_values(**values))
        return out


def mirrored(half: np.ndarray) -> np.ndarray:
    """Antithetic pairs: the rows of ``half`` interleaved with their negatives
    (``d0, -d0, d1, -d1, ...``), so that any prefix of even length is centred."""
    out = np.empty((2 * len(half), *half.shape[1:]))
    out[0::2] = half
    out[1::2] = -half
    return out
