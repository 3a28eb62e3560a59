"""Which steps identify the ground: the candidate steps, their information, the probes.

A calibration learns the ground's parameters (:data:`~emulator.calibration.
FIT_PARAMETERS`, as logarithms) from steps measured at rest before and after
(:mod:`emulator.observations`). How much a step tells is its *Fisher information*:
``J^T C^-1 J``, ``J`` the ``3 x p`` sensitivity of its move (forward, lateral, yaw in
its start frame) to the log-parameters, ``C`` its noise (the measurement's and the
process noise the calibration estimates). :func:`sensitivities` computes ``J`` for any
steps at once on the open plane (a step's move does not depend on where it starts
there), by forward differences in one replay batch (:func:`emulator.moves.play_moves`).

What matters is not a parameter but what the twin predicts with it: :func:`probes` are
the steps plans are made of (the planner's drive, approach and turn speeds), and a
calibration is good enough when the spread its covariance leaves on every probe is
below :data:`PROBE_POSITION_M` and :data:`PROBE_YAW_RAD` (:func:`probe_spread`,
:func:`excess`). A parameter's uncertainty is judged by what it does there: its *share*
of the worst probe's spread, how much that spread would shrink were the parameter known
(:func:`shares`; correlated parameters, such as the rolling resistance and the slip
ratio, each keep a large relative error while their combined effect is pinned). Its
*target* (:func:`targets`) is the relative 1-sigma at which its share reaches the bar;
every probe under its bar puts every parameter under its target.

:func:`candidates` are the steps ``rover calibrate --drive`` may choose from (straight
steps at low and high speed both ways, turns both ways at several speeds and angles);
:func:`best_step` picks the one that cuts the worst probe's spread most per second of
driving, and :func:`advice` the steps that would make an unidentifiable parameter
identifiable (what a refusal says to drive).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from emulator.batch import BatchDraw
from emulator.ground import Ground
from emulator.moves import MoveJob, play_moves
from emulator.twin import GATE_DT_S, Pose2D
from firmware_proto.model.rover import RoverDescription
from firmware_proto.wire.messages import Command

__all__ = [
    "DIFF_STEP",
    "NEAR_BEST",
    "PROBE_POSITION_M",
    "PROBE_YAW_RAD",
    "SETTLE_S",
    "advice",
    "best_step",
    "candidates",
    "describe_step",
    "excess",
    "information",
    "probe_spread",
    "probes",
    "sensitivities",
    "shares",
    "step_noise",
    "targets",
]

SETTLE_S = 1.0
"""Twin time replayed with the wheels stopped after each step, s (the body comes to
rest; the measurement is at rest)."""

DIFF_STEP = 1e-3
"""Forward-difference step in each log-parameter (0.1 %)."""

PROBE_POSITION_M = 0.002
"""A calibration is good enough when no probe's position is uncertain by more than this
(1 sigma): about the measurement error of one step; twelve of them, adding up, stay a
tenth of the drift guard's 0.25 m."""
NEAR_BEST = 0.05
"""Candidates whose gain is within this fraction of the best are as good (a design's
information is an estimate): a tie-breaker chooses among them."""
PROBE_YAW_RAD = math.radians(0.05)
"""... and no probe's yaw by more than this (1 sigma): six turns of a 12-step plan, adding
up, turn its last metres by 0.3 degree, 5 mm at 1 m."""


def _straights(rover: RoverDescription) -> list[tuple[int, int, int]]:
    out = []
    for command in (Command.FWD, Command.REV):
        for speed in (10, 25, 45, 60):
            for metres in (0.5,) if speed == 10 else (0.5, 1.0):
                out.append((int(command), speed, rover.m_to_units(metres)))
    return out


def _turns(rover: RoverDescription) -> list[tuple[int, int, int]]:
    out = []
    for command in (Command.LEFT, Command.RIGHT):
        for speed in (10, 25, 45, 60):
            for degrees in (45.0,) if speed == 10 else (45.0, 90.0, 180.0):
                units = min(rover.turn_units_for_yaw(math.radians(degrees)), 30000)
                out.append((int(command), speed, units))
    return out


def candidates(rover: RoverDescription) -> tuple[tuple[int, int, int], ...]:
    """The steps a designed calibration chooses from: FWD and REV at speeds 10 (over
    0.5 m), 25, 45 and 60 (over 0.5 and 1 m); LEFT and RIGHT at speed 10 (by 45
    degrees), 25, 45 and 60 (by 45, 90 and 180 degrees, by ``rover``'s turn model). The
    slowest steps are short: at speed 10 a metre takes 20 s of the budget."""
    return tuple(_straights(rover) + _turns(rover))


def probes(rover: RoverDescription) -> tuple[tuple[int, int, int], ...]:
    """The steps a calibrated twin must predict, across what plans are made of: FWD over
    1 m at speeds 15, 35 and 60 (the planner drives at 60 and approaches at 30), REV
    over 0.5 m at 35 (repairs back up), 90 degree turns at 15, 30 and 45 and the other
    way at 20 (the planner's turn speed), a 15 degree turn at 10 (its fine turns)."""
    quarter = rover.turn_units_for_yaw(math.pi / 2.0)
    metre = rover.m_to_units(1.0)
    return (
        (int(Command.FWD), 15, metre),
        (int(Command.FWD), 35, metre),
        (int(Command.FWD), 60, metre),
        (int(Command.REV), 35, metre // 2),
        (int(Command.LEFT), 15, quarter),
        (int(Command.LEFT), 30, quarter),
        (int(Command.LEFT), 45, quarter),
        (int(Command.RIGHT), 20, quarter),
        (int(Command.LEFT), 10, rover.turn_units_for_yaw(math.radians(15.0))),
    )


def describe_step(rover: RoverDescription, step: tuple[int, int, int]) -> str:
    """``FWD at speed 10 over 1.00 m`` / ``LEFT at speed 25 by about 90 degrees``."""
    command, speed, distance = step
    name = Command(command).name
    if command in (Command.LEFT, Command.RIGHT):
        degrees = math.degrees(rover.yaw_for_turn_units(distance))
        return f"{name} at speed {speed} by about {degrees:.0f} degrees ({distance} units)"
    return f"{name} at speed {speed} over {rover.units_to_m(distance):.2f} m"


def sensitivities(
    rover: RoverDescription,
    ground: Ground,
    names: Sequence[str],
    steps: Sequence[tuple[int, int, int]],
    *,
    dt_s: float = GATE_DT_S,
    sides: bool = False,
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """The moves of ``steps`` on ``ground`` (open plane, from rest) and their
    sensitivities, in one replay batch.

    Args:
        names: the log-parameters to differentiate by (ground parameter names; no
            region: the open plane has none).
        sides: also by the log of each side's friction factor (the process noise's
            direction, :mod:`emulator.fit`).

    Returns:
        ``(moves, J, G)``: ``moves`` ``(k, 3)`` forward, lateral (m) and yaw (rad);
        ``J`` ``(k, 3, p)`` per log-parameter; ``G`` ``(k, 3, 2)`` per log side factor
        (left, right), or ``None``.
    """
    draws = [BatchDraw(ground)]
    for name in names:
        value = float(getattr(ground, name))
        draws.append(BatchDraw(ground.with_values(**{name: value * math.exp(DIFF_STEP)})))
    if sides:
        factor = math.exp(DIFF_STEP)
        draws += [BatchDraw(ground, factor, 1.0), BatchDraw(ground, 1.0, factor)]
    origin = Pose2D(0.0, 0.0, 0.0)
    jobs = [MoveJob(origin, (step,), d) for d in draws for step in steps]
    ends = play_moves(rover, None, jobs, dt_s=dt_s, settle_s=SETTLE_S)
    k = len(steps)
    table = ends.reshape(len(draws), k, 3)
    moves = table[0]
    jac = np.transpose((table[1 : 1 + len(names)] - moves) / DIFF_STEP, (1, 2, 0))
    side = None
    if sides:
        side = np.transpose((table[1 + len(names) :] - moves) / DIFF_STEP, (1, 2, 0))
    return moves, jac, side


def step_noise(
    moves: np.ndarray,
    side: np.ndarray,
    *,
    sigma_xy_m: float,
    sigma_yaw_rad: float,
    sigma_heading_rad: float,
    slip_sigma: float,
) -> np.ndarray:
    """``(k, 3, 3)``: the noise of steps with start-frame ``moves`` ``(k, 3)`` and side
    sensitivities ``side`` ``(k, 3, 2)``, measured as calibration steps are: the
    positions' and the yaw change's errors, the start heading's (which turns a move of
    ``(f, l)`` by ``(l, -f)`` per radian), and the process noise ``slip_sigma`` on each
    side's log friction (:class:`~emulator.observations.StepObservation.covariance`)."""
    turn = np.stack((moves[:, 1], -moves[:, 0], np.zeros(len(moves))), axis=1)
    measured = np.diag([sigma_xy_m**2, sigma_xy_m**2, sigma_yaw_rad**2])[None]
    cov = measured + sigma_heading_rad**2 * np.einsum("ka,kb->kab", turn, turn)
    return np.asarray(cov + slip_sigma**2 * np.einsum("kap,kbp->kab", side, side))


def information(jac: np.ndarray, noise: np.ndarray) -> np.ndarray:
    """Fisher information ``sum_i J_i^T C_i^-1 J_i`` of steps with sensitivities ``jac``
    ``(k, 3, p)`` and noise covariances ``noise`` ``(k, 3, 3)``."""
    inv = np.linalg.inv(noise)
    return np.asarray(np.einsum("kap,kab,kbq->pq", jac, inv, jac))


def probe_spread(probe_jac: np.ndarray, covariance: np.ndarray) -> np.ndarray:
    """``(k, 3)``: the 1-sigma spread of each probe's forward, lateral and yaw that a
    log-parameter covariance leaves."""
    var = np.einsum("kap,pq,kaq->ka", probe_jac, covariance, probe_jac)
    return np.asarray(np.sqrt(np.maximum(var, 0.0)))


def _weights() -> np.ndarray:
    return np.array([1.0 / PROBE_POSITION_M, 1.0 / PROBE_POSITION_M, 1.0 / PROBE_YAW_RAD])


def excess(spread: np.ndarray) -> np.ndarray:
    """``(k,)``: each probe's spread in units of its bars, the three axes together
    (``sqrt((f^2 + l^2) / bar_m^2 + yaw^2 / bar_rad^2)``); 1 is at the bar."""
    return np.asarray(np.sqrt(np.sum((spread * _weights()) ** 2, axis=1)))


def shares(probe_jac: np.ndarray, covariance: np.ndarray) -> np.ndarray:
    """``(p,)``: each log-parameter's share of the probes' spread, in bars: how much the
    worst probe's spread (in :func:`excess`'s units) would shrink, in quadrature, were
    that parameter known exactly (its correlations with the others kept). A share
    never exceeds the worst probe's :func:`excess`."""
    weighted = probe_jac * _weights()[None, :, None]  # (k, 3, p)
    cross = np.einsum("kap,pq->kaq", weighted, covariance)  # Cov(y_ka, theta_q)
    var = np.maximum(np.diag(covariance), 1e-300)
    shrink = np.sum(cross * cross, axis=1) / var  # (k, p)
    return np.asarray(np.sqrt(np.max(shrink, axis=0)))


def targets(probe_jac: np.ndarray, covariance: np.ndarray) -> np.ndarray:
    """Each log-parameter's target 1-sigma: the one at which (its correlations with the
    others as they are) its :func:`shares` reaches the bar."""
    sigma = np.sqrt(np.maximum(np.diag(covariance), 0.0))
    return np.asarray(sigma / np.maximum(shares(probe_jac, covariance), 1e-12))


def best_step(
    precision: np.ndarray,
    probe_jac: np.ndarray,
    candidate_jac: np.ndarray,
    candidate_noise: np.ndarray,
    durations_s: np.ndarray,
    *,
    allowed: np.ndarray | None = None,
    preference: np.ndarray | None = None,
) -> tuple[int, float]:
    """The candidate that lowers the worst probe's spread most per second of driving
    (a sequential, cost-weighted minimax design); among those within
    :data:`NEAR_BEST` of the best, the one ``preference`` ranks first (where there is
    room, which way to turn).

    Args:
        precision: the information so far (with the prior's), ``(p, p)``.
        probe_jac: ``(m, 3, p)`` the probes' sensitivities.
        candidate_jac, candidate_noise: ``(k, 3, p)`` and ``(k, 3, 3)``.
        durations_s: ``(k,)`` each candidate's driving time.
        allowed: ``(k,)`` which candidates may be chosen (room to drive them).
        preference: ``(k,)`` a tie-breaker, higher preferred.

    Returns:
        ``(index, worst excess after it)``: the worst probe's spread over its bar if
        that candidate were measured next; ``(-1, inf)`` if none is allowed.
    """
    now = float(np.max(excess(probe_spread(probe_jac, np.linalg.inv(precision)))))
    inv = np.linalg.inv(candidate_noise)
    gains = np.full(len(candidate_jac), -math.inf)
    afters = np.full(len(candidate_jac), math.inf)
    for i in range(len(candidate_jac)):
        if allowed is not None and not allowed[i]:
            continue
        j = candidate_jac[i]
        after_cov = np.linalg.inv(precision + j.T @ inv[i] @ j)
        afters[i] = float(np.max(excess(probe_spread(probe_jac, after_cov))))
        gains[i] = (math.log(now) - math.log(max(afters[i], 1e-12))) / max(durations_s[i], 0.1)
    top = float(np.max(gains)) if len(gains) else -math.inf
    if not math.isfinite(top):
        return -1, math.inf
    near = gains >= top - NEAR_BEST * abs(top)
    order = preference if preference is not None else np.zeros(len(gains))
    best = int(np.argmax(np.where(near, order, -math.inf) + np.where(near, gains * 1e-9, 0.0)))
    return best, float(afters[best])


def advice(
    precision: np.ndarray,
    probe_jac: np.ndarray,
    candidate_jac: np.ndarray,
    candidate_noise: np.ndarray,
    durations_s: np.ndarray,
    *,
    max_steps: int = 12,
) -> list[int]:
    """The candidates to drive, in order (repeats allowed), until every probe's spread
    is under its bar, chosen one at a time by :func:`best_step`; at most ``max_steps``
    (the list is then as far as it got)."""
    chosen: list[int] = []
    info = precision.copy()
    inv = np.linalg.inv(candidate_noise)
    for _ in range(max_steps):
        cov = np.linalg.inv(info)
        if float(np.max(excess(probe_spread(probe_jac, cov)))) <= 1.0:
            break
        index, _after = best_step(info, probe_jac, candidate_jac, candidate_noise, durations_s)
        if index < 0:
            break
        chosen.append(index)
        j = candidate_jac[index]
        info = info + j.T @ inv[index] @ j
    return chosen
