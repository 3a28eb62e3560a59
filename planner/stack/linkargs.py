"""The emulated link's options that ``rover stack up`` and ``rover demo`` share:
``--rtt``, ``--jitter`` and ``--loss``, passed to the link relay (``rover link``, whose
options they are; docs/ground.md, "A degraded link in one command")."""

from __future__ import annotations

import argparse

from firmware_proto.cli import values

__all__ = ["add_link_arguments"]


def add_link_arguments(p: argparse.ArgumentParser) -> None:
    """``--rtt S``, ``--jitter S`` (mission seconds) and ``--loss P`` (0 <= P < 1)."""
    group = p.add_argument_group("the emulated link (rover link; docs/ground.md)")
    group.add_argument(
        "--rtt",
        type=values.non_negative,
        default=3.0,
        metavar="S",
        help="link round trip, s (default 3: Earth-Moon)",
    )
    group.add_argument(
        "--jitter",
        type=values.non_negative,
        default=0.0,
        metavar="S",
        help="extra one-way delay of each message, uniform in 0..S s (default 0); a topic's "
        "messages keep their order",
    )
    group.add_argument(
        "--loss",
        type=values.loss_ratio,
        default=0.0,
        metavar="P",
        help="share of messages lost each way, 0 <= P < 1 (default 0; drawn per topic from --seed)",
    )
