"""The predicted trajectory, tagged per step for a drift monitor.

The twin plays the steps back to back; the executor does not (it waits for each step's
``completed`` across a 3 s round trip), so a monitor cannot compare on one global clock.
Every sample therefore carries the index of its step and the time since that step
started. :func:`tag_samples` builds that from :func:`emulator.playback.play`'s output:
per step, its start pose (``step_t_s == 0``), the fixed-rate samples strictly inside it,
and its end pose; then the samples of the settling phase under the last step.

Times are compared as whole physics steps (``round(t / dt)``), never as floats.
"""

from __future__ import annotations

from collections.abc import Callable

from emulator.playback import PlaybackResult
from emulator.twin import Pose2D
from firmware_proto.model.pose import Pose
from firmware_proto.model.verdict import TrajectorySample

__all__ = ["tag_samples"]


def tag_samples(
    result: PlaybackResult, pose: Callable[[Pose2D], Pose], seconds: Callable[[float], float]
) -> list[TrajectorySample]:
    """Trajectory samples of the playback ``result`` tagged with their step (see the
    module docstring); ``pose`` converts the twin's pose to the verdict's (units,
    rounding), ``seconds`` rounds a time for the verdict. With no step played (the start
    pose already collides), the one sample at time 0 belongs to step 0."""

    def sample(t_s: float, step: int, step_t_s: float, p: Pose2D) -> TrajectorySample:
        return TrajectorySample(seconds(t_s), step, seconds(step_t_s), pose(p))

    dt = result.dt_s

    def tick(t: float) -> int:
        return round(t / dt)

    samples = result.samples
    if not result.steps:
        first = samples[0]
        return [sample(first.time_s, 0, 0.0, first.pose)]
    ticks = [tick(s.time_s) for s in samples]
    out: list[TrajectorySample] = []
    cursor = 0  # next fixed-rate sample not yet placed
    previous_end = samples[0].pose
    for step in result.steps:
        start_k, end_k = tick(step.start_time_s), tick(step.end_time_s)
        out.append(sample(start_k * dt, step.index, 0.0, previous_end))
        while cursor < len(samples) and ticks[cursor] <= end_k:
            k = ticks[cursor]
            if start_k < k < end_k:  # the step's own start and end are added apart
                out.append(sample(k * dt, step.index, (k - start_k) * dt, samples[cursor].pose))
            cursor += 1
        out.append(sample(end_k * dt, step.index, (end_k - start_k) * dt, step.end_pose))
        previous_end = step.end_pose
    last = result.steps[-1]
    last_start = tick(last.start_time_s)
    for k, settled in zip(ticks[cursor:], samples[cursor:], strict=True):  # settling
        out.append(sample(k * dt, last.index, (k - last_start) * dt, settled.pose))
    return out
