"""A controller played frame by frame by a test, on the controller's end of a real pty.

For the host's rules that hang on one ordering of frames (a clear that crosses a new
fault, a reboot whose IDENT is lost, a FAULT frame lost): the emulator, a faithful
controller, produces such orderings only by chance. The bridge's ``ControllerLink``
opens the pty's device with pyserial as it would a USB adapter; the test writes each
frame the controller would send, through the real codec, and reads what the host sent.
"""

from __future__ import annotations

import os
import select
import threading
from collections.abc import Callable
from types import TracebackType
from typing import TypeVar

from firmware_proto.linkio.inbox import Inbox
from firmware_proto.linkio.ptypair import PtyPair
from firmware_proto.wire.framing import FrameDecoder, FrameEncoder
from firmware_proto.wire.message import Message
from firmware_proto.wire.messages import (
    PROTOCOL_VERSION,
    SCHEMA_HASH,
    ControllerState,
    Heartbeat,
    Hello,
    Ident,
    Progress,
)

M = TypeVar("M", bound=Message)


class ScriptedController:
    """See the module docstring. A reader thread collects the host's messages."""

    def __init__(self, boot_nonce: int = 0x1234) -> None:
        self.pty = PtyPair()
        self.boot_nonce = boot_nonce
        self._encoder = FrameEncoder()
        self._decoder = FrameDecoder()
        self.log: Inbox[Message] = Inbox()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._read, name="scripted-rx", daemon=True)
        self._thread.start()

    @property
    def device(self) -> str:
        """The host's end: what the link opens."""
        return self.pty.device

    def send(self, *messages: Message) -> None:
        """Write these frames to the host, in order, with the frame counter running on."""
        os.write(self.pty.master_fd, b"".join(self._encoder.encode(m) for m in messages))

    def reboot(self, boot_nonce: int) -> None:
        """From now on the frames are a new boot's: a new nonce, the counter from 0."""
        self.boot_nonce = boot_nonce
        self._encoder = FrameEncoder()

    def ident(self) -> Ident:
        return Ident(PROTOCOL_VERSION, 1, 0, 0, SCHEMA_HASH, self.boot_nonce)

    def heartbeat(
        self,
        state: int = ControllerState.IDLE,
        *,
        stop: int = 0,
        watchdog: int = 0,
        fault: int = 0,
        fault_bits: int = 0,
        handshake_ok: int = 1,
        gen: int = 0,
    ) -> list[Message]:
        """A HEARTBEAT (and the PROGRESS that follows it) with these latch causes and
        latch generation."""
        latched = int(bool(stop or watchdog or fault))
        hb = Heartbeat(
            state,
            latched,
            handshake_ok,
            stop,
            watchdog,
            fault,
            fault_bits,
            0,
            self.boot_nonce,
            0,
            gen,
        )
        return [hb, Progress(0, 0, 0, 0, 0)]

    def handshake(self, timeout_s: float = 10.0) -> None:
        """Answer the host's HELLO with IDENT and a heartbeat of an open session."""
        self.wait_for(Hello, timeout_s=timeout_s)
        self.send(self.ident(), *self.heartbeat())

    @property
    def received(self) -> list[Message]:
        """Every message the host sent, in order."""
        return self.log.items()

    def mark(self) -> int:
        return self.log.mark()

    def messages(self, kind: type[M], since: int = 0) -> list[M]:
        return [m for m in self.log.items(since) if isinstance(m, kind)]

    def wait_for(
        self,
        kind: type[M],
        pred: Callable[[M], bool] = lambda m: True,
        *,
        since: int = 0,
        timeout_s: float = 10.0,
    ) -> M:
        """The first message of ``kind`` from the host after ``since`` that ``pred``
        accepts.

        Raises:
            TimeoutError: none came within ``timeout_s``.
        """
        found = self.log.wait(
            lambda m: isinstance(m, kind) and pred(m), since=since, timeout_s=timeout_s
        )
        if found is None:
            raise TimeoutError(f"the host sent no {kind.__name__} within {timeout_s} s")
        return found[1]  # type: ignore[return-value]

    def _read(self) -> None:
        while not self._stop.is_set():
            ready, _, _ = select.select([self.pty.master_fd], [], [], 0.05)
            if not ready:
                continue
            try:
                data = os.read(self.pty.master_fd, 4096)
            except OSError:
                return
            frames = self._decoder.feed(data)
            for frame in frames:
                self.log.append(frame.message)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5.0)
        self.pty.close()

    def __enter__(self) -> ScriptedController:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
