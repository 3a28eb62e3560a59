"""Fitting the twin's ground to recorded missions: ``scipy.optimize.least_squares``.

Each measured step (:class:`~emulator.observations.StepObservation`) is replayed on a
twin from its recorded start pose, at rest, with the candidate ground: its command
played as the controller plays it (:func:`emulator.playback.play`), then
:data:`SETTLE_S` with the wheels stopped. Three residuals per step compare the twin's
move with the recorded one, each divided by its measurement error: the position after
the step in the frame of its start pose (forward, lateral; the POSE averaged at rest)
and the yaw change (the gyro's). The parameters (:data:`~emulator.calibration.
FIT_PARAMETERS`, and the friction scale of each map region the steps drove on) are
fitted as logarithms within :data:`BOUNDS`, with a trust-region reflective solver and
a finite-difference Jacobian.

Outliers: a first fit with a robust (soft-L1) loss finds the steps that no ground
explains (an injected fault, a bump into something: more than :data:`OUTLIER_SIGMA`
measurement errors off after it); they are left out and listed, and the plain fit runs
on the rest from there.

Uncertainty: the covariance of the log-parameters is ``s^2 (J^T J)^-1`` at the
solution, ``J`` the Jacobian of the normalised residuals and ``s^2`` the reduced
chi-square when it exceeds 1 (the measurement errors were then too optimistic, or the
model is not the ground's: either way the spread is wider).

Each parameter also has a weak prior: normal in ``log(value)`` around the rover
description's value with :data:`PRIOR_SIGMA` (a factor of two at one sigma), appended
as one residual per parameter. A parameter the recordings say little about (on a grippy
ground the slip ratio barely shows) then stays near the description instead of
wandering to a bound, and its reported uncertainty stays about the prior's.

What cannot be identified is refused (:class:`~emulator.errors.UnidentifiableError`),
never guessed: before fitting, recordings without a turn measured (``mu_lateral``), or
without a straight step (the slip ratio and rolling resistance), or too short
(:data:`MIN_STEPS`, :data:`MIN_DRIVING_S`); after fitting, a parameter the recordings
did not inform (its uncertainty is still more than :data:`UNINFORMED_RATIO` of the
prior's) *and* that matters: changing it by its prior's sigma moves one of
:data:`PROBE_STEPS` by more than :data:`RELEVANT_POSITION_M` or
:data:`RELEVANT_YAW_DEG`. A parameter that is not informed and does not matter is kept
near the description, its uncertainty reported.

Deterministic: the twin is, and the solver has no randomness.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from emulator.calibration import FIT_PARAMETERS, Calibration, Residuals
from emulator.errors import CalibrationError, RecordingError, UnidentifiableError
from emulator.ground import Ground
from emulator.observations import ObservedSteps, StepObservation
from emulator.playback import measure_turn_efficiency, play
from emulator.twin import GATE_DT_S, Pose2D, Twin
from firmware_proto.model.rover import RoverDescription
from firmware_proto.model.worldmap import WorldMap
from firmware_proto.wire.messages import Command

__all__ = [
    "BOUNDS",
    "MIN_DRIVING_S",
    "MIN_STEPS",
    "OUTLIER_SIGMA",
    "PRIOR_SIGMA",
    "PROBE_STEPS",
    "RELEVANT_POSITION_M",
    "RELEVANT_YAW_DEG",
    "SETTLE_S",
    "UNINFORMED_RATIO",
    "FitReport",
    "fit_ground",
    "predict_moves",
]

logger = logging.getLogger(__name__)

SETTLE_S = 1.0
"""Twin time played with the wheels stopped after each replayed step, s."""

MIN_STEPS = 6
"""Fewer measured steps than this is too short to fit."""

MIN_DRIVING_S = 15.0
"""Less driving than this (nominal step durations, s) is too short to fit."""

PRIOR_SIGMA = math.log(2.0)
"""1-sigma of each parameter's prior, in ``log(value)``: a factor of two."""

OUTLIER_SIGMA = 20.0
"""A step whose residual (in its own measurement errors) is still above this after the
robust fit is left out: no ground the twin can model explains it."""

OUTLIER_F_SCALE = 3.0
"""Where the robust fit's soft-L1 loss turns from quadratic to linear, in sigmas."""

UNINFORMED_RATIO = 0.9
"""A parameter whose fitted 1-sigma error is above this fraction of its prior's was not
informed by the recordings."""

PROBE_STEPS: tuple[tuple[int, int, int], ...] = (
    (int(Command.FWD), 15, 23000),
    (int(Command.FWD), 60, 23000),
    (int(Command.REV), 30, 23000),
    (int(Command.LEFT), 20, 15484),
    (int(Command.RIGHT), 45, 15484),
)
"""Steps that say whether an uninformed parameter matters: 1 m straight at low, high
and reverse speed; 90 degree turns (by the description's model) both ways."""

RELEVANT_POSITION_M = 0.01
"""An uninformed parameter that moves a probe step's end by more than this matters."""
RELEVANT_YAW_DEG = 0.5
"""An uninformed parameter that turns a probe step's end by more than this matters."""

BOUNDS: dict[str, tuple[float, float]] = {
    "mu_longitudinal": (0.05, 3.0),
    "mu_lateral": (0.02, 5.0),
    "slip_saturation_ratio": (0.001, 0.5),
    "rolling_resistance": (0.001, 0.5),
    "region": (0.02, 2.0),
}
"""Where each parameter is searched (``region`` for every region scale)."""

_HINTS = {
    "mu_longitudinal": "drive straight steps at several speeds, both ways",
    "mu_lateral": "turn on the spot, both ways, at more than one speed",
    "slip_saturation_ratio": "drive straight steps at high and low speed",
    "rolling_resistance": "drive straight steps at high and low speed",
}


@dataclass(frozen=True)
class FitReport:
    """How the fit went, beside its :class:`Calibration`.

    Attributes:
        evaluations: residual evaluations (each replays every step once).
        wall_s: time the fit took (wall clock), s.
        status: the solver's message.
        outliers: steps the robust fit found off every ground it can fit.
    """

    evaluations: int
    wall_s: float
    status: str
    outliers: tuple[tuple[str, int, str], ...] = ()
    """Steps left out as outliers: ``(source, step index, why)``."""


def predict_moves(
    observations: tuple[StepObservation, ...] | list[StepObservation],
    rover: RoverDescription,
    world: WorldMap | None,
    ground: Ground,
    *,
    dt_s: float = GATE_DT_S,
) -> np.ndarray:
    """Each step replayed on a twin on ``ground`` from its recorded start pose: an
    ``(n, 3)`` array of ``(forward_m, left_m, yaw_rad)`` moves in the start frame."""
    twin_rover = ground.rover(rover)
    twin_world = ground.world(world, strict=False)
    out = np.empty((len(observations), 3))
    for i, obs in enumerate(observations):
        twin = Twin(twin_rover, twin_world, dt_s=dt_s, start=obs.start)
        play(twin, [obs.step], settle_s=0.0)
        twin.advance(SETTLE_S)
        pose = twin.pose
        dx, dy = pose.x_m - obs.start.x_m, pose.y_m - obs.start.y_m
        c, s = math.cos(obs.start.yaw_rad), math.sin(obs.start.yaw_rad)
        out[i] = (c * dx + s * dy, -s * dx + c * dy, twin.yaw_unwrapped_rad - obs.start.yaw_rad)
    return out


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
            "RIGHT) measured at rest; drive turns both ways",
            "mu_lateral",
        )
    if straights == 0:
        raise UnidentifiableError(
            "cannot identify slip_saturation_ratio and rolling_resistance: the recordings "
            "have no straight step (FWD or REV) measured at rest",
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


def fit_ground(
    observed: ObservedSteps,
    rover: RoverDescription,
    world: WorldMap | None,
    *,
    start: Ground | None = None,
    dt_s: float = GATE_DT_S,
    sources: tuple[str, ...] = (),
    max_evaluations: int = 200,
) -> tuple[Calibration, FitReport]:
    """Fit the ground to measured steps (module docstring).

    Args:
        observed: the measured steps (:func:`emulator.observations.observe_steps`).
        rover: the rover description (its traction is the starting point).
        world: the map the steps were driven on (its regions; ``None``: open plane).
        start: the starting ground (default: the description's, with the map's
            region scales).
        dt_s: the twin's step (default the gate's, so the fit is what the gate plays).
        sources: the recordings' names, for the report.
        max_evaluations: the solver's budget of residual evaluations.

    Raises:
        RecordingError: no step could be measured.
        UnidentifiableError: a parameter cannot be identified (module docstring).
        CalibrationError: scipy is not installed.
    """
    try:
        from scipy.optimize import least_squares  # noqa: PLC0415 - only a fit needs it
    except ImportError as exc:
        raise CalibrationError("rover calibrate needs scipy: install rover-hil[calibrate]") from exc
    t0 = time.perf_counter()
    _structure(observed)
    obs = list(observed.observations)
    base = start if start is not None else Ground.of_rover(rover, world)
    measured = np.array([o.displacement() for o in obs])
    sigma = np.array([(o.sigma_xy_m, o.sigma_xy_m, o.sigma_yaw_rad) for o in obs])
    evaluations = [0]

    def residuals_of(ground: Ground) -> np.ndarray:
        evaluations[0] += 1
        moves = predict_moves(obs, rover, world, ground, dt_s=dt_s)
        out: np.ndarray = ((moves - measured) / sigma).ravel()
        return out

    names = list(FIT_PARAMETERS)
    fixed_regions: list[str] = []
    r0 = residuals_of(base)
    for rid, scale in base.regions:
        probe = residuals_of(base.with_values(**{f"region.{rid}": scale * 0.5}))
        if np.any(np.abs(probe - r0) > 1e-6):
            names.append(f"region.{rid}")
        else:
            fixed_regions.append(rid)

    def ground_at(x: np.ndarray) -> Ground:
        return base.with_values(**{n: math.exp(v) for n, v in zip(names, x, strict=True)})

    lo, hi = _bounds(names)
    prior = np.clip(np.log([_value(base, n) for n in names]), lo + 1e-9, hi - 1e-9)

    def fun(x: np.ndarray) -> np.ndarray:
        return np.concatenate((residuals_of(ground_at(x)), (x - prior) / PRIOR_SIGMA))

    def solve(x0: np.ndarray, loss: str) -> Any:
        return least_squares(
            fun,
            x0,
            bounds=(lo, hi),
            method="trf",
            loss=loss,
            f_scale=OUTLIER_F_SCALE,
            x_scale="jac",
            diff_step=1e-4,
            max_nfev=max_evaluations,
        )

    # A robust fit first, so that a step the twin cannot explain on any ground (a fault
    # injected, a bump into something) is found, not averaged in; then the plain fit
    # on the others, whose Jacobian gives the covariance.
    robust = solve(prior, "soft_l1")
    worst = np.max(np.abs(residuals_of(ground_at(robust.x)).reshape(-1, 3)), axis=1)
    outliers = tuple(
        (o.source, o.index, f"off every ground the twin fits: {w:.0f} sigma after the fit")
        for o, w in zip(obs, worst, strict=True)
        if w > OUTLIER_SIGMA
    )
    if outliers:
        keep = worst <= OUTLIER_SIGMA
        obs = [o for o, k in zip(obs, keep, strict=True) if k]
        measured, sigma = measured[keep], sigma[keep]
        observed = ObservedSteps(
            tuple(obs),
            observed.skipped + outliers,
            sum(rover.step_duration_s(o.speed, o.distance) for o in obs),
        )
        for source, index, why in outliers:
            logger.info("%s step %d left out: %s", source, index, why)
        _structure(observed)
    result = solve(robust.x, "linear")
    fitted = replace(ground_at(result.x), name="calibrated")
    jac = np.asarray(result.jac)
    data = np.asarray(result.fun)[: len(obs) * 3]
    chi2 = float(np.sum(data * data) / max(1, data.size - len(names)))
    covariance = _covariance(jac, max(1.0, chi2), names)
    _refuse_uninformed(names, covariance, fitted, rover, observed)
    before = Residuals.of(predict_moves(obs, rover, world, base, dt_s=dt_s) - measured)
    after = Residuals.of(predict_moves(obs, rover, world, fitted, dt_s=dt_s) - measured)
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
    )
    report = FitReport(evaluations[0], time.perf_counter() - t0, str(result.message), outliers)
    logger.info(
        "fit: %s after %d evaluations in %.1f s; %s",
        ", ".join(f"{n}={calibration.value(n):.4g}" for n in names),
        report.evaluations,
        report.wall_s,
        after.line(),
    )
    return calibration, report


def _value(ground: Ground, name: str) -> float:
    if name.startswith("region."):
        return ground.region_scale(name[len("region.") :]) or 1.0
    return float(getattr(ground, name))


def _refuse_uninformed(
    names: list[str],
    covariance: np.ndarray,
    fitted: Ground,
    rover: RoverDescription,
    observed: ObservedSteps,
) -> None:
    """Raise for the first parameter that the recordings did not inform and that
    matters (module docstring)."""
    probes: list[StepObservation] = [
        StepObservation(
            "probe", i, c, sp, d, Pose2D(0.0, 0.0, 0.0), Pose2D(0.0, 0.0, 0.0), 0.0, 1.0, 1.0
        )
        for i, (c, sp, d) in enumerate(PROBE_STEPS)
    ]
    reference: np.ndarray | None = None
    for i, name in enumerate(names):
        sigma = math.sqrt(max(0.0, covariance[i, i]))
        if sigma <= UNINFORMED_RATIO * PRIOR_SIGMA:
            continue
        if name.startswith("region."):
            what = f"the friction of region {name[len('region.') :]}"
            raise UnidentifiableError(
                f"cannot identify {what}: the recordings drove too little on it "
                f"(+/-{sigma * 100:.0f}% at 1 sigma); drive more steps inside it",
                name,
            )
        if reference is None:
            reference = predict_moves(probes, rover, None, fitted)
        moved = predict_moves(
            probes,
            rover,
            None,
            fitted.with_values(**{name: _value(fitted, name) * math.exp(PRIOR_SIGMA)}),
        )
        delta = np.abs(moved - reference)
        position = float(np.max(np.hypot(delta[:, 0], delta[:, 1])))
        yaw = math.degrees(float(np.max(delta[:, 2])))
        if position > RELEVANT_POSITION_M or yaw > RELEVANT_YAW_DEG:
            raise UnidentifiableError(
                f"cannot identify {name}: the recordings ({len(observed.observations)} "
                f"steps, {observed.driving_s:.0f} s of driving) hardly inform it, yet it "
                f"moves a probe step by {position * 1e3:.0f} mm, {yaw:.1f} deg; "
                f"{_HINTS.get(name, 'drive more')}",
                name,
            )
        logger.info(
            "%s: not informed by the recordings, and it does not matter here "
            "(%.1f mm, %.2f deg on the probe steps): kept near the description",
            name,
            position * 1e3,
            yaw,
        )


def _covariance(jac: np.ndarray, scale: float, names: list[str]) -> np.ndarray:
    """``scale * (J^T J)^-1`` through the SVD of ``J``.

    Raises:
        UnidentifiableError: ``J`` is rank-deficient: the parameter that weighs most in
            its weakest direction has no effect the recordings can see.
    """
    _u, s, vt = np.linalg.svd(jac, full_matrices=False)
    if s.size == 0 or s[-1] <= s[0] * 1e-9:
        weakest = names[int(np.argmax(np.abs(vt[-1])))]
        raise UnidentifiableError(
            f"cannot identify {weakest}: the recordings do not depend on it "
            f"({_HINTS.get(weakest, 'drive more on it')})",
            weakest,
        )
    inv = (vt.T / (s * s)) @ vt
    return np.asarray(scale * inv)
