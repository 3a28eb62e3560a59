"""Fitting the twin's ground to measured steps: ``scipy.optimize.least_squares``.

Each measured step (:class:`~emulator.observations.StepObservation`) is replayed on the
twin from its recorded start pose, at rest, with the candidate ground: its command
played as the controller plays it, then :data:`SETTLE_S` with the wheels stopped
(:func:`emulator.moves.play_moves`: every step, and every ground a Jacobian needs, in
one replay batch). Three residuals per step compare the twin's move with the recorded
one: the position after the step in the frame of its start pose (forward, lateral; the
POSE averaged at rest) and the yaw change (the gyro's), whitened by the step's error
covariance (:meth:`~emulator.observations.StepObservation.covariance`: the positions',
the yaw change's and the start heading's). The parameters (:data:`~emulator.
calibration.FIT_PARAMETERS`, every traction parameter of the force model, and the
friction scale of each map region the steps drove on) are fitted as logarithms within
:data:`BOUNDS`, with a trust-region reflective solver.

Each parameter has a weak prior: normal in ``log(value)`` around the rover description's
value with :data:`PRIOR_SIGMA` (a factor of two at one sigma), appended as one residual
per parameter, so that a parameter the steps say little about stays near the
description instead of wandering to a bound.

Outliers: a step still more than :data:`OUTLIER_SIGMA` errors off after the fit (an
injected fault, a bump into something) is found with a robust (soft-L1) fit, left out
and listed, and the plain fit runs on the rest.

**Noise** (:class:`~emulator.calibration.Noise`). The residuals hold what the
measurements' errors explain and what the twin cannot predict: process noise, modelled
as the gate models it, a friction factor per side, log-normal with ``slip_sigma``. Its
sensitivities ``G`` (per step, by each side's log factor) come with the last Jacobian;
``slip_sigma`` is the maximum-likelihood value of the residuals under ``C_i = M_i +
slip_sigma^2 G_i G_i^T`` (``M_i`` the measurement's covariance); the fit then runs once
more weighted by ``C_i``. The start pose's noise (a position and heading averaged at
rest) is what the rests measured. The share of the gate's step error (a plan's final
pose at a finer step than the gate's, less at the gate's) is not estimated here: the
steps, all from rest, cannot show what of it remains in a plan run back to back; it was
estimated once, on development grounds (:data:`~emulator.calibration.STEP_ERROR_SCALE`).

**Uncertainty**: the covariance of the log-parameters is ``s^2 (J^T J + P)^-1`` at the
solution, ``J`` the Jacobian of the whitened residuals, ``P`` the priors' precision and
``s^2`` the reduced chi-square when it exceeds 1 (a misfit the noise terms do not
explain widens it). That Gaussian is the design's and the refusals' (linearised);
what the gate samples grounds from is the posterior itself, drawn by
sampling-importance-resampling around it (:func:`_posterior`): a draw the measured steps
rule out is not kept, however far the Gaussian's tails reach. **Checks**: each step left
out in turn, linearised (the fit's hat matrix), predicted with its 90 % band
(parameters, process noise, its measurement errors): the report
(:class:`~emulator.calibration.Check`).

**Refusals** (:class:`~emulator.errors.UnidentifiableError`), never guesses: before
fitting, steps without a turn measured, without a straight step, or too few
(:data:`MIN_STEPS`, :data:`MIN_DRIVING_S`); after fitting, a region barely driven on, or
a covariance that leaves a probe (:func:`emulator.design.probes`: the steps plans are
made of) uncertain by more than :data:`REFUSE_FACTOR` times its bar. The message names
the parameter that weighs most in that spread and the steps that would fix it
(:func:`emulator.design.advice`), which the error carries (``advice``).

Deterministic: the twin is, and the solver has no randomness.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from emulator import design
from emulator.batch import BatchDraw
from emulator.calibration import (
    FIT_PARAMETERS,
    STEP_ERROR_SCALE,
    Calibration,
    Check,
    Noise,
    Residuals,
    band_half_width,
    mirrored,
)
from emulator.errors import CalibrationError, RecordingError, UnidentifiableError
from emulator.ground import Ground
from emulator.moves import MoveJob, play_moves
from emulator.observations import ObservedSteps, StepObservation
from emulator.playback import measure_turn_efficiency
from emulator.twin import GATE_DT_S, Pose2D
from firmware_proto.model.geometry import wrap_rad
from firmware_proto.model.rover import RoverDescription
from firmware_proto.model.worldmap import WorldMap
from firmware_proto.wire.messages import Command

__all__ = [
    "BOUNDS",
    "MIN_DRIVING_S",
    "MIN_STEPS",
    "OUTLIER_SIGMA",
    "PRIOR_SIGMA",
    "REFUSE_FACTOR",
    "SETTLE_S",
    "UNINFORMED_RATIO",
    "FitReport",
    "fit_ground",
    "predict_moves",
]

logger = logging.getLogger(__name__)

SETTLE_S = design.SETTLE_S
"""Twin time played with the wheels stopped after each replayed step, s."""

MIN_STEPS = 6
"""Fewer measured steps than this is too short to fit."""

MIN_DRIVING_S = 15.0
"""Less driving than this (nominal step durations, s) is too short to fit."""

PRIOR_SIGMA = math.log(2.0)
"""1-sigma of each parameter's prior, in ``log(value)``: a factor of two."""

OUTLIER_SIGMA = 20.0
"""A step whose residual (in its own errors) is still above this after the fit is left
out: no ground the twin can model explains it."""

OUTLIER_F_SCALE = 3.0
"""Where the robust fit's soft-L1 loss turns from quadratic to linear, in sigmas."""

UNINFORMED_RATIO = 0.9
"""A region scale whose fitted 1-sigma error is above this fraction of its prior's was
not informed by the steps."""

REFUSE_FACTOR = 5.0
"""A fit that leaves a probe more than this many times its bar uncertain
(:data:`emulator.design.PROBE_POSITION_M`, :data:`~emulator.design.PROBE_YAW_RAD`: 1 cm
and 0.25 degree at one sigma) is refused."""

BOUNDS: dict[str, tuple[float, float]] = {
    "mu_longitudinal": (0.05, 3.0),
    "mu_lateral": (0.02, 5.0),
    "slip_saturation_mps": (1e-4, 0.05),
    "slip_saturation_ratio": (0.001, 0.5),
    "rolling_resistance": (0.001, 0.5),
    "region": (0.02, 2.0),
}
"""Where each parameter is searched (``region`` for every region scale)."""

POSTERIOR_PROPOSALS = 256
"""Proposals of the posterior's sampling-importance-resampling."""
POSTERIOR_DRAWS = 100
"""Draws kept from the posterior (what the gate samples grounds from)."""
PROPOSAL_SCALE = 1.5
"""The proposal's spread over the Gaussian's: wider, so it covers the posterior."""
POSTERIOR_SEED = 44
"""Seed of the posterior's draws (a calibration is deterministic)."""

_TOLERANCE = 1e-6
"""The solver's ``ftol`` and ``xtol``: a thousandth of the smallest uncertainty a fit
reaches."""


@dataclass(frozen=True)
class FitReport:
    """How the fit went, beside its :class:`Calibration`.

    Attributes:
        evaluations: replay batches (each replays every step on every ground a
            Jacobian needs).
        wall_s: time the fit took (wall clock), s.
        status: the solver's message.
        outliers: steps the robust fit found off every ground it can fit.
    """

    evaluations: int
    wall_s: float
    status: str
    outliers: tuple[tuple[str, int, str], ...] = ()
    """Steps left out as outliers: ``(source, step index, why)``."""


class _Replays:
    """The measured steps replayed on any grounds, one batch per call. On a map without
    traction regions a step's move does not depend on where it starts, so each
    distinct step is replayed once, from the origin."""

    def __init__(
        self,
        observations: Sequence[StepObservation],
        rover: RoverDescription,
        world: WorldMap | None,
        dt_s: float,
    ) -> None:
        self.rover = rover
        self.world = world
        self.dt_s = dt_s
        self.batches = 0
        self.invariant = world is None or not world.traction_regions
        self.set(observations)

    def set(self, observations: Sequence[StepObservation]) -> None:
        """Replay these observations from now on."""
        self.observations = list(observations)
        steps = sorted({o.step for o in self.observations})
        self._unique = steps
        index = {s: i for i, s in enumerate(steps)}
        self._of = np.array([index[o.step] for o in self.observations], dtype=np.int64)

    def moves(self, draws: Sequence[BatchDraw]) -> np.ndarray:
        """``(len(draws), n, 3)``: each observation's move (start frame) on each draw."""
        self.batches += 1
        obs = self.observations
        if self.invariant:
            origin = Pose2D(0.0, 0.0, 0.0)
            jobs = [MoveJob(origin, (s,), d) for d in draws for s in self._unique]
            ends = play_moves(self.rover, None, jobs, dt_s=self.dt_s, settle_s=SETTLE_S)
            table = ends.reshape(len(draws), len(self._unique), 3)
            return np.asarray(table[:, self._of, :])
        jobs = [MoveJob(o.start, (o.step,), d) for d in draws for o in obs]
        ends = play_moves(self.rover, self.world, jobs, dt_s=self.dt_s, settle_s=SETTLE_S)
        ends = ends.reshape(len(draws), len(obs), 3)
        start = np.array([(o.start.x_m, o.start.y_m, o.start.yaw_rad) for o in obs])
        dx = ends[..., 0] - start[:, 0]
        dy = ends[..., 1] - start[:, 1]
        c, s = np.cos(start[:, 2]), np.sin(start[:, 2])
        return np.stack((c * dx + s * dy, -s * dx + c * dy, ends[..., 2] - start[:, 2]), axis=-1)


def predict_moves(
    observations: Sequence[StepObservation],
    rover: RoverDescription,
    world: WorldMap | None,
    ground: Ground,
    *,
    dt_s: float = GATE_DT_S,
) -> np.ndarray:
    """Each step replayed on a twin on ``ground`` from its recorded start pose: an
    ``(n, 3)`` array of ``(forward_m, left_m, yaw_rad)`` moves in the start frame."""
    moves: np.ndarray = _Replays(observations, rover, world, dt_s).moves([BatchDraw(ground)])[0]
    return moves


def _structure(observed: ObservedSteps) -> None:
    """Refuse recordings that cannot identify the parameters, before any fitting."""
    obs = observed.observations
    if not obs:
        reasons = "; ".join(f"step {i}: {why}" for _, i, why in observed.skipped[:3])
        raise RecordingError(
            "no step could be measured at rest before and after it"
            + (f" ({reasons})" if reasons else " (no completed step)")
        )
    turns = sum(o.command in (Command.LEFT, Command.RIGHT) for o in obs)
    straights = len(obs) - turns
    if turns == 0:
        raise UnidentifiableError(
            "cannot identify mu_lateral: the recordings have no turn on the spot (LEFT or "
            "RIGHT) measured at rest; drive turns both ways, e.g. LEFT and RIGHT at speed "
            "25 by about 90 degrees",
            "mu_lateral",
        )
    if straights == 0:
        raise UnidentifiableError(
            "cannot identify rolling_resistance, slip_saturation_ratio and "
            "slip_saturation_mps: the recordings have no straight step (FWD or REV) "
            "measured at rest; drive straight steps at low and high speed, e.g. FWD at "
            "speed 10 and at speed 60 over 1 m",
            "rolling_resistance",
        )
    if len(obs) < MIN_STEPS or observed.driving_s < MIN_DRIVING_S:
        raise UnidentifiableError(
            f"too short to fit: {len(obs)} steps, {observed.driving_s:.1f} s of driving "
            f"measured at rest; need at least {MIN_STEPS} steps and {MIN_DRIVING_S:g} s"
        )


def _bounds(names: list[str]) -> tuple[np.ndarray, np.ndarray]:
    lo, hi = [], []
    for name in names:
        a, b = BOUNDS["region" if name.startswith("region.") else name]
        lo.append(math.log(a))
        hi.append(math.log(b))
    return np.array(lo), np.array(hi)


def _value(ground: Ground, name: str) -> float:
    if name.startswith("region."):
        return ground.region_scale(name[len("region.") :]) or 1.0
    return float(getattr(ground, name))


def _whitener(covariances: np.ndarray) -> np.ndarray:
    """``L_i^-1`` of each ``(3, 3)`` covariance's Cholesky factor ``L_i``."""
    chol = np.linalg.cholesky(covariances)
    return np.asarray(np.linalg.inv(chol))


class _Problem:
    """The least-squares problem: whitened residuals and priors, and their Jacobian by
    forward differences, from one replay batch per point (the last one is kept, so the
    solver's Jacobian at a point it has just evaluated costs nothing)."""

    def __init__(
        self,
        replays: _Replays,
        base: Ground,
        names: list[str],
        prior: np.ndarray,
        measured: np.ndarray,
        whiten: np.ndarray,
    ) -> None:
        self.replays = replays
        self.base = base
        self.names = names
        self.prior = prior
        self.measured = measured
        self.whiten = whiten
        self._key: bytes | None = None
        self._value: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

    def ground(self, x: np.ndarray) -> Ground:
        return self.base.with_values(**{n: math.exp(v) for n, v in zip(self.names, x, strict=True)})

    def evaluate(self, x: np.ndarray, *, sides: bool = False) -> tuple[np.ndarray, ...]:
        """``(f, J, moves, J_moves, G)`` at ``x``: whitened residuals with the priors'
        rows, their Jacobian, the raw moves ``(n, 3)``, their Jacobian ``(n, 3, p)``,
        and with ``sides`` their sensitivity to each side's log friction ``(n, 3, 2)``."""
        key = x.tobytes() + bytes([sides])
        if self._key == key and self._value is not None:
            return self._value
        h = design.DIFF_STEP
        draws = [BatchDraw(self.ground(x))]
        for j in range(len(x)):
            step = x.copy()
            step[j] += h
            draws.append(BatchDraw(self.ground(step)))
        if sides:
            factor = math.exp(h)
            draws += [
                BatchDraw(draws[0].ground, factor, 1.0),
                BatchDraw(draws[0].ground, 1.0, factor),
            ]
        table = self.replays.moves(draws)
        p = len(x)
        moves = table[0]
        jac_moves = np.transpose((table[1 : 1 + p] - moves) / h, (1, 2, 0))
        side = np.transpose((table[1 + p :] - moves) / h, (1, 2, 0)) if sides else None
        r = np.einsum("nab,nb->na", self.whiten, moves - self.measured).ravel()
        jw = np.einsum("nab,nbp->nap", self.whiten, jac_moves).reshape(-1, p)
        f = np.concatenate((r, (x - self.prior) / PRIOR_SIGMA))
        jac = np.vstack((jw, np.eye(p) / PRIOR_SIGMA))
        value = (f, jac, moves, jac_moves, side)
        self._key, self._value = key, value  # type: ignore[assignment]
        return value  # type: ignore[return-value]

    def solve(self, x0: np.ndarray, loss: str, max_nfev: int) -> Any:
        from scipy.optimize import least_squares  # noqa: PLC0415 - only a fit needs it

        lo, hi = _bounds(self.names)
        return least_squares(
            lambda x: self.evaluate(x)[0],
            np.clip(x0, lo + 1e-9, hi - 1e-9),
            jac=lambda x: self.evaluate(x)[1],
            bounds=(lo, hi),
            method="trf",
            loss=loss,
            f_scale=OUTLIER_F_SCALE,
            x_scale="jac",
            ftol=_TOLERANCE,
            xtol=_TOLERANCE,
            max_nfev=max_nfev,
        )


def _slip_sigma(residuals: np.ndarray, measurement: np.ndarray, side: np.ndarray) -> float:
    """The maximum-likelihood slip spread of ``residuals`` ``(n, 3)`` under
    ``M_i + s^2 G_i G_i^T`` (see the module docstring); 0 when the measurements explain
    them."""
    from scipy.optimize import minimize_scalar  # noqa: PLC0415 - only a fit needs it

    gg = np.einsum("nap,nbp->nab", side, side)

    def nll(s: float) -> float:
        cov = measurement + (s * s) * gg
        _sign, logdet = np.linalg.slogdet(cov)
        quad = np.einsum("na,na->n", residuals, np.linalg.solve(cov, residuals[..., None])[..., 0])
        return float(np.sum(logdet) + np.sum(quad))

    best = minimize_scalar(nll, bounds=(0.0, 1.0), method="bounded", options={"xatol": 1e-5})
    s = float(best.x)
    return s if nll(s) < nll(0.0) else 0.0


def fit_ground(
    observed: ObservedSteps,
    rover: RoverDescription,
    world: WorldMap | None,
    *,
    start: Ground | None = None,
    dt_s: float = GATE_DT_S,
    sources: tuple[str, ...] = (),
    max_evaluations: int = 100,
    refuse: bool = True,
    posterior: bool = True,
) -> tuple[Calibration, FitReport]:
    """Fit the ground to measured steps (module docstring).

    Args:
        observed: the measured steps (:func:`emulator.observations.observe_steps`).
        rover: the rover description (its traction is the prior).
        world: the map the steps were driven on (its regions; ``None``: open plane).
        start: where the solver starts (default: the description's ground, with the
            map's region scales); the priors stay the description's.
        dt_s: the twin's step (default the gate's, so the fit is what the gate plays).
        sources: the recordings' names, for the report.
        max_evaluations: the solver's budget of evaluations per pass.
        refuse: raise for a covariance that leaves a probe too uncertain (``False``:
            return the fit, as a designed calibration does between its rounds; the
            structural refusals stay).
        posterior: draw from the posterior (:func:`_posterior`; ``False``: the
            calibration has no draws, as a designed calibration's fits between rounds).

    Raises:
        RecordingError: no step could be measured.
        UnidentifiableError: a parameter cannot be identified (module docstring).
        CalibrationError: scipy is not installed.
    """
    try:
        import scipy.optimize  # noqa: F401, PLC0415 - only a fit needs it
    except ImportError as exc:
        raise CalibrationError("rover calibrate needs scipy: install rover-hil[calibrate]") from exc
    t0 = time.perf_counter()
    _structure(observed)
    obs = list(observed.observations)
    described = Ground.of_rover(rover, world)
    base = start if start is not None else described
    replays = _Replays(obs, rover, world, dt_s)

    names = list(FIT_PARAMETERS)
    fixed_regions: list[str] = []
    if base.regions:
        probes = [BatchDraw(base)]
        probes += [
            BatchDraw(base.with_values(**{f"region.{rid}": s * 0.5})) for rid, s in base.regions
        ]
        moved = replays.moves(probes)
        for k, (rid, _scale) in enumerate(base.regions):
            if np.any(np.abs(moved[k + 1] - moved[0]) > 1e-9):
                names.append(f"region.{rid}")
            else:
                fixed_regions.append(rid)
    lo, hi = _bounds(names)
    prior = np.clip(np.log([_value(described, n) for n in names]), lo + 1e-9, hi - 1e-9)
    x0 = np.clip(np.log([_value(base, n) for n in names]), lo + 1e-9, hi - 1e-9)

    def problem_for(steps: list[StepObservation], covariances: np.ndarray) -> _Problem:
        measured = np.array([o.displacement() for o in steps])
        return _Problem(replays, base, names, prior, measured, _whitener(covariances))

    measurement = np.array([o.covariance() for o in obs])
    problem = problem_for(obs, measurement)
    result = problem.solve(x0, "linear", max_evaluations)
    outliers: tuple[tuple[str, int, str], ...] = ()
    worst = np.max(np.abs(problem.evaluate(result.x)[0][: 3 * len(obs)].reshape(-1, 3)), axis=1)
    if np.any(worst > OUTLIER_SIGMA):
        # A step the twin cannot explain on any ground (a fault injected, a bump into
        # something) pulls a plain fit toward it: find it with a robust loss.
        robust = problem.solve(x0, "soft_l1", max_evaluations)
        worst = np.max(np.abs(problem.evaluate(robust.x)[0][: 3 * len(obs)].reshape(-1, 3)), axis=1)
        outliers = tuple(
            (o.source, o.index, f"off every ground the twin fits: {w:.0f} sigma after the fit")
            for o, w in zip(obs, worst, strict=True)
            if w > OUTLIER_SIGMA
        )
        keep = worst <= OUTLIER_SIGMA
        obs = [o for o, k in zip(obs, keep, strict=True) if k]
        measurement = measurement[keep]
        observed = ObservedSteps(
            tuple(obs),
            observed.skipped + outliers,
            sum(rover.step_duration_s(o.speed, o.distance) for o in obs),
        )
        for source, index, why in outliers:
            logger.info("%s step %d left out: %s", source, index, why)
        _structure(observed)
        replays.set(obs)
        problem = problem_for(obs, measurement)
        result = problem.solve(robust.x, "linear", max_evaluations)

    # The process noise the residuals hold beyond the measurements', then the fit once
    # more with it in the weights.
    _f, _j, moves, _jm, side = problem.evaluate(result.x, sides=True)
    measured = problem.measured
    slip = _slip_sigma(moves - measured, measurement, side)
    total = measurement + slip * slip * np.einsum("nap,nbp->nab", side, side)
    if slip > 0.0:
        problem = problem_for(obs, total)
        result = problem.solve(result.x, "linear", max_evaluations)
    f, jac, moves, jac_moves, side = problem.evaluate(result.x, sides=True)
    p = len(names)
    data = f[: 3 * len(obs)]
    chi2 = float(np.sum(data * data) / max(1, data.size - p))
    covariance = _covariance(jac, max(1.0, chi2), names)
    fitted = replace(problem.ground(result.x), name="calibrated")
    noise = Noise(
        slip_sigma=slip,
        pose_sigma_m=float(np.median([o.sigma_xy_m for o in obs])) / math.sqrt(2.0),
        heading_sigma_rad=float(np.median([o.sigma_heading_rad for o in obs])),
    )
    checks = _checks(obs, measured, moves, jac, total, covariance)
    plans = _plans(obs, moves, jac_moves, side, covariance, noise)
    plan_slip = _slip_sigma(
        np.array([pl.residual for pl in plans]).reshape(-1, 3),
        np.array([pl.fixed for pl in plans]).reshape(-1, 3, 3),
        np.array([pl.side for pl in plans]).reshape(-1, 3, 2),
    )
    if plan_slip > slip:
        # A bias too small to see in one step adds up over a plan's; the gate draws one
        # friction factor per side for a whole plan, so its slip spread is the plans'.
        noise = replace(noise, slip_sigma=plan_slip)
        logger.info(
            "slip spread %.4f from %d plans (%.4f from the steps)", plan_slip, len(plans), slip
        )
    checks += tuple(pl.check(noise.slip_sigma) for pl in plans)
    draws: tuple[tuple[float, ...], ...] = ()
    if posterior:
        draws, ess = _posterior(problem, result.x, covariance, max(1.0, chi2))
        logger.info("posterior: %d draws resampled, effective sample size %.0f", len(draws), ess)
    targets = _refuse_uninformed(
        names, covariance, fitted, rover, observed, noise, dt_s, refuse=refuse
    )
    before = Residuals.of(replays.moves([BatchDraw(described)])[0] - measured)
    after = Residuals.of(moves - measured)
    efficiency = measure_turn_efficiency(
        fitted.rover(rover), distance=rover.turn_units_for_yaw(math.pi / 2.0)
    )
    calibration = Calibration(
        ground=fitted,
        parameters=tuple(names),
        covariance=tuple(tuple(float(v) for v in row) for row in covariance),
        before=before,
        after=after,
        reduced_chi2=chi2,
        driving_s=observed.driving_s,
        sources=sources,
        map_name=world.name if world is not None else None,
        dt_s=dt_s,
        turn_efficiency=efficiency,
        fixed_regions=tuple(fixed_regions),
        noise=noise,
        targets=targets,
        checks=checks,
        draws=draws,
        step_error_scale=STEP_ERROR_SCALE,
    )
    report = FitReport(replays.batches, time.perf_counter() - t0, str(result.message), outliers)
    logger.info(
        "fit: %s after %d replay batches in %.1f s; %s; slip_sigma %.4f",
        ", ".join(f"{n}={calibration.value(n):.4g}" for n in names),
        report.evaluations,
        report.wall_s,
        after.line(),
        slip,
    )
    return calibration, report


def _posterior(
    problem: _Problem, x_hat: np.ndarray, covariance: np.ndarray, temper: float
) -> tuple[tuple[tuple[float, ...], ...], float]:
    """Draws from the fit's posterior by sampling-importance-resampling: proposals from
    the Gaussian (its covariance widened by :data:`PROPOSAL_SCALE`, antithetic pairs,
    seeded), each replayed on every measured step in one batch and weighed by its
    likelihood (the whitened residuals, tempered by the reduced chi-square when above
    1) times its prior over its proposal density; :data:`POSTERIOR_DRAWS` resampled
    systematically. Where the Gaussian is poor (the slip ratio, the slip floor and the
    rolling resistance trade off along a curved valley, and a straight-line draw far
    along it predicts what the steps rule out) the weights say so. With few effective
    draws the proposal is fitted to the weighted ones and drawn once more.

    Returns:
        The draws (log-values, ``problem.names`` order) and the effective sample size
        of the last weighing.
    """
    rng = np.random.default_rng(POSTERIOR_SEED)
    lo, hi = _bounds(problem.names)
    mean, cov = x_hat, covariance * PROPOSAL_SCALE**2
    ess = 0.0
    weights = np.ones(1)
    points = x_hat[None, :]
    for _attempt in range(2):
        half = rng.multivariate_normal(np.zeros(len(mean)), cov, size=POSTERIOR_PROPOSALS // 2)
        points = np.clip(mean + mirrored(half), lo, hi)
        table = problem.replays.moves([BatchDraw(problem.ground(x)) for x in points])
        white = np.einsum("nab,knb->kna", problem.whiten, table - problem.measured)
        loglik = -0.5 * np.sum(white * white, axis=(1, 2)) / temper
        logprior = -0.5 * np.sum(((points - problem.prior) / PRIOR_SIGMA) ** 2, axis=1)
        delta = points - mean
        logq = -0.5 * np.einsum("ka,ab,kb->k", delta, np.linalg.inv(cov), delta)
        logw = loglik + logprior - logq
        weights = np.exp(logw - np.max(logw))
        weights /= np.sum(weights)
        ess = float(1.0 / np.sum(weights * weights))
        if ess >= POSTERIOR_PROPOSALS / 10:
            break
        mean = np.sum(weights[:, None] * points, axis=0)
        centred = points - mean
        cov = (weights[:, None] * centred).T @ centred * PROPOSAL_SCALE**2
        cov += np.eye(len(mean)) * 1e-10
    positions = (rng.random() + np.arange(POSTERIOR_DRAWS)) / POSTERIOR_DRAWS
    chosen = np.minimum(np.searchsorted(np.cumsum(weights), positions), len(points) - 1)
    rows = tuple(tuple(float(v) for v in points[i]) for i in chosen)
    return rows, ess


@dataclass(frozen=True)
class _Plan:
    """A recorded plan, every step of it measured: its prediction's residual and the
    parts of its spread (see :func:`_plans`)."""

    source: str
    index: int
    steps: tuple[tuple[int, int, int], ...]
    residual: np.ndarray  # (3,) measured minus predicted, in the predicted final frame
    fixed: np.ndarray  # (3, 3) parameters, start and end measurement
    side: np.ndarray  # (3, 2) per log side factor

    def check(self, slip_sigma: float) -> Check:
        cov = self.fixed + slip_sigma**2 * self.side @ self.side.T
        return Check(
            source=self.source,
            index=self.index,
            steps=self.steps,
            measured=tuple(float(v) for v in self.residual),  # type: ignore[arg-type]
            predicted=(0.0, 0.0, 0.0),
            half_width=tuple(band_half_width(float(cov[a, a])) for a in range(3)),  # type: ignore[arg-type]
        )


def _compose(start: Pose2D, moves: np.ndarray) -> Pose2D:
    """``start`` moved by each ``(forward, left, yaw)`` move in turn, each in the frame
    of the pose before it."""
    x, y, yaw = start.x_m, start.y_m, start.yaw_rad
    for f, left, dyaw in moves:
        c, s = math.cos(yaw), math.sin(yaw)
        x, y, yaw = x + c * f - s * left, y + s * f + c * left, yaw + dyaw
    return Pose2D(x, y, yaw)


def _plans(
    obs: list[StepObservation],
    moves: np.ndarray,
    jac_moves: np.ndarray,
    side: np.ndarray,
    covariance: np.ndarray,
    noise: Noise,
) -> list[_Plan]:
    """Each recording whose steps (two or more) were all measured, one after the other:
    the fit's moves of its steps chained from the rest before the first (as the plan
    ran, each step from rest), against the rest after the last (its heading the start's
    plus the gyro's yaw changes). What the steps alone cannot show, a plan does: a bias
    too small to see in one step adds up over the steps of a plan. Its spread: the
    parameters' covariance carried through the chain, the start's noise
    (:class:`Noise`), the end's measurement, and each side's friction factor shared by
    every step of the plan (the gate draws one per side per plan)."""
    index = {id(o): i for i, o in enumerate(obs)}
    by_source: dict[str, list[StepObservation]] = {}
    for o in obs:
        by_source.setdefault(o.source, []).append(o)
    out: list[_Plan] = []
    h = design.DIFF_STEP
    for source, group in by_source.items():
        group.sort(key=lambda o: o.index)
        if len(group) < 2 or group[-1].index - group[0].index != len(group) - 1:
            continue
        rows = [index[id(o)] for o in group]
        chain = moves[rows]
        start, last = group[0].start, group[-1]
        nominal = _compose(start, chain)
        # How the final pose (in its own frame) follows each step's move.
        through = np.zeros((len(rows), 3, 3))
        for k in range(len(rows)):
            for a in range(3):
                moved = chain.copy()
                moved[k, a] += h
                through[k, :, a] = np.array(_in_frame(_compose(start, moved), nominal)) / h
        jac = np.einsum("kab,kbp->ap", through, jac_moves[rows])
        coherent = np.einsum("kab,kbp->ap", through, side[rows])
        jstart = np.zeros((3, 3))
        for a, offset in enumerate(((h, 0.0, 0.0), (0.0, h, 0.0), (0.0, 0.0, h))):
            shifted = Pose2D(
                start.x_m + offset[0], start.y_m + offset[1], start.yaw_rad + offset[2]
            )
            jstart[:, a] = np.array(_in_frame(_compose(shifted, chain), nominal)) / h
        # The end's heading is the start's plus the gyro's yaw changes, so the start
        # heading's error turns the prediction and the measurement alike: it leaves the
        # yaw, and moves only the predicted position.
        jstart[2, :] = 0.0
        measured_yaw = start.yaw_rad + sum(o.yaw_change_rad for o in group)
        end = Pose2D(last.end.x_m, last.end.y_m, measured_yaw)
        residual = np.array(_in_frame(end, nominal))
        start_cov = np.diag([noise.pose_sigma_m**2] * 2 + [noise.heading_sigma_rad**2])
        yaw_var = sum(o.sigma_yaw_rad**2 for o in group)
        end_cov = np.diag([last.sigma_xy_m**2 / 2.0] * 2 + [yaw_var])
        fixed = jac @ covariance @ jac.T + jstart @ start_cov @ jstart.T + end_cov
        out.append(
            _Plan(source, group[0].index, tuple(o.step for o in group), residual, fixed, coherent)
        )
    return out


def _in_frame(pose: Pose2D, origin: Pose2D) -> tuple[float, float, float]:
    """``pose`` in ``origin``'s frame: along, across (m), yaw difference (rad, wrapped)."""
    dx, dy = pose.x_m - origin.x_m, pose.y_m - origin.y_m
    c, s = math.cos(origin.yaw_rad), math.sin(origin.yaw_rad)
    return c * dx + s * dy, -s * dx + c * dy, wrap_rad(pose.yaw_rad - origin.yaw_rad)


def _checks(
    obs: list[StepObservation],
    measured: np.ndarray,
    moves: np.ndarray,
    jac_whitened: np.ndarray,
    total: np.ndarray,
    covariance: np.ndarray,
) -> tuple[Check, ...]:
    """Each step left out of the fit in turn, linearised: its prediction error
    ``(I - H_ii)^-1 r_i`` in whitened units (``H`` the hat matrix of the whitened
    Jacobian with the priors), its variance ``(I - H_ii)^-1``, back in metres and
    radians through the step's noise factor."""
    n = len(obs)
    jw = jac_whitened[: 3 * n].reshape(n, 3, -1)
    chol = np.linalg.cholesky(total)
    out = []
    for i, o in enumerate(obs):
        h = jw[i] @ covariance @ jw[i].T
        keep = np.linalg.inv(np.eye(3) - h)
        white = np.linalg.solve(chol[i], moves[i] - measured[i])
        error = chol[i] @ (keep @ white)  # left-out prediction minus measurement
        band = chol[i] @ keep @ chol[i].T
        out.append(
            Check(
                source=o.source,
                index=o.index,
                steps=(o.step,),
                measured=tuple(float(v) for v in measured[i]),  # type: ignore[arg-type]
                predicted=tuple(float(v) for v in measured[i] + error),  # type: ignore[arg-type]
                half_width=tuple(band_half_width(float(band[a, a])) for a in range(3)),  # type: ignore[arg-type]
            )
        )
    return tuple(out)


def _design_noise(
    obs: Sequence[StepObservation], moves: np.ndarray, side: np.ndarray, noise: Noise
) -> np.ndarray:
    """``(k, 3, 3)``: the noise of steps with ``moves`` and side sensitivities ``side``
    measured as the calibration's steps were (their median errors)."""
    return design.step_noise(
        moves,
        side,
        sigma_xy_m=float(np.median([o.sigma_xy_m for o in obs])),
        sigma_yaw_rad=float(np.median([o.sigma_yaw_rad for o in obs])),
        sigma_heading_rad=noise.heading_sigma_rad,
        slip_sigma=noise.slip_sigma,
    )


def _refuse_uninformed(
    names: list[str],
    covariance: np.ndarray,
    fitted: Ground,
    rover: RoverDescription,
    observed: ObservedSteps,
    noise: Noise,
    dt_s: float,
    *,
    refuse: bool = True,
) -> tuple[float, ...]:
    """Raise for a region the steps did not inform, or for a covariance that leaves a
    probe too uncertain (module docstring; not without ``refuse``); return each
    parameter's target 1-sigma."""
    for i, name in enumerate(names):
        sigma = math.sqrt(max(0.0, covariance[i, i]))
        if refuse and name.startswith("region.") and sigma > UNINFORMED_RATIO * PRIOR_SIGMA:
            raise UnidentifiableError(
                f"cannot identify the friction of region {name[len('region.') :]}: the "
                f"recordings drove too little on it (+/-{sigma * 100:.0f}% at 1 sigma); "
                "drive more steps inside it",
                name,
            )
    ground_names = [n for n in names if not n.startswith("region.")]
    index = [names.index(n) for n in ground_names]
    cov = covariance[np.ix_(index, index)]
    probes = design.probes(rover)
    _moves, probe_jac, _ = design.sensitivities(rover, fitted, ground_names, probes, dt_s=dt_s)
    goals = design.targets(probe_jac, cov)
    targets = [
        float(goals[ground_names.index(n)]) if n in ground_names else PRIOR_SIGMA for n in names
    ]
    spread = design.probe_spread(probe_jac, cov)
    excess = design.excess(spread)
    worst = int(np.argmax(excess))
    if excess[worst] <= REFUSE_FACTOR or not refuse:
        return tuple(targets)
    # The parameter whose uncertainty weighs most in the worst probe's spread: the one
    # that, known, would shrink it most.
    name = ground_names[int(np.argmax(design.shares(probe_jac[worst : worst + 1], cov)))]
    candidates = design.candidates(rover)
    cand_moves, cand_jac, cand_side = design.sensitivities(
        rover, fitted, ground_names, candidates, dt_s=dt_s, sides=True
    )
    assert cand_side is not None
    cand_noise = _design_noise(observed.observations, cand_moves, cand_side, noise)
    durations = np.array([rover.step_duration_s(s, d) for _c, s, d in candidates])
    precision = np.linalg.inv(cov)
    # Enough to bring every probe under the refusal's bar, not the stricter target's.
    scaled = probe_jac / REFUSE_FACTOR
    chosen = design.advice(precision, scaled, cand_jac, cand_noise, durations)
    advised = tuple(candidates[i] for i in chosen)
    counts: dict[tuple[int, int, int], int] = {}
    for step in advised:
        counts[step] = counts.get(step, 0) + 1
    what = ", ".join(
        design.describe_step(rover, step) + (f" (x{k})" if k > 1 else "")
        for step, k in counts.items()
    )
    probe = design.describe_step(rover, probes[worst])
    position = math.hypot(spread[worst, 0], spread[worst, 1])
    by = (
        f"{math.degrees(spread[worst, 2]):.2f} deg"
        if probes[worst][0] in (Command.LEFT, Command.RIGHT)
        else f"{position * 1e3:.0f} mm"
    )
    raise UnidentifiableError(
        f"cannot identify {name}: the recordings ({len(observed.observations)} steps, "
        f"{observed.driving_s:.0f} s of driving) leave {probe} uncertain by {by} (1 sigma), "
        f"mostly through {name}; drive {what or 'more steps like it'}",
        name,
        advised,
    )


def _covariance(jac: np.ndarray, scale: float, names: list[str]) -> np.ndarray:
    """``scale * (J^T J)^-1`` through the SVD of ``J`` (the priors' rows included).

    Raises:
        UnidentifiableError: ``J`` is rank-deficient: the parameter that weighs most in
            its weakest direction has no effect the recordings can see.
    """
    _u, s, vt = np.linalg.svd(jac, full_matrices=False)
    if s.size == 0 or s[-1] <= s[0] * 1e-9:
        weakest = names[int(np.argmax(np.abs(vt[-1])))]
        raise UnidentifiableError(
            f"cannot identify {weakest}: the recordings do not depend on it", weakest
        )
    inv = (vt.T / (s * s)) @ vt
    return np.asarray(scale * inv)
