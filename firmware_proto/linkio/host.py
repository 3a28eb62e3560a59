"""A scripted protocol host: the host side of docs/protocol.md, driven by a script.

What tests, ``rover conformance`` and ``rover bench stop`` talk to a controller with:
:class:`ProtocolHost` owns one host-side endpoint, keeps every message received in an
:class:`~firmware_proto.linkio.inbox.Inbox`, sends messages (checked, unchecked, raw
frames, raw bytes), answers a script's questions with timeouts, and sends HOST_HEARTBEAT
every period unless :meth:`~ProtocolHost.silent`.

**Threads.** With the :data:`~firmware_proto.linkio.clock.WALL` clock, ``open`` starts a
reader thread (it only reads and appends) and a heartbeat thread. With a
:class:`~firmware_proto.linkio.clock.LockstepClock` there are none: the pump and the
heartbeat run on the clock's ticks, and every wait advances the clock. Writes happen on
the caller's (and heartbeat) thread, one at a time under a lock.
"""

from __future__ import annotations

import contextlib
import logging
import threading
from collections.abc import Callable, Iterator
from types import TracebackType
from typing import NamedTuple, TypeVar

from firmware_proto.linkio.clock import WALL, Clock, LockstepClock
from firmware_proto.linkio.endpoint import HOST, Endpoint
from firmware_proto.linkio.errors import LinkError, NotReceivedError, UnexpectedMessageError
from firmware_proto.linkio.inbox import Inbox
from firmware_proto.wire.message import Message
from firmware_proto.wire.messages import (
    HOST_HEARTBEAT_PERIOD_MS,
    PROTOCOL_VERSION,
    SCHEMA_HASH,
    ClearAck,
    ClearStop,
    Heartbeat,
    Hello,
    HostHeartbeat,
    Ident,
)

__all__ = ["HEARTBEAT_S", "ProtocolHost", "Received"]

logger = logging.getLogger(__name__)

M = TypeVar("M", bound=Message)
H = TypeVar("H", bound="ProtocolHost")

HEARTBEAT_S = HOST_HEARTBEAT_PERIOD_MS / 1000.0
"""The protocol's host heartbeat period, s."""


class Received(NamedTuple):
    """One message received, with the host clock when it was read (``arrived``, s) and the
    serial frame counter it came with (``seq``; ``None`` on CAN)."""

    arrived: float
    message: Message
    seq: int | None


def _any(_message: Message) -> bool:
    return True


class ProtocolHost:
    """A scripted host on one endpoint (see the module docstring).

    Positions (``since``) come from :meth:`mark` or a send, which returns the mark taken
    just before it. Every timeout and window is in seconds, scaled by :attr:`timeout_scale`
    (a repeat period ``every_s`` is not). Every wait raises :class:`LinkError` when the link
    failed meanwhile; every send raises it when the write failed or the host is not open.

    Args:
        endpoint: the host's end of the link, not yet open (``side`` must be host).
        clock: :data:`~firmware_proto.linkio.clock.WALL`, or a
            :class:`~firmware_proto.linkio.clock.LockstepClock` that also ticks the controller.
        heartbeat_s: HOST_HEARTBEAT period, s; ``None``: never send one.
        timeout_scale: multiplies every timeout and window (at least 1).
        keep: received messages kept (``None``: all); marks stay valid when trimmed.
    """

    def __init__(
        self,
        endpoint: Endpoint,
        *,
        clock: Clock = WALL,
        heartbeat_s: float | None = HEARTBEAT_S,
        timeout_scale: float = 1.0,
        keep: int | None = None,
    ) -> None:
        if endpoint.side != HOST:
            raise ValueError(f"a protocol host needs a host-side endpoint, got {endpoint.side}")
        self.endpoint = endpoint
        self.clock = clock
        self.heartbeat_s = heartbeat_s
        self.timeout_scale = max(1.0, timeout_scale)
        self.inbox: Inbox[Received] = Inbox(clock=clock, keep=keep)
        self._write_lock = threading.Lock()
        self._quiet = 0
        self._beats_sent = 0
        self._next_beat = 0.0
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._opened = False
        self._closed = False
        self.latch_gen = 0
        """The controller's latch generation per the last frame carrying one (docs/protocol.md,
        "Latch and faults"): what this host's CLEAR_STOP names (:meth:`clear_stop_for`)."""

    @property
    def kind(self) -> str:
        """``serial`` or ``can``: the medium."""
        return self.endpoint.medium

    @property
    def lockstep(self) -> bool:
        """Whether waits advance a lockstep world instead of sleeping."""
        return isinstance(self.clock, LockstepClock)

    def now(self) -> float:
        """The host clock, s."""
        return self.clock.now()

    # -- lifecycle ------------------------------------------------------------------------
    def open(self: H) -> H:
        """Open the endpoint and start receiving (and sending heartbeats); OSError (a
        :class:`LinkError` and its kin) when the medium cannot be opened."""
        if self._opened:
            raise RuntimeError("protocol host already open")
        self.endpoint.open()
        self._opened = True
        self._next_beat = self.clock.now() + (self.heartbeat_s or 0.0)
        if isinstance(self.clock, LockstepClock):
            self.clock.add(self._lockstep_tick)
            return self
        for target, name in ((self._reader, "host-rx"), (self._heartbeats, "host-hb")):
            if name == "host-hb" and self.heartbeat_s is None:
                continue
            thread = threading.Thread(target=target, name=name, daemon=True)
            thread.start()
            self._threads.append(thread)
        return self

    def close(self) -> None:
        """Stop the threads and close the endpoint (idempotent)."""
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        for thread in self._threads:
            thread.join(timeout=5.0)
            if thread.is_alive():
                logger.error("%s did not stop within 5 s", thread.name)
        self._threads = []
        with self._write_lock:
            self.endpoint.close()

    def __enter__(self: H) -> H:
        return self if self._opened else self.open()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    # -- receive --------------------------------------------------------------------------
    def _take(self, got: list[tuple[Message, int | None]]) -> None:
        now = self.clock.now()
        for message, seq in got:
            self._received(Received(now, message, seq))

    def _received(self, item: Received) -> None:
        """Keep one message (a subclass may extend this to log it)."""
        gen = getattr(item.message, "latch_gen", None)
        if isinstance(gen, int):
            self.latch_gen = gen
        self.inbox.append(item)

    def clear_stop_for(self, stop_id: int, *, ahead: int = 0) -> ClearStop:
        """A CLEAR_STOP ``stop_id`` naming the latch generation last heard of plus ``ahead``
        (latch causes sent that no answer reported yet: a STOP just written adds one)."""
        return ClearStop(stop_id, (self.latch_gen + ahead) & 0xFF)

    def _reader(self) -> None:
        while not self._stop.is_set():
            try:
                got = self.endpoint.read_numbered(0.05)
            except OSError as exc:
                if not self._stop.is_set():
                    logger.warning("%s: read failed: %s", self.endpoint.name, exc)
                    self.inbox.fail(exc)
                return
            if got:
                self._take(got)

    def pump(self) -> None:
        """Take in everything that has arrived, without waiting (each lockstep tick)."""
        got = self.endpoint.read_ready()
        if got:
            self._take(got)

    def _lockstep_tick(self) -> None:
        if self._closed:
            return
        self.pump()
        self._beat_if_due()

    def mark(self) -> int:
        """A position in the received messages: what arrives after this call."""
        return self.inbox.mark()

    def received(self, since: int = 0) -> list[Message]:
        """Every message received from position ``since`` on (those still kept)."""
        return [r.message for r in self.inbox.items(since)]

    def messages(self, kind: type[M], since: int = 0) -> list[M]:
        """Every ``kind`` message received from position ``since`` on."""
        return [r.message for r in self.inbox.items(since) if isinstance(r.message, kind)]

    def scaled(self, seconds: float) -> float:
        """``seconds`` times :attr:`timeout_scale`."""
        return seconds * self.timeout_scale

    def find(
        self,
        kind: type[M],
        where: Callable[[M], bool] = _any,
        *,
        since: int = 0,
        timeout_s: float = 1.0,
    ) -> tuple[int, Received] | None:
        """The first ``kind`` message from ``since`` on for which ``where`` holds, with its
        position, waiting up to ``timeout_s``; ``None`` if none came."""

        def accept(item: Received) -> bool:
            return isinstance(item.message, kind) and where(item.message)

        return self.inbox.wait(accept, since=since, timeout_s=self.scaled(timeout_s))

    def expect(
        self,
        kind: type[M],
        where: Callable[[M], bool] = _any,
        *,
        since: int = 0,
        timeout_s: float = 1.0,
        what: str = "",
    ) -> M:
        """Like :meth:`find`, the message itself; :class:`NotReceivedError` ("expected <what>
        within <t> s") when none came."""
        found = self.find(kind, where, since=since, timeout_s=timeout_s)
        if found is None:
            raise NotReceivedError(
                f"expected {what or getattr(kind, 'NAME', kind.__name__)} within "
                f"{self.scaled(timeout_s):g} s"
            )
        message: M = found[1].message  # type: ignore[assignment]
        return message

    def absent(
        self,
        kind: type[M],
        where: Callable[[M], bool] = _any,
        *,
        since: int,
        window_s: float = 0.3,
        what: str = "",
    ) -> None:
        """Let ``window_s`` pass and check that no such message came from ``since`` on;
        :class:`UnexpectedMessageError` ("unexpected <what>: <message>") when one did."""
        found = self.find(kind, where, since=since, timeout_s=window_s)
        if found is not None:
            message = found[1].message
            name = what or getattr(kind, "NAME", kind.__name__)
            raise UnexpectedMessageError(f"unexpected {name}: {message.describe()}")

    def settle(self, seconds: float) -> None:
        """Let ``seconds`` (scaled) pass while messages keep arriving."""
        self.inbox.settle(self.scaled(seconds))

    def heartbeat(self, *, since: int | None = None, timeout_s: float = 1.0) -> Heartbeat:
        """The next HEARTBEAT after ``since`` (default: after now)."""
        return self.expect(
            Heartbeat,
            since=self.mark() if since is None else since,
            timeout_s=timeout_s,
            what="HEARTBEAT",
        )

    def heartbeat_where(
        self, what: str, where: Callable[[Heartbeat], bool], *, timeout_s: float = 1.0
    ) -> Heartbeat:
        """The first HEARTBEAT from now on for which ``where`` holds."""
        return self.expect(
            Heartbeat,
            where,
            since=self.mark(),
            timeout_s=timeout_s,
            what=f"a HEARTBEAT with {what}",
        )

    def handshake(self, *, timeout_s: float = 5.0, every_s: float | None = None) -> Ident:
        """HELLO with this protocol's version and schema hash; the first IDENT after it (maybe a
        boot IDENT that crossed it: :meth:`matches` tells), HELLO repeated every ``every_s`` if
        given. :class:`NotReceivedError` when no IDENT came within ``timeout_s``."""
        hello = Hello(PROTOCOL_VERSION, SCHEMA_HASH)
        _, (_, got), _ = self.request(
            hello, Ident, every_s=every_s, timeout_s=timeout_s, what="IDENT"
        )
        ident: Ident = got.message  # type: ignore[assignment]
        return ident

    @staticmethod
    def matches(ident: Ident) -> str:
        """``""`` when ``ident`` speaks this host's protocol version and schema hash,
        else a sentence saying how it differs."""
        theirs = (ident.protocol_version, ident.schema_hash)
        if theirs == (PROTOCOL_VERSION, SCHEMA_HASH):
            return ""
        return (
            f"controller speaks protocol v{ident.protocol_version} schema "
            f"0x{ident.schema_hash:04X}, this host v{PROTOCOL_VERSION} schema "
            f"0x{SCHEMA_HASH:04X}"
        )

    def clear_stop(
        self,
        clear_id: int,
        *,
        latch_gen: int | None = None,
        every_s: float | None = None,
        timeout_s: float = 1.0,
    ) -> ClearAck:
        """CLEAR_STOP ``clear_id`` naming ``latch_gen`` (default :attr:`latch_gen`), repeated
        every ``every_s`` if given; its CLEAR_ACK, whatever it says. :class:`NotReceivedError`
        when none came within ``timeout_s``."""
        gen = self.latch_gen if latch_gen is None else latch_gen
        _, (_, got), _ = self.request(
            ClearStop(clear_id, gen),
            ClearAck,
            lambda a: a.stop_id == clear_id,
            every_s=every_s,
            timeout_s=timeout_s,
            what=f"CLEAR_ACK for stop_id {clear_id}",
        )
        ack: ClearAck = got.message  # type: ignore[assignment]
        return ack

    def request(
        self,
        message: Message,
        kind: type[M],
        where: Callable[[M], bool] = _any,
        *,
        every_s: float | None = None,
        timeout_s: float = 1.0,
        what: str = "",
    ) -> tuple[float, tuple[int, Received], int]:
        """Send ``message`` and await the first ``kind`` message after it for which ``where``
        holds, sending it again every ``every_s`` if given (the protocol's repeat period,
        STOP_REPEAT_MS for STOP and CLEAR_STOP).

        Returns:
            the host clock just before the first write, s; the answer with its position; how
            many times the message was repeated.

        Raises:
            NotReceivedError: no answer within ``timeout_s`` of the first send.
        """

        def accept(item: Received) -> bool:
            return isinstance(item.message, kind) and where(item.message)

        sent_at = self.now()
        since = self.send(message)
        deadline = sent_at + self.scaled(timeout_s)
        repeats = 0
        while True:
            left = max(0.0, deadline - self.now())
            found = self.inbox.wait(accept, since=since, timeout_s=min(every_s or left, left))
            if found is not None:
                return sent_at, found, repeats
            if self.now() >= deadline:
                raise NotReceivedError(
                    f"expected {what or getattr(kind, 'NAME', kind.__name__)} within "
                    f"{self.scaled(timeout_s):g} s"
                )
            self.send(message)
            repeats += 1

    def indexed(self, kind: type[M], since: int = 0) -> list[tuple[int, Received]]:
        """Every ``kind`` message still kept from ``since`` on, with its position."""
        return [(i, r) for i, r in self.inbox.indexed(since) if isinstance(r.message, kind)]

    # -- send -----------------------------------------------------------------------------
    def send(self, message: Message, *, strict: bool = True) -> int:
        """Send one message; ``strict=False`` skips its semantic limits (a MOTION at speed 61)."""
        mark = self.mark()
        if strict:
            self._write(lambda: self.endpoint.write(message), message.describe())
        else:
            payload = message.pack(strict=False)
            self._write(
                lambda: self.endpoint.write_raw(message.MSG_ID, payload),
                f"{message.describe()} (unchecked)",
            )
        return mark

    def send_raw(self, msg_id: int, payload: bytes, *, bad_crc: bool = False) -> int:
        """Send an unchecked frame (an unknown id, a wrong length, a bad CRC; not traffic-logged);
        :class:`LinkError` also when the medium cannot carry it (a bad CRC on CAN)."""
        mark = self.mark()
        note = f"RAW id={msg_id} payload={payload.hex() or '-'}" + (" bad-crc" if bad_crc else "")
        self._write(lambda: self.endpoint.write_raw(msg_id, payload, bad_crc=bad_crc), note)
        return mark

    def write_bytes(self, data: bytes) -> int:
        """Serial only (else LinkError): put raw ``data`` on the line (garbage, a cut frame)."""
        write_wire = getattr(self.endpoint, "write_wire", None)
        if write_wire is None:
            raise LinkError(f"{self.endpoint.name}: raw bytes need a serial link")
        mark = self.mark()
        self._write(lambda: write_wire(data, log=False), f"BYTES {data.hex()}")
        return mark

    def _write(self, write: Callable[[], object], note: str) -> None:
        with self._write_lock:
            if not self._opened or self._closed:
                raise LinkError(f"{self.endpoint.name} is not open")
            try:
                write()
            except (OSError, ValueError) as exc:
                raise LinkError(f"{self.endpoint.name}: cannot send {note}: {exc}") from exc
            self._sent(note)

    def _sent(self, note: str) -> None:
        """One frame went out (``note`` describes it); a subclass may log it. Called
        with the write lock held, just after the write."""

    # -- heartbeats -----------------------------------------------------------------------
    @contextlib.contextmanager
    def silent(self) -> Iterator[None]:
        """No HOST_HEARTBEAT while inside: the host goes quiet, as a cut cable would (if the
        script sends nothing meanwhile, the controller's watchdog trips)."""
        with self.inbox.cond:
            self._quiet += 1
        try:
            yield
        finally:
            with self.inbox.cond:
                self._quiet -= 1

    def _beat(self) -> None:
        with self.inbox.cond:
            if self._quiet:
                return
            self._beats_sent += 1
            beat = HostHeartbeat(self._beats_sent & 0xFFFF)
        try:
            self._write(lambda: self.endpoint.write(beat), beat.describe())
        except LinkError as exc:
            logger.warning("host heartbeat not sent: %s", exc)

    def _beat_if_due(self) -> None:
        if self.heartbeat_s is None:
            return
        now = self.clock.now()
        if now + 1e-9 >= self._next_beat:
            self._next_beat += self.heartbeat_s
            self._beat()

    def _heartbeats(self) -> None:
        assert self.heartbeat_s is not None
        while not self._stop.wait(self.heartbeat_s):
            self._beat()
