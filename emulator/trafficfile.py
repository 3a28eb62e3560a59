"""The emulator's traffic log files, opened by path: the file edge of
:mod:`firmware_proto.trafficio` for ``rover emulate --record`` and ``rover replay
--emulator`` (docs/traffic-logs.md).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

from firmware_proto.trafficio import LogFile, LogWriter, parse_log, writer_for

__all__ = ["open_recorder", "read_log"]


def open_recorder(
    path: str | Path, medium: str, *, channel: str = "", metadata: Mapping[str, str] | None = None
) -> LogWriter:
    """A recorder for the controller's end of the link: a new log at ``path`` (created or
    truncated) in the format its medium and suffix call for
    (:func:`~firmware_proto.trafficio.writer_for`); ``metadata`` heads a serial log,
    where ``rover replay`` finds the emulator's seed, speed factor and map. An unknown
    medium or suffix is a ValueError before any file is created; an OSError means the file
    could not be."""
    start = writer_for(medium, Path(path).suffix, channel=channel, metadata=metadata)
    return start(Path(path).open("wb"))


def read_log(path: str | Path) -> LogFile:
    """A recorded session to replay into the emulator, from the log at ``path``
    (:func:`~firmware_proto.trafficio.parse_log`; OSError, or ValueError for a file that is
    no traffic log)."""
    return parse_log(Path(path).open("rb"), path)
