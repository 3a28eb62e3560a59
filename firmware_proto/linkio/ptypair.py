"""A pseudo-terminal pair: the emulator holds the controller end, hosts open the device.

A pty has no baud rate; wire timing, where it matters, is paced by the emulator.
:class:`PtyPair` opens the pair in raw mode, exposes the host-side device path
(``/dev/pts/N``) and optionally a stable symlink to it.
"""

from __future__ import annotations

import os
import pty
import termios
import tty
from pathlib import Path
from types import TracebackType

__all__ = ["PtyPair"]


class PtyPair:
    """Open a raw pty pair. Use as a context manager; :meth:`close` is idempotent.

    Attributes:
        master_fd: the controller end (read and write it with ``os.read``/``os.write``).
        device: path of the host end, for pyserial or any terminal program.
    """

    def __init__(self, link: str | Path | None = None) -> None:
        """Open the pair, with an optional symlink ``link`` to the device (one already there is
        replaced if it is a symlink); OSError when no pty is available or ``link`` exists and is
        not a symlink."""
        self.master_fd, self._slave_fd = pty.openpty()
        tty.setraw(self._slave_fd)
        attrs = termios.tcgetattr(self._slave_fd)
        attrs[3] &= ~termios.ECHO
        termios.tcsetattr(self._slave_fd, termios.TCSANOW, attrs)
        self.device = os.ttyname(self._slave_fd)
        self.link: Path | None = None
        if link is not None:
            self._make_link(Path(link))

    def _make_link(self, link: Path) -> None:
        if link.is_symlink():
            link.unlink()
        elif link.exists():
            self.close()
            raise FileExistsError(f"{link} exists and is not a symlink; not replacing it")
        link.symlink_to(self.device)
        self.link = link

    def close(self) -> None:
        """Close both ends and remove the symlink (idempotent)."""
        for name in ("master_fd", "_slave_fd"):
            fd = getattr(self, name, -1)
            if fd >= 0:
                os.close(fd)
                setattr(self, name, -1)
        if self.link is not None:
            try:
                if self.link.is_symlink():
                    self.link.unlink()
            finally:
                self.link = None

    def __enter__(self) -> PtyPair:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
