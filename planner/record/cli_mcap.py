"""``rover decode mission.mcap``: a summary of a recorded mission (plugged into ``rover
decode`` through the ``rover.decode`` entry point)."""

from __future__ import annotations

import argparse
import json

__all__ = ["run"]


def run(args: argparse.Namespace) -> int:
    """Print the summary of ``args.log`` (``--json``: as one JSON object)."""
    from planner.record.mcaprec import read_summary

    summary = read_summary(args.log)
    if getattr(args, "json", False):
        print(
            json.dumps(
                {
                    "counts": summary.counts,
                    "types": summary.types,
                    "first_pose": summary.first_pose,
                    "last_pose": summary.last_pose,
                    "start_ns": summary.start_ns,
                    "end_ns": summary.end_ns,
                }
            )
        )
        return 0
    print(f"{args.log}: ROS 2 MCAP")
    print(summary.text())
    return 0
