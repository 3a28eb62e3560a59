"""Traffic log writers and reader, on streams or by path (docs/traffic-logs.md).

The records, the serial frame-log format and the decoding are pure
(:mod:`firmware_proto.linkio.trafficlog`); this module turns records into log files and
back, for both ends of the link. A writer (:class:`LogWriter`) is an endpoint's
listener. CAN logs are python-can's formats by suffix (:data:`CAN_LOG_FORMATS`): ``.log``
(candump ``-L``, flushed per frame) and ``.blf`` (buffered until closed); other suffixes
are refused (docs/traffic-logs.md says why). Writers and the reader own the streams they
are given, as python-can's do.
"""

from __future__ import annotations

import io
import logging
import struct
import threading
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path, PurePath
from types import TracebackType
from typing import IO, Any, BinaryIO, TextIO

import can
from can.io.blf import BLFParseError

from firmware_proto.linkio.media import MEDIA
from firmware_proto.linkio.trafficlog import (
    SERIAL_LOG_MAGIC,
    CanRecord,
    SerialRecord,
    TrafficRecord,
    format_serial_record,
    parse_serial_log,
    serial_log_header,
)

__all__ = [
    "CAN_LOG_FORMATS",
    "MEDIA",
    "CanLogFormat",
    "CanLogWriter",
    "LogFile",
    "LogWriter",
    "SerialLogWriter",
    "can_record",
    "keep_previous",
    "open_recorder",
    "parse_log",
    "read_log",
    "writer_for",
]

logger = logging.getLogger(__name__)


class LogWriter(ABC):
    """A recorder writing one log (a :class:`~firmware_proto.linkio.trafficlog.TrafficRecorder`).

    :meth:`record` is thread-safe and checks the record type. Times never go back in a log:
    a record stamped earlier than the one before it (two threads racing to the log) takes
    that one's time, so file order is time order. An implementation fills :meth:`_write`
    (one record, under the lock) and :meth:`_close` (finish the log, close the stream,
    called once). :attr:`frames` counts the records written.
    """

    record_type: type[SerialRecord] | type[CanRecord]
    """The records this log holds."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._closed = False
        self._last_time_s = float("-inf")
        self.frames = 0

    def record(self, entry: TrafficRecord) -> None:
        """Append one frame; after :meth:`close`, drop it (a reader thread may still hand one
        over while its owner shuts down).

        Raises:
            TypeError: a record of the other medium.
            OSError: the stream failed (disk full); callers log it once and carry on.
        """
        if not isinstance(entry, self.record_type):
            raise TypeError(f"a {self.record_type.__name__} log cannot hold {entry!r}")
        with self._lock:
            if self._closed:
                return
            if entry.time_s < self._last_time_s:
                entry = replace(entry, time_s=self._last_time_s)
            self._last_time_s = entry.time_s
            self._write(entry)
            self.frames += 1

    def close(self) -> None:
        """Finish the log and close its stream (idempotent)."""
        with self._lock:
            if not self._closed:
                self._closed = True
                self._close()

    @abstractmethod
    def _write(self, entry: Any) -> None:
        """Write one record of :attr:`record_type` and flush it where the format can."""

    @abstractmethod
    def _close(self) -> None:
        """Finish the log and close the stream."""

    def __enter__(self) -> LogWriter:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


class SerialLogWriter(LogWriter):
    """Writes a serial frame log to a text stream, one line per frame, each flushed as it
    is written, so that a log survives a crash up to its last frame."""

    record_type = SerialRecord

    def __init__(self, stream: TextIO, metadata: Mapping[str, str] | None = None) -> None:
        """Write the header (``# key: value`` lines of ``metadata``: role, device...) to
        ``stream``, a writable text stream at its start, which the writer owns from here on;
        OSError if it cannot."""
        super().__init__()
        self._stream = stream
        stream.write(serial_log_header(metadata))
        stream.flush()

    def _write(self, entry: SerialRecord) -> None:
        self._stream.write(format_serial_record(entry))
        self._stream.flush()

    def _close(self) -> None:
        self._stream.close()


class CanLogWriter(LogWriter):
    """Feeds CAN records to one of python-can's log writers, e.g.
    ``CanLogWriter(can.CanutilsLogWriter(text_stream, channel="can0"))``; a writer with a
    ``file`` is flushed after every frame."""

    record_type = CanRecord

    def __init__(self, writer: can.Listener) -> None:
        """Own ``writer`` (a python-can ``can.io`` writer): closing this one stops it, which
        closes its file."""
        super().__init__()
        self._writer = writer

    def _write(self, entry: CanRecord) -> None:
        self._writer.on_message_received(
            can.Message(
                timestamp=entry.time_s,
                arbitration_id=entry.arbitration_id,
                data=entry.data,
                is_extended_id=entry.is_extended_id,
                is_remote_frame=entry.is_remote_frame,
                is_error_frame=entry.is_error_frame,
                is_rx=entry.is_rx,
                channel=entry.channel or None,
            )
        )
        file = getattr(self._writer, "file", None)
        if file is not None:
            file.flush()

    def _close(self) -> None:
        self._writer.stop()


@dataclass(frozen=True)
class CanLogFormat:
    """A python-can log format that traffic logs are recorded in and read from.

    Attributes:
        name: what the format is called.
        binary: its stream is bytes; otherwise ASCII text (:meth:`stream`).
        writer: python-can's writer on such a stream, given the channel name for frames
            that carry none.
        reader: python-can's reader on such a stream.
    """

    # The stream is Any: BinaryIO or TextIO as ``binary`` says, which no type can say.
    name: str
    binary: bool
    writer: Callable[[Any, str], can.Listener]
    reader: Callable[[Any], Iterable[can.Message]]

    def stream(self, binary: BinaryIO) -> IO[Any]:
        """``binary`` as this format's writers and readers want it (ASCII text or as is)."""
        return binary if self.binary else io.TextIOWrapper(binary, "ascii", newline="\n")


CAN_LOG_FORMATS: Mapping[str, CanLogFormat] = {
    ".log": CanLogFormat(
        name="candump -L",
        binary=False,
        writer=lambda f, ch: can.CanutilsLogWriter(f, channel=ch),
        reader=can.CanutilsLogReader,
    ),
    ".blf": CanLogFormat(
        name="Vector BLF",
        binary=True,
        writer=lambda f, ch: can.BLFWriter(f),
        reader=can.BLFReader,
    ),
}
"""CAN log formats by file suffix (see the module docstring for those refused)."""


def _can_format(suffix: str) -> CanLogFormat:
    try:
        return CAN_LOG_FORMATS[suffix.lower()]
    except KeyError:
        raise ValueError(
            f"cannot record CAN traffic to a {suffix or 'suffix-less'!r} file; known: "
            f"{', '.join(CAN_LOG_FORMATS)} (convert with python -m can.logconvert)"
        ) from None


def writer_for(
    medium: str,
    suffix: str,
    *,
    channel: str = "",
    metadata: Mapping[str, str] | None = None,
) -> Callable[[BinaryIO], LogWriter]:
    """The writer for a log of ``medium`` (``"serial"``, any suffix, ``.rlog`` by custom; or
    ``"can"``) in a file with ``suffix`` (dot included), as a function of the binary stream
    to write to (which it then owns, closing it if it fails to start). ``channel``: CAN, the
    channel name for frames that carry none; ``metadata``: serial, the header's lines.

    Raises:
        ValueError: an unknown medium, or a suffix no CAN format has; before anything opens.
    """
    if medium == "serial":

        def serial(binary: BinaryIO) -> LogWriter:
            return SerialLogWriter(io.TextIOWrapper(binary, "ascii", newline="\n"), metadata)

        return _owning(serial)
    if medium == "can":
        fmt = _can_format(suffix)

        def can_log(binary: BinaryIO) -> LogWriter:
            return CanLogWriter(fmt.writer(fmt.stream(binary), channel or "can0"))

        return _owning(can_log)
    raise ValueError(f"unknown medium {medium!r}; known: {', '.join(MEDIA)}")


def _owning(make: Callable[[BinaryIO], LogWriter]) -> Callable[[BinaryIO], LogWriter]:
    def start(binary: BinaryIO) -> LogWriter:
        try:
            return make(binary)
        except BaseException:
            binary.close()
            raise

    return start


@dataclass(frozen=True)
class LogFile:
    """A traffic log read back: ``kind`` is ``"serial"`` or ``"can"``; ``path`` names
    where it came from (for messages)."""

    path: PurePath
    kind: str
    records: tuple[TrafficRecord, ...]
    metadata: dict[str, str] = field(default_factory=dict)


def _in_time_order(records: Iterable[TrafficRecord]) -> tuple[TrafficRecord, ...]:
    return tuple(sorted(records, key=lambda r: r.time_s))  # stable: ties keep file order


def can_record(msg: can.Message, channel: str, *, is_rx: bool, time_s: float) -> CanRecord:
    """The traffic record of a python-can frame (data, identifier and flags from ``msg``;
    where, which way and when from the caller, who knows them best)."""
    return CanRecord(
        time_s=time_s,
        channel=channel,
        arbitration_id=msg.arbitration_id,
        data=bytes(msg.data),
        is_rx=is_rx,
        is_extended_id=msg.is_extended_id,
        is_remote_frame=msg.is_remote_frame,
        is_error_frame=msg.is_error_frame,
    )


def _logged_can_record(msg: can.Message) -> CanRecord:
    """A frame read back from a CAN log, as the log has it."""
    channel = str(msg.channel) if msg.channel is not None else ""
    return can_record(msg, channel, is_rx=bool(msg.is_rx), time_s=float(msg.timestamp))


def parse_log(stream: BinaryIO, path: str | PurePath) -> LogFile:
    """Read a serial frame log or a CAN log, told apart by content (the serial log's first
    line), then by the suffix of ``path`` (named for messages, not opened). ``stream`` is a
    seekable binary stream at the log's start, closed on return and on error. Records come
    sorted (stably) by time.

    Raises:
        OSError: the stream cannot be read.
        ValueError: neither a serial frame log nor a CAN log of a known suffix, or a
            malformed line or record.
    """
    path = PurePath(path)
    with stream:
        head = stream.read(len(SERIAL_LOG_MAGIC) + 2)
        stream.seek(0)
        if head.startswith(SERIAL_LOG_MAGIC.encode()):
            with io.TextIOWrapper(stream, "ascii") as text:
                parsed = parse_serial_log(text)
            return LogFile(path, "serial", _in_time_order(parsed.records), parsed.metadata)
        fmt = CAN_LOG_FORMATS.get(path.suffix.lower())
        if fmt is None:
            raise ValueError(
                f"{path}: not a serial frame log (no {SERIAL_LOG_MAGIC!r} line) and not a "
                f"CAN log of a known suffix ({', '.join(CAN_LOG_FORMATS)})"
            )
        with fmt.stream(stream) as wrapped:
            try:
                records = [_logged_can_record(msg) for msg in fmt.reader(wrapped)]
            except (ValueError, IndexError, struct.error, BLFParseError) as exc:
                raise ValueError(f"{path}: malformed {fmt.name} log: {exc}") from exc
    return LogFile(path, "can", _in_time_order(records))


def open_recorder(
    path: str | Path, medium: str, *, channel: str = "", metadata: Mapping[str, str] | None = None
) -> LogWriter:
    """A new log of ``medium`` at ``path``, in the format its suffix calls for; a log
    already there is kept (:func:`keep_previous`). ``metadata`` heads a serial log (where
    ``rover replay`` finds the emulator's seed, speed factor and map). Raises as
    :func:`writer_for` (before the file is made), and OSError when it cannot be made."""
    target = Path(path)
    start = writer_for(medium, target.suffix, channel=channel, metadata=metadata)
    keep_previous(target)
    return start(target.open("xb"))


def keep_previous(path: Path) -> Path | None:
    """Rename a non-empty file at ``path`` to ``<stem>.<n><suffix>`` beside it, ``n``
    the first free from 1 (the suffix kept, so its format is still known), and return
    the new name; an empty one is removed. ``None`` when there was nothing to keep."""
    try:
        size = path.stat().st_size
    except FileNotFoundError:
        return None
    if size == 0:
        path.unlink()
        return None
    for n in range(1, 100_000):
        kept = path.with_name(f"{path.stem}.{n}{path.suffix}")
        if not kept.exists():
            path.rename(kept)
            logger.info("kept the previous recording %s as %s", path, kept)
            return kept
    raise FileExistsError(f"{path}: 99,999 earlier recordings beside it; move them away")


def read_log(path: str | Path) -> LogFile:
    """The traffic log at ``path``, serial or CAN; raises OSError (unreadable) and
    ValueError (not a log) as :func:`parse_log` says."""
    return parse_log(Path(path).open("rb"), path)
