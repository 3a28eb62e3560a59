"""``rover replay --emulator``: the emulator's replay target (options:
:mod:`firmware_proto.cli.replay`; what it does: :mod:`emulator.emulator_replay`)."""

from __future__ import annotations

import argparse
import os
from collections.abc import Mapping

__all__ = ["LEGACY_EMULATE_DT_S", "recorded_dt_s", "run"]

LEGACY_EMULATE_DT_S = 0.001
"""The step of ``rover emulate`` logs older than ``dt_s``, s of twin time (any speed factor)."""


def recorded_dt_s(metadata: Mapping[str, str]) -> float | None:
    """The twin step (s) a traffic log was recorded at: its ``dt_s``; for an older
    emulator log (``speed_factor`` only) :data:`LEGACY_EMULATE_DT_S`; ``None`` for
    another recorder's log (``rover emulate``'s default applies)."""
    if metadata.get("dt_s"):
        return float(metadata["dt_s"])
    if "speed_factor" in metadata:
        return LEGACY_EMULATE_DT_S
    return None


def run(args: argparse.Namespace) -> int:
    """Replay ``args.log`` into a fresh emulator and print the report; 0 if alike, else 1."""
    from emulator.emulator_replay import ReplayOptions, replay_into_emulator
    from firmware_proto.linkio.trafficio import open_recorder, read_log

    log = read_log(args.log)
    meta = log.metadata
    interface, channel = "virtual", f"rover-replay-{os.getpid()}"
    if args.can:
        interface, sep, channel = args.can.partition(":")
        if not sep or not interface or not channel:
            raise ValueError(f"--can needs INTERFACE:CHANNEL, got {args.can!r}")
    options = ReplayOptions(
        seed=args.seed if args.seed is not None else int(meta.get("seed", "0")),
        speed_factor=(
            args.speed_factor
            if args.speed_factor is not None
            else float(meta.get("speed_factor", "1"))
        ),
        dt_s=recorded_dt_s(meta),
        map_name=args.map or meta.get("map") or "lab",
        rover_path=args.rover or meta.get("rover", ""),
        node=args.node,
        can_interface=interface,
        can_channel=channel,
        strict=args.strict,
        edge_s=args.edge,
    )
    if options.speed_factor <= 0 or args.edge < 0:
        raise ValueError("--speed-factor must be > 0 and --edge >= 0")
    recorder = (
        open_recorder(args.record, log.kind, channel=channel, metadata={"role": "replay"})
        if args.record
        else None
    )
    try:
        result = replay_into_emulator(log, options, recorder=recorder)
    finally:
        if recorder is not None:
            recorder.close()
    print(
        f"{log.path}: {log.kind} log, {len(log.records)} frames; emulator seed "
        f"{options.seed}, speed factor {options.speed_factor:g}, map {options.map_name}"
    )
    print(result.report())
    return 0 if result.ok else 1
