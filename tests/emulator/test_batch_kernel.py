"""The batch twins' C kernel (emulator/batch_kernel.c) computes the forces numpy does:
the gate's batches of twins play the same, collide at the same tick and come to rest at
the same tick whichever computes them (the replays of emulator/moves.py:
tests/emulator/test_moves.py)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from emulator import batch_kernel
from emulator.batch import _WHEEL_PROBE_RADIUS_M, BatchDraw, BatchResult, _Forces, play_batch
from emulator.errors import TwinConfigError
from emulator.ground import load_ground
from emulator.moves import MoveJob, play_moves
from emulator.twin import Pose2D
from firmware_proto.model.rover import RoverDescription
from firmware_proto.model.worldmap import TractionRegion, WorldMap, load_map

pytestmark = pytest.mark.usefixtures("c_compiler")

QUARTER = 15484
SQUARE = [(1, 60, 28750), (1, 60, 28750), (3, 30, QUARTER)] * 4
"""Four sides of 2 x 1.25 m on scn01, through its traction region."""


def _draws(rover: RoverDescription, world: WorldMap, n: int, seed: int) -> list[BatchDraw]:
    rng = np.random.default_rng(seed)
    base = load_ground("loose", rover)
    draws = []
    for _ in range(n):
        region = {f"region.{r.id}": float(rng.uniform(0.3, 1.0)) for r in world.traction_regions}
        ground = base.with_values(mu_lateral=float(rng.uniform(0.3, 0.7)), **region)
        draws.append(
            BatchDraw(
                ground,
                float(rng.uniform(0.7, 1.1)),
                float(rng.uniform(0.7, 1.1)),
                float(rng.normal(0.0, 0.03)),
                float(rng.normal(0.0, 0.03)),
                float(rng.normal(0.0, 0.05)),
            )
        )
    return draws


@pytest.mark.parametrize(
    ("map_name", "steps", "start"),
    [
        ("scn01", SQUARE, Pose2D(1.0, 4.0, 0.0)),
        ("lab", [(1, 60, 30000), (1, 60, 30000)], None),  # into the table: most collide
    ],
)
def test_the_c_kernel_plays_the_batch_as_numpy_does(
    rover: RoverDescription, map_name: str, steps: list[tuple[int, int, int]], start: Pose2D | None
) -> None:
    world = load_map(map_name)
    if start is None:
        start = Pose2D(world.start.x, world.start.y, math.radians(world.start.yaw_deg))
    draws = _draws(rover, world, 12, seed=len(map_name))

    def run(kernel: str) -> BatchResult:
        return play_batch(
            rover, world, draws, steps, dt_s=0.01, safety_margin_m=0.1, start=start,
            record_every_s=0.5, kernel=kernel,
        )  # fmt: skip

    c, plain = run("c"), run("numpy")
    assert np.array_equal(c.final_tick, plain.final_tick)
    assert np.array_equal(c.collision_tick, plain.collision_tick)
    assert c.collision_obstacle == plain.collision_obstacle
    assert np.allclose(c.final, plain.final, rtol=0.0, atol=1e-9)
    assert np.allclose(c.poses, plain.poses, rtol=0.0, atol=1e-9, equal_nan=True)
    assert np.allclose(c.collision_contact, plain.collision_contact, atol=1e-9, equal_nan=True)
    # The batch is varied enough to tell: twins end apart, some collide (all of them into
    # the lab's table), some on scn01 come to rest after the plan, each at its own tick.
    assert np.ptp(c.final[:, 0]) > 0.01
    collided = c.collision_tick >= 0
    if map_name == "lab":
        assert collided.all() and len(set(c.collision_tick)) > 1
    else:
        assert 0 < collided.sum() < len(draws) and len(set(c.final_tick[~collided])) > 1
    with pytest.raises(TwinConfigError, match="kernel must be one of"):
        run("cuda")


def test_overlapping_and_concave_regions_scale_the_wheels_alike(
    rover: RoverDescription,
) -> None:
    lab = load_map("lab")
    ell = TractionRegion(  # concave, over the sandbox's right half
        "ell", ((1.0, 4.0), (3.0, 4.0), (3.0, 5.0), (2.0, 5.0), (2.0, 6.0), (1.0, 6.0)), 0.3
    )
    patch = TractionRegion("patch", ((1.5, 4.6), (2.5, 4.6), (2.5, 5.4), (1.5, 5.4)), 1.6)
    world = dataclasses.replace(lab, traction_regions=(*lab.traction_regions, ell, patch))
    draws = _draws(rover, lab, 12, seed=7)  # the ground leaves the new regions the map's
    jobs = [
        MoveJob(Pose2D(0.8 + 0.2 * (i % 4), 4.4 + 0.3 * (i // 4), 0.5 * i), steps, d)
        for i, (d, steps) in enumerate(
            zip(draws, [((1, 40, 20000),), ((3, 30, 15484), (1, 50, 15000))] * 6, strict=True)
        )
    ]
    c = play_moves(rover, world, jobs, dt_s=0.01, settle_s=0.5, kernel="c")
    plain = play_moves(rover, world, jobs, dt_s=0.01, settle_s=0.5, kernel="numpy")
    assert np.allclose(c, plain, rtol=0.0, atol=1e-12)
    # The two regions matter: the same jobs end elsewhere on the lab as it is.
    on_lab = play_moves(rover, lab, jobs, dt_s=0.01, settle_s=0.5, kernel="c")
    assert np.abs(c - on_lab).max() > 1e-3
    start = Pose2D(0.8, 5.0, 0.0)
    steps = [(1, 60, 28750), (3, 30, 15484), (1, 40, 20000)]
    batch_c, batch_plain = (
        play_batch(
            rover,
            world,
            draws,
            steps,
            dt_s=0.01,
            safety_margin_m=0.1,
            start=start,
            record_every_s=0.5,
            kernel=kernel,
        )
        for kernel in ("c", "numpy")
    )
    assert np.array_equal(batch_c.final_tick, batch_plain.final_tick)
    assert np.allclose(batch_c.poses, batch_plain.poses, atol=1e-9, equal_nan=True)


def test_the_forces_refuse_arrays_of_the_wrong_shape(rover: RoverDescription) -> None:
    world = load_map("scn01")
    forces = _Forces(rover, world, _draws(rover, world, 3, seed=1))
    lib = batch_kernel.load()
    prepared = batch_kernel.Prepared(forces, dt_s=0.01, probe_m=_WHEEL_PROBE_RADIUS_M)
    offsets = np.zeros((3, 2))
    with pytest.raises(ValueError, match="3 \\* n contiguous float64"):
        batch_kernel.Forces(lib, prepared, offsets, np.zeros(8))
    out = np.zeros(9)
    compute = batch_kernel.Forces(lib, prepared, offsets, out)
    with pytest.raises(ValueError, match=r"state must be \(3, 6\) and contiguous"):
        compute(np.zeros((3, 6))[:, ::-1], 0.1, 0.1)
    with pytest.raises(ValueError, match=r"state must be \(3, 6\)"):
        compute(np.zeros((2, 6)), 0.1, 0.1)
    state = np.zeros((3, 6))
    state[:, 0:2] = (1.0, 4.0)
    compute(state, 0.1, 0.1)  # at rest, wheels turning: each pushed forward (yaw 0)
    assert (out[0::3] > 0.0).all() and np.allclose(out[1::3], 0.0, atol=1e-9)
