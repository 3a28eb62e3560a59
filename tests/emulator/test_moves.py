"""The replay batch a calibration fits with (emulator/moves.py) plays each step as the
twin does, and the design's measures (emulator/design.py) say what they promise."""

from __future__ import annotations

import logging
import math
import os
import re
from pathlib import Path

import numpy as np
import pytest

from emulator import batch_kernel, design
from emulator.batch import BatchDraw
from emulator.calibration import FIT_PARAMETERS, mirrored
from emulator.errors import NativeBuildError, TwinConfigError
from emulator.ground import load_ground
from emulator.moves import MoveJob, play_moves
from emulator.playback import play
from emulator.twin import Pose2D, Twin
from firmware_proto.model.rover import RoverDescription
from firmware_proto.model.worldmap import WorldMap

LEFT, FWD, REV, RIGHT = 3, 1, 2, 4


def test_a_replay_in_the_batch_is_the_twins(
    rover: RoverDescription, lab: WorldMap, kernel: str
) -> None:
    ground = load_ground("loose", rover).with_values(**{"region.sandbox": 0.35})
    cases = [
        ((LEFT, 30, 15484), Pose2D(1.1, 4.9, math.pi / 2)),  # on the sandbox's edge
        ((FWD, 40, 23000), Pose2D(1.0, 5.0, 0.3)),  # across it
        ((REV, 20, 11500), Pose2D(6.0, 1.0, 2.0)),
        ((RIGHT, 60, 30000), Pose2D(2.0, 2.0, -1.0)),
    ]
    draws = [BatchDraw(ground), BatchDraw(ground, 0.8, 0.9, 0.01, -0.02, 0.03)]
    jobs = [MoveJob(start, (step,), d) for d in draws for step, start in cases]
    ends = play_moves(rover, lab, jobs, dt_s=0.01, settle_s=1.0, kernel=kernel)
    for job, end in zip(jobs, ends, strict=True):
        d = job.draw
        start = Pose2D(
            job.start.x_m + d.start_dx_m,
            job.start.y_m + d.start_dy_m,
            job.start.yaw_rad + d.start_dyaw_rad,
        )
        twin = Twin(ground.rover(rover), ground.world(lab), dt_s=0.01, start=start)
        twin.set_traction_scale(d.slip_left, d.slip_right)
        play(twin, list(job.steps), settle_s=0.0)
        twin.advance(1.0)  # the rest it is measured at
        assert end == pytest.approx(
            (twin.pose.x_m, twin.pose.y_m, twin.yaw_unwrapped_rad), abs=1e-9
        )
    with pytest.raises(TwinConfigError):
        play_moves(rover, None, jobs, dt_s=0.05, settle_s=1.0, kernel=kernel)


def _varied_jobs(rover: RoverDescription, seed: int) -> list[MoveJob]:
    """Jobs of one to three steps (some alike, one with none: it rests where it starts)
    on varied grounds, sides and starts."""
    rng = np.random.default_rng(seed)
    base = load_ground("loose", rover)
    jobs: list[MoveJob] = []
    for i in range(20):
        steps = tuple(
            (int(rng.integers(1, 5)), int(rng.integers(5, 61)), int(rng.integers(500, 20000)))
            for _ in range(int(rng.integers(1, 4)))
        )
        if i % 5 == 0:
            steps = jobs[-1].steps if jobs else ()
        ground = base.with_values(
            **{"region.sandbox": float(rng.uniform(0.2, 1.0)), "mu_lateral": 0.3 + 0.4 * i / 20}
        )
        draw = BatchDraw(
            ground,
            float(rng.uniform(0.6, 1.2)),
            float(rng.uniform(0.6, 1.2)),
            float(rng.normal(0.0, 0.02)),
            float(rng.normal(0.0, 0.02)),
            float(rng.normal(0.0, 0.05)),
        )
        start = Pose2D(float(rng.uniform(0.5, 7.5)), float(rng.uniform(0.5, 7.5)), 3.0 - i * 0.3)
        jobs.append(MoveJob(start, steps, draw))
    return jobs


@pytest.mark.usefixtures("c_compiler")
def test_the_c_kernel_replays_what_numpy_does(rover: RoverDescription, lab: WorldMap) -> None:
    jobs = _varied_jobs(rover, 1)
    assert any(not job.steps for job in jobs)
    for world in (lab, None):
        c = play_moves(rover, world, jobs, dt_s=0.01, settle_s=0.5, kernel="c")
        plain = play_moves(rover, world, jobs, dt_s=0.01, settle_s=0.5, kernel="numpy")
        # The same operations in the same order: libm's last bits apart.
        assert np.allclose(c, plain, rtol=0.0, atol=1e-12)
    # Where the sandbox is (the map's regions), the ends differ from an open plane's.
    on_map = play_moves(rover, lab, jobs, dt_s=0.01, settle_s=0.5, kernel="c")
    open_plane = play_moves(rover, None, jobs, dt_s=0.01, settle_s=0.5, kernel="c")
    assert not np.allclose(on_map, open_plane, atol=1e-6)
    with pytest.raises(TwinConfigError, match="kernel must be one of"):
        play_moves(rover, lab, jobs, dt_s=0.01, settle_s=0.5, kernel="fortran")


@pytest.mark.parametrize("cause", ["no compiler", "no cache"])
def test_where_the_kernel_cannot_build_the_replay_says_so_once_and_uses_numpy(
    rover: RoverDescription,
    lab: WorldMap,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    caplog: pytest.LogCaptureFixture,
    cause: str,
) -> None:
    jobs = _varied_jobs(rover, 3)[:3]
    plain = play_moves(rover, lab, jobs, dt_s=0.01, settle_s=0.5, kernel="numpy")
    path = os.environ["PATH"]
    monkeypatch.setattr(batch_kernel, "_LIB", [])  # not loaded yet in this process
    monkeypatch.setattr(batch_kernel, "_FAILED", [])
    monkeypatch.setattr(batch_kernel, "_said_numpy", [])
    if cause == "no compiler":
        monkeypatch.setenv("ROVER_FIRMWARE_CACHE", str(tmp_path))  # nothing built there
        monkeypatch.setenv("PATH", str(tmp_path))
        monkeypatch.setenv("CC", "no-such-cc")
        why = "no C compiler ('no-such-cc' or cc) on PATH"
    else:  # a file where the cache directory would be: it cannot be made
        (tmp_path / "file").write_text("")
        monkeypatch.setenv("ROVER_FIRMWARE_CACHE", str(tmp_path / "file" / "cache"))
        why = f"cannot write the library to {tmp_path / 'file' / 'cache'}"
    with pytest.raises(NativeBuildError, match=re.escape(why)):
        play_moves(rover, lab, jobs, dt_s=0.01, settle_s=0.5, kernel="c")
    with caplog.at_level(logging.WARNING, logger="emulator.batch_kernel"):
        first = play_moves(rover, lab, jobs, dt_s=0.01, settle_s=0.5)
        second = play_moves(rover, lab, jobs, dt_s=0.01, settle_s=0.5)
    assert np.array_equal(first, plain) and np.array_equal(second, plain)
    said = [r.getMessage() for r in caplog.records if r.name == "emulator.batch_kernel"]
    assert len(said) == 1 and said[0].startswith(f"batch twins in numpy, not the C kernel: {why}")
    # The failure is kept: with the compiler back, this process builds nothing again.
    monkeypatch.setenv("PATH", path)
    monkeypatch.delenv("CC", raising=False)
    with pytest.raises(NativeBuildError, match=re.escape(why)):
        play_moves(rover, lab, jobs, dt_s=0.01, settle_s=0.5, kernel="c")
    assert [p.name for p in tmp_path.iterdir()] == ([] if cause == "no compiler" else ["file"])


def test_antithetic_draws_are_centred_pairs() -> None:
    half = np.random.default_rng(3).normal(size=(4, 2))
    pairs = mirrored(half)
    assert np.array_equal(pairs[0::2], half) and np.array_equal(pairs[1::2], -half)
    assert np.allclose(pairs.sum(axis=0), 0.0)


# Seconds of CPU (the candidates replayed, up to 20 s of twin time each): out of the
# fast lane, in the test command's background part.
@pytest.mark.slow
@pytest.mark.virtual
def test_the_design_measures_hang_together(rover: RoverDescription) -> None:
    ground = load_ground("dusty", rover)
    names = list(FIT_PARAMETERS)
    probes = design.probes(rover)
    moves, jac, side = design.sensitivities(rover, ground, names, probes, sides=True)
    assert side is not None and jac.shape == (len(probes), 3, len(names))
    # A turn on the spot turns, a straight step goes straight.
    assert moves[0, 0] > 0.9 and abs(moves[4, 2]) > 1.0
    # Less lateral friction turns more (docs/twin.md).
    assert jac[4, 2, names.index("mu_lateral")] < 0.0
    cov = np.diag([0.05, 0.02, 0.5, 0.5, 0.3]) ** 2
    cov[3, 4] = cov[4, 3] = 0.9 * 0.5 * 0.3  # the slip ratio and the rolling resistance
    worst = float(np.max(design.excess(design.probe_spread(jac, cov))))
    shares = design.shares(jac, cov)
    assert np.all(shares <= worst + 1e-9)  # a share never exceeds the spread
    targets = design.targets(jac, cov)
    sigma = np.sqrt(np.diag(cov))
    assert np.allclose(sigma / targets, shares)
    # With only the prior, the advice leads every probe under its bar.
    candidates = design.candidates(rover)
    cmoves, cjac, cside = design.sensitivities(rover, ground, names, candidates, sides=True)
    assert cside is not None
    noise = design.step_noise(
        cmoves,
        cside,
        sigma_xy_m=0.003,
        sigma_yaw_rad=0.002,
        sigma_heading_rad=0.002,
        slip_sigma=0.0,
    )
    durations = np.array([rover.step_duration_s(s, d) for _c, s, d in candidates])
    prior = np.eye(len(names)) / math.log(2.0) ** 2
    chosen = design.advice(prior, jac, cjac, noise, durations, max_steps=40)
    info = prior + design.information(cjac[chosen], noise[chosen])
    assert float(np.max(design.excess(design.probe_spread(jac, np.linalg.inv(info))))) <= 1.0
    kinds = {candidates[i][0] for i in chosen}
    assert kinds & {LEFT, RIGHT} and kinds & {FWD, REV}
