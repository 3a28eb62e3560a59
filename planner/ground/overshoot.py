"""The physical figures of a drift stop (:class:`Overshoot`), from the rover's own stamped
poses (``odom_ground``, stamped at measurement) and the approved plan's predicted path
(docs/onboard.md, "Measured"): where the rover crossed the limit, where it came to rest
(moved less than :data:`REST_MOVE_M` over :data:`REST_HOLD_S`), and in between. Pure:
poses in, figures out.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass

from firmware_proto.model.geometry import point_segment_distance
from firmware_proto.model.pose import Point

__all__ = ["REST_HOLD_S", "REST_MOVE_M", "Overshoot", "off_path_m", "overshoot"]

REST_MOVE_M = 0.03
"""At rest: no pose further than this from the first, m (three sigmas of POSE noise) ..."""
REST_HOLD_S = 0.3
"""... over this long, s of mission time."""


def off_path_m(path: Sequence[tuple[float, float]], x: float, y: float) -> float:
    """Distance from ``(x, y)`` to the polyline ``path``, m."""
    p = Point(x, y)
    if len(path) == 1:
        return math.dist(path[0], (x, y))
    return min(point_segment_distance(p, Point(*a), Point(*b)) for a, b in itertools.pairwise(path))


@dataclass(frozen=True)
class Overshoot:
    """How far and how long the rover went on after it strayed past the limit.

    Attributes:
        crossed: whether a pose was ever more than the limit off the path; when not,
            the figures are from the worst pose (``crossed_s`` its stamp).
        crossed_s: the stamp of the first pose past the limit (rover clock).
        past_limit_m: the distance driven from there to rest (along the poses), m.
        time_to_rest_s: from there to the first pose at rest, s.
        rest_off_path_m: how far off the path the rover came to rest, m.
        worst_off_path_m: the largest distance off the path, m.
        rest_s: the stamp of the pose at rest (``nan`` when it never settled).
    """

    crossed: bool
    crossed_s: float
    past_limit_m: float
    time_to_rest_s: float
    rest_off_path_m: float
    worst_off_path_m: float
    rest_s: float

    def line(self, limit_m: float = 0.25, time_scale: float = 1.0, *, what: str = "") -> str:
        """One line for a summary (times in mission seconds: rover seconds x
        ``time_scale``, for an emulator that runs faster); ``what`` names the crossing
        (default: ``limit_m`` off the approved path)."""
        if what:
            return (
                f"{self.past_limit_m:.3f} m driven after {what}, at rest "
                f"{self.time_to_rest_s * time_scale:.2f} s later, {self.rest_off_path_m:.3f} m "
                "off the approved path"
            )
        if not self.crossed:
            return (
                f"never {limit_m:g} m off the approved path (at most "
                f"{self.worst_off_path_m:.3f} m); at rest {self.rest_off_path_m:.3f} m off it"
            )
        return (
            f"{self.past_limit_m:.3f} m driven past {limit_m:g} m off the approved path, at "
            f"rest {self.time_to_rest_s * time_scale:.2f} s after crossing it, "
            f"{self.rest_off_path_m:.3f} m off the path"
        )


def overshoot(
    path: Sequence[tuple[float, float]],
    poses: Sequence[tuple[float, float, float]],
    limit_m: float = 0.25,
    *,
    crossing_s: float | None = None,
    time_scale: float = 1.0,
    rest_move_m: float = REST_MOVE_M,
) -> Overshoot | None:
    """The figures of ``poses`` (``(stamp_s, x, y)`` in time order) against ``path``;
    ``None`` without poses or a path.

    Args:
        crossing_s: when drift control found the limit crossed: the figures start at
            the first pose stamped then or after (``None``: the first pose ``limit_m``
            off the path).
        time_scale: mission seconds per second of the stamps; the rest's hold is
            :data:`REST_HOLD_S` of mission time.
        rest_move_m: at rest when no pose of the hold is further than this from its
            first (the figures' resolution): :data:`REST_MOVE_M` for POSE's noise, less
            for noiseless poses.
    """
    if not poses or not path:
        return None
    offs = [off_path_m(path, x, y) for _, x, y in poses]
    worst = max(offs)
    if crossing_s is not None:
        first = next((i for i, p in enumerate(poses) if p[0] >= crossing_s), None)
    else:
        first = next((i for i, off in enumerate(offs) if off > limit_m), None)
    crossed = first is not None
    start = first if first is not None else offs.index(worst)
    rest = _rest_index(poses, start, REST_HOLD_S / time_scale, rest_move_m)
    end = rest if rest is not None else len(poses) - 1
    driven = sum(math.dist(poses[i][1:], poses[i + 1][1:]) for i in range(start, end))
    return Overshoot(
        crossed,
        poses[start][0],
        driven,
        poses[end][0] - poses[start][0],
        offs[end],
        worst,
        poses[rest][0] if rest is not None else math.nan,
    )


def _rest_index(
    poses: Sequence[tuple[float, float, float]], start: int, hold_s: float, move_m: float
) -> int | None:
    """The first pose from ``start`` on after which the rover stays within ``move_m``
    for ``hold_s`` (``None``: never, in what was seen)."""
    n = len(poses)
    for i in range(start, n):
        t0, x0, y0 = poses[i]
        j = i + 1
        while j < n and poses[j][0] - t0 <= hold_s:
            if math.hypot(poses[j][1] - x0, poses[j][2] - y0) >= move_m:
                break
            j += 1
        else:
            if j < n:  # a pose past the hold, and none moved
                return i
    return None
