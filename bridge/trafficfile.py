"""The bridge's traffic log files, opened by path: the file edge of
:mod:`firmware_proto.trafficio` for the bridge node (``record``), ``rover bench stop
--record``, ``rover decode`` and ``rover replay --bridge`` (docs/traffic-logs.md).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

from firmware_proto.trafficio import LogFile, LogWriter, parse_log, writer_for

__all__ = ["open_recorder", "read_log"]


def open_recorder(
    path: str | Path, medium: str, *, channel: str = "", metadata: Mapping[str, str] | None = None
) -> LogWriter:
    """A recorder for the host's end of the link: a new log of ``medium`` (``"serial"``,
    ``"can"``) at ``path``, created or truncated, in the format its suffix calls for
    (:func:`~firmware_proto.trafficio.writer_for`, whose ValueError comes before the file
    is made; OSError: it cannot be made)."""
    start = writer_for(medium, Path(path).suffix, channel=channel, metadata=metadata)
    return start(Path(path).open("wb"))


def read_log(path: str | Path) -> LogFile:
    """The traffic log at ``path``, serial or CAN; raises OSError (unreadable) and
    ValueError (not a log) as :func:`~firmware_proto.trafficio.parse_log` says."""
    return parse_log(Path(path).open("rb"), path)
