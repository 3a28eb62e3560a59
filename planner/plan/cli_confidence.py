"""The confidence options of ``rover go`` and ``rover demo`` (``--max-collision-p``,
``--samples``): light, so that building the ``rover`` parser imports no gate client."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from planner.plan.gate_client import GateOptions

__all__ = ["DEFAULT_CONFIDENCE_SAMPLES", "add_confidence_arguments", "confidence_options"]

DEFAULT_CONFIDENCE_SAMPLES = 200
"""Twins a ``--max-collision-p`` check plays when ``--samples`` is not given."""


def add_confidence_arguments(p: Any) -> None:
    """``--max-collision-p P`` and ``--samples N`` of ``rover go`` and ``rover demo``
    (an :class:`argparse.ArgumentParser`)."""
    p.add_argument(
        "--max-collision-p",
        type=float,
        metavar="P",
        help="approve a plan only if at most this fraction of the gate's samples collide "
        "(twins drawn from its calibration's uncertainty, or its default spread; "
        f"{DEFAULT_CONFIDENCE_SAMPLES} samples unless --samples): e.g. 0.05",
    )
    p.add_argument(
        "--samples",
        type=int,
        metavar="N",
        help="twins the gate plays each plan on (with --max-collision-p; 2..2000)",
    )


def confidence_options(args: Any) -> tuple[GateOptions, float | None]:
    """The gate options and the collision threshold ``add_confidence_arguments`` gave
    (``ValueError``: ``--samples`` without ``--max-collision-p``, or out of range)."""
    from planner.plan.gate_client import GateOptions  # the client: not needed to build a parser

    limit: float | None = args.max_collision_p
    if limit is None:
        if args.samples is not None:
            raise ValueError("--samples is for --max-collision-p")
        return GateOptions(), None
    samples = DEFAULT_CONFIDENCE_SAMPLES if args.samples is None else args.samples
    if not 2 <= samples <= 2000 or not 0.0 <= limit <= 1.0:
        raise ValueError("--samples must be in 2..2000 and --max-collision-p in [0, 1]")
    return GateOptions(samples=samples), limit
