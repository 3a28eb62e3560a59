"""What a stack (``rover stack up``) tells the commands that talk to it, and how they
take it: environment variables and the ``--domain`` option.

A stack runs on a ROS 2 domain of its own (:data:`DOMAIN_ENV`) with discovery kept on
this host (:data:`RANGE_ENV`), so two stacks never hear each other. It prints (and
``rover stack env`` prints again) one ``export`` line (:func:`export_line`); the
operator's commands read those variables, or take ``--domain N``
(:func:`add_domain_argument`, :func:`apply_domain`).
"""

from __future__ import annotations

import argparse
import os
import shlex
from collections.abc import Mapping, MutableMapping
from pathlib import Path

from firmware_proto.cli import values
from firmware_proto.model.uplink import TOKEN_ENV as UPLINK_TOKEN_ENV
from firmware_proto.runtime.stall import STALL_LOG_ENV
from planner.ground.console_client import CONSOLE_ENV

__all__ = [
    "CONTROL_ENV",
    "DOMAIN_ENV",
    "GATE_ENV",
    "RANGE_ENV",
    "RTT_ENV",
    "SCALE_ENV",
    "TWIN_ENV",
    "UPLINK_TOKEN_ENV",
    "add_domain_argument",
    "apply_domain",
    "env_default",
    "export_line",
    "stack_environment",
]

DOMAIN_ENV = "ROS_DOMAIN_ID"
"""ROS 2's domain id variable (read when a ROS port's context starts)."""
RANGE_ENV = "ROS_AUTOMATIC_DISCOVERY_RANGE"
"""ROS 2 Jazzy's discovery range; a stack sets it to ``LOCALHOST``."""
GATE_ENV = "ROVER_GATE_URL"
"""The gate's URL; ``rover go`` reads it when ``--gate`` is not given."""
CONTROL_ENV = "ROVER_STACK_CONTROL"
"""``HOST:PORT`` of the stack's emulator control interface (``rover stack inject``)."""
RTT_ENV = "ROVER_LINK_RTT"
"""The stack's link round trip in wall seconds; ``rover go --rtt`` defaults to it."""
SCALE_ENV = "ROVER_TIME_SCALE"
"""The stack's mission seconds per wall second; ``rover go --time-scale`` defaults to it."""
TWIN_ENV = "ROVER_TWIN"
"""The calibrated twin file the stack's gate plays plans on (``rover stack up --twin``); ``rover go
--rover`` defaults to it, so that the planner turns by the twin's turn efficiency."""


def add_domain_argument(p: argparse.ArgumentParser) -> None:
    """``--domain N``: the ROS 2 domain to talk on (default ``$ROS_DOMAIN_ID``, else 0)."""
    p.add_argument(
        "--domain",
        type=values.domain_id,
        default=None,
        metavar="N",
        help=(
            f"ROS 2 domain id of the stack to talk to (default ${DOMAIN_ENV}, else 0; "
            "'rover stack up' prints its own); keeps discovery on this host"
        ),
    )


def apply_domain(
    args: argparse.Namespace, env: MutableMapping[str, str] | None = None
) -> int | None:
    """Put ``--domain`` into the environment the ROS port reads (and keep discovery on
    this host, as the stack does); returns the domain in effect, ``None`` when neither
    the option nor the variable gives one (ROS 2's default, 0)."""
    env = os.environ if env is None else env
    domain = getattr(args, "domain", None)
    if domain is not None:
        env[DOMAIN_ENV] = str(domain)
        env.setdefault(RANGE_ENV, "LOCALHOST")
        return int(domain)
    text = env.get(DOMAIN_ENV, "").strip()
    return values.check(values.domain_id, text, DOMAIN_ENV) if text else None


def stack_environment(
    domain: int,
    gate_url: str,
    control: str,
    rtt_s: float = 3.0,
    speed: float = 1.0,
    stall_log: Path | None = None,
    *,
    twin: Path | None = None,
    console: str = "",
    uplink_token: str = "",
) -> dict[str, str]:
    """The variables a stack exports: ``rtt_s`` in mission seconds, ``speed`` mission
    seconds per wall second; ``stall_log`` its parts' stall log (docs/realtime.md);
    ``twin`` its gate's calibrated twin; ``console`` its console socket's URL
    (:mod:`planner.stack.console_server`); ``uplink_token`` the key its onboard program
    checks plans with (``ROVER_UPLINK_TOKEN``)."""
    variables = {
        DOMAIN_ENV: str(domain),
        RANGE_ENV: "LOCALHOST",
        GATE_ENV: gate_url,
        CONTROL_ENV: control,
        RTT_ENV: f"{rtt_s / speed:g}",
        SCALE_ENV: f"{speed:g}",
    }
    if stall_log is not None:
        variables[STALL_LOG_ENV] = str(stall_log)
    if twin is not None:
        variables[TWIN_ENV] = str(twin)
    if console:
        variables[CONSOLE_ENV] = console
    if uplink_token:
        variables[UPLINK_TOKEN_ENV] = uplink_token
    return variables


def env_default(name: str, fallback: float, env: Mapping[str, str] | None = None) -> float:
    """A number option's default from the environment (a stack's export), else
    ``fallback``; a variable that is not a finite number >= 0 is ignored."""
    text = (os.environ if env is None else env).get(name, "").strip()
    try:
        return values.non_negative(text) if text else fallback
    except ValueError:
        return fallback


def export_line(variables: Mapping[str, str]) -> str:
    """One shell line: ``export NAME=value ...`` (quoted where needed)."""
    return "export " + " ".join(f"{k}={shlex.quote(v)}" for k, v in variables.items())
