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

import numpy as np

from emulator.ground import REGION_SCALE_MAX, Ground

__all__ = ["FIT_PARAMETERS", "Calibration", "Residuals"]

FIT_PARAMETERS = ("mu_longitudinal", "mu_lateral", "slip_saturation_ratio", "rolling_resistance")
"""The ground parameters a calibration fits (plus the scale of each map region the
recordings drove on). ``slip_saturation_mps``, the slip floor near standstill, is kept
from the rover description: it only shows below about 0.15 m/s of wheel speed, where a
recording holds too little to tell it from the slip ratio."""


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

    def sample(self, rng: np.random.Generator | int, n: int) -> list[Ground]:
        """``n`` grounds drawn from the calibration's uncertainty: ``log(values)``
        normal with :attr:`covariance` around the fitted ones; region scales clipped to
        the map format's ``(0, 2]``.

        Args:
            rng: a numpy generator, or a seed for a new one (same seed, same grounds).
            n: how many (>= 0).
        """
        gen = np.random.default_rng(rng) if isinstance(rng, int) else rng
        if not self.parameters or n <= 0:
            return [self.ground] * max(0, n)
        mean = np.log([self.value(p) for p in self.parameters])
        cov = np.array(self.covariance, dtype=np.float64)
        draws = gen.multivariate_normal(mean, cov, size=n, method="eigh")
        out = []
        for row in np.exp(draws):
            values = {
                p: min(REGION_SCALE_MAX, float(v)) if p.startswith("region.") else float(v)
                for p, v in zip(self.parameters, row, strict=True)
            }
            out.append(self.ground.with_values(**values))
        return out
