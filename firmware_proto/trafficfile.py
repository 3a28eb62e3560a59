"""Traffic log files: recorders that write serial frame logs and candump logs, and a
reader for both (docs/traffic-logs.md).

The format and the decoding are pure and live in :mod:`firmware_proto.trafficlog`; this
module is their file edge, the one place outside the command line where
``firmware_proto`` touches files. It lives here because both ends of the link record
(the bridge and the emulator), and those two packages never import each other.

- :class:`SerialLogWriter`: the serial frame log, one frame per line.
- :class:`CanLogWriter`: any log python-can writes, chosen by the file suffix
  (``.log``: candump ``-L``, the one to use; ``.asc``, ``.blf``, ``.csv``, ...).
- :func:`open_recorder` picks one for a medium; :func:`read_log` reads either kind back.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Any

import can

from firmware_proto.trafficlog import (
    SERIAL_LOG_MAGIC,
    CanRecord,
    SerialRecord,
    TrafficRecord,
    format_serial_record,
    parse_serial_log,
    serial_log_header,
)

__all__ = ["CanLogWriter", "LogFile", "SerialLogWriter", "open_recorder", "read_log"]

logger = logging.getLogger(__name__)


class SerialLogWriter:
    """Writes a serial frame log; thread-safe; each line is flushed as it is written, so
    a log survives a crash up to its last frame."""

    def __init__(self, path: str | Path, metadata: dict[str, str] | None = None) -> None:
        """Args:
        path: the log file (created or truncated).
        metadata: ``# key: value`` lines for the header (role, device, ...).

        Raises:
            OSError: the file cannot be created.
        """
        self.path = Path(path)
        self._lock = threading.Lock()
        self._file = self.path.open("w", encoding="ascii")
        self._file.write(serial_log_header(metadata))
        self._file.flush()
        self.frames = 0

    def record(self, entry: TrafficRecord) -> None:
        """Append one frame.

        Raises:
            TypeError: a CAN record (a serial log holds serial frames only).
        """
        if not isinstance(entry, SerialRecord):
            raise TypeError(f"a serial frame log cannot hold {type(entry).__name__}")
        line = format_serial_record(entry)
        with self._lock:
            if self._file.closed:
                return
            self._file.write(line)
            self._file.flush()
            self.frames += 1

    def close(self) -> None:
        """Close the file (idempotent)."""
        with self._lock:
            if not self._file.closed:
                self._file.close()

    def __enter__(self) -> SerialLogWriter:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


class CanLogWriter:
    """Writes CAN frames through python-can's log writers (``can.Logger``, by suffix);
    thread-safe; text formats are flushed per frame."""

    def __init__(self, path: str | Path, channel: str = "can0") -> None:
        """Args:
        path: the log file; its suffix picks the format (``.log`` for candump).
        channel: the channel name written for frames that carry none.

        Raises:
            ValueError: python-can cannot write this suffix.
            OSError: the file cannot be created.
        """
        self.path = Path(path)
        self._lock = threading.Lock()
        self._writer: Any = can.Logger(str(self.path), channel=channel)
        self._closed = False
        self.frames = 0

    def record(self, entry: TrafficRecord) -> None:
        """Append one frame.

        Raises:
            TypeError: a serial record.
        """
        if not isinstance(entry, CanRecord):
            raise TypeError(f"a CAN log cannot hold {type(entry).__name__}")
        msg = can.Message(
            timestamp=entry.time_s,
            arbitration_id=entry.arbitration_id,
            data=entry.data,
            is_extended_id=entry.is_extended_id,
            is_remote_frame=entry.is_remote_frame,
            is_error_frame=entry.is_error_frame,
            is_rx=entry.is_rx,
            channel=entry.channel or None,
        )
        with self._lock:
            if self._closed:
                return
            self._writer.on_message_received(msg)
            file = getattr(self._writer, "file", None)
            if file is not None and hasattr(file, "flush"):
                file.flush()
            self.frames += 1

    def close(self) -> None:
        """Finish and close the log (idempotent)."""
        with self._lock:
            if not self._closed:
                self._closed = True
                self._writer.stop()

    def __enter__(self) -> CanLogWriter:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


def open_recorder(
    path: str | Path,
    medium: str,
    *,
    channel: str = "",
    metadata: dict[str, str] | None = None,
) -> SerialLogWriter | CanLogWriter:
    """A recorder for ``medium`` (``"serial"`` or ``"can"``) writing to ``path``.

    Raises:
        ValueError: unknown medium, or a suffix python-can cannot write.
        OSError: the file cannot be created.
    """
    if medium == "serial":
        return SerialLogWriter(path, metadata)
    if medium == "can":
        return CanLogWriter(path, channel or "can0")
    raise ValueError(f"unknown medium {medium!r}; known: serial, can")


@dataclass(frozen=True)
class LogFile:
    """A traffic log read back: ``kind`` is ``"serial"`` or ``"can"``."""

    path: Path
    kind: str
    records: tuple[TrafficRecord, ...]
    metadata: dict[str, str] = field(default_factory=dict)


def _in_time_order(records: Iterable[TrafficRecord]) -> tuple[TrafficRecord, ...]:
    return tuple(sorted(records, key=lambda r: r.time_s))  # stable: ties keep file order


def read_log(path: str | Path) -> LogFile:
    """Read a serial frame log or any CAN log python-can reads, told apart by content
    (the serial log's first line) and then by suffix. Records come in time order: a
    recorder writes a sent frame once its send returned, so the answer to it may come
    first in the file (its time, taken before the send, is earlier).

    Raises:
        OSError: the file cannot be read.
        ValueError: neither a serial frame log nor a CAN log python-can can read, or a
            malformed line (DecodeError names it).
    """
    path = Path(path)
    with path.open("rb") as f:
        head = f.read(len(SERIAL_LOG_MAGIC) + 2)
    if head.startswith(SERIAL_LOG_MAGIC.encode()):
        with path.open(encoding="ascii") as f:
            parsed = parse_serial_log(f)
        return LogFile(path, "serial", _in_time_order(parsed.records), parsed.metadata)
    try:
        reader: Any = can.LogReader(str(path))
    except ValueError as exc:
        raise ValueError(
            f"{path}: not a serial frame log (no {SERIAL_LOG_MAGIC!r} line) and not a CAN "
            f"log python-can reads ({exc})"
        ) from None
    records: list[TrafficRecord] = []
    try:
        for msg in reader:
            records.append(
                CanRecord(
                    time_s=float(msg.timestamp),
                    channel=str(msg.channel) if msg.channel is not None else "",
                    arbitration_id=msg.arbitration_id,
                    data=bytes(msg.data),
                    is_rx=bool(msg.is_rx),
                    is_extended_id=msg.is_extended_id,
                    is_remote_frame=msg.is_remote_frame,
                    is_error_frame=msg.is_error_frame,
                )
            )
    except (ValueError, IndexError) as exc:
        raise ValueError(f"{path}: malformed CAN log: {exc}") from exc
    finally:
        reader.stop()
    return LogFile(path, "can", _in_time_order(records))
