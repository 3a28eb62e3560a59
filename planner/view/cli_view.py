"""The options of the live view and the MCAP recording, shared by ``rover go`` and
``rover demo`` (light: imported when the command line is built)."""

from __future__ import annotations

import argparse
import os
from typing import TYPE_CHECKING

from firmware_proto.cli import values

if TYPE_CHECKING:
    from planner.view.server import ViewConfig

__all__ = ["TOKEN_ENV", "add_view_arguments", "view_config"]

TOKEN_ENV = "ROVER_VIEW_TOKEN"
"""Environment variable holding the view's token when ``--view-token-file`` is not given."""


def add_view_arguments(p: argparse.ArgumentParser, *, record_default: str | None) -> None:
    """``--view`` and its options, and ``--record`` (default ``record_default``)."""
    p.add_argument(
        "--view",
        action="store_true",
        help="serve the live view (the ghost against the rover, drift, STOP button) and "
        "print its URL",
    )
    p.add_argument(
        "--view-host",
        default="127.0.0.1",
        help="address the view binds (default 127.0.0.1; any other needs a token)",
    )
    p.add_argument(
        "--view-port", type=values.tcp_port, default=0, help="view port (default: a free one)"
    )
    p.add_argument(
        "--view-token-file",
        default=None,
        metavar="PATH",
        help=f"view bearer token, read from this file (or set ${TOKEN_ENV}); a "
        "non-loopback --view-host needs one",
    )
    p.add_argument("--view-token", default=None, help=argparse.SUPPRESS)  # refused
    p.add_argument(
        "--view-allowed-host",
        action="append",
        default=[],
        metavar="NAME",
        help="a further name browsers reach the view by (the Host header; repeatable)",
    )
    p.add_argument(
        "--view-hold",
        type=float,
        default=0.0,
        metavar="S",
        help="keep the view (and the demo's processes) up this long after the mission "
        "(Ctrl-C ends it early; default 0)",
    )
    p.add_argument(
        "--view-wait",
        type=float,
        default=0.0,
        metavar="S",
        help="before the mission starts, wait up to this long for a browser to open the "
        "view (default 0: do not wait)",
    )
    p.add_argument(
        "--foxglove",
        type=values.tcp_port,
        nargs="?",
        const=8765,
        default=None,
        metavar="PORT",
        help="also serve the mission live to Foxglove (foxglove-sdk WebSocket server on "
        "127.0.0.1, PORT default 8765, 0 a free one)",
    )
    if record_default is None:
        p.add_argument(
            "--record",
            default=None,
            metavar="FILE.mcap",
            help="record every ROS message the ground station sees and sends, and the gate's "
            "predicted trajectories, as ROS 2 MCAP",
        )
    else:
        p.add_argument(
            "--record",
            default=record_default,
            metavar="FILE.mcap",
            help="where to record the mission as ROS 2 MCAP: every ROS message the ground "
            f"station sees and sends, and the gate's predictions (default {record_default})",
        )
        p.add_argument("--no-record", action="store_true", help="record nothing")


def view_config(args: argparse.Namespace) -> ViewConfig | None:
    """The view's configuration from the options, ``None`` without ``--view``
    (``ValueError``: a bad option, such as a non-loopback address without a token)."""
    if not args.view:
        return None
    from firmware_proto.http.tokenfile import read_token_file, refuse_token_argument
    from planner.view.server import ViewConfig

    if args.view_token is not None:
        raise refuse_token_argument("--view-token", "--view-token-file", TOKEN_ENV)
    if args.view_token_file:
        token: str | None = read_token_file(args.view_token_file, what="view token")
    else:
        token = os.environ.get(TOKEN_ENV) or None
    return ViewConfig(
        host=args.view_host,
        port=args.view_port,
        token=token,
        allowed_hosts=tuple(args.view_allowed_host),
        hold_s=args.view_hold,
        wait_s=args.view_wait,
    )
