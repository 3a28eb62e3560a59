"""Which ROS 2 domains the stacks on this machine hold, and where their parts are.

A running ``rover stack up`` holds an exclusive ``flock`` on ``domain-<N>.lock`` in
:func:`registry_dir` for as long as it lives (the kernel drops it when the process
ends, however it ends) and writes its endpoints beside it, ``domain-<N>.json``.
:func:`claim` takes the first free domain of :data:`STACK_DOMAINS` (or the one asked
for, refusing one that another stack holds); :func:`running` lists the stacks alive.
Domains 0..99 are left to the test workers and to whoever runs ROS 2 by hand.
"""

from __future__ import annotations

import errno
import fcntl
import json
import os
import tempfile
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from planner.errors import DomainBusyError

__all__ = [
    "DIR_ENV",
    "STACK_DOMAINS",
    "DomainBusyError",
    "DomainClaim",
    "claim",
    "registry_dir",
    "running",
]

DIR_ENV = "ROVER_STACK_DIR"
"""Overrides :func:`registry_dir` (tests give each run its own)."""
STACK_DOMAINS = range(101, 233)
"""The domains ``rover stack up`` picks from, lowest free first (ROS 2 documents 0..232
for Fast DDS on Linux)."""


def registry_dir() -> Path:
    """``$ROVER_STACK_DIR``, else ``rover-stacks-<uid>`` in the temporary directory."""
    env = os.environ.get(DIR_ENV)
    path = Path(env) if env else Path(tempfile.gettempdir()) / f"rover-stacks-{os.getuid()}"
    path.mkdir(parents=True, exist_ok=True)
    return path


@dataclass
class DomainClaim:
    """A domain held by this process (see the module docstring)."""

    domain: int
    _fd: int
    _dir: Path

    def publish(self, info: Mapping[str, object]) -> None:
        """Write the stack's endpoints beside the lock (for ``rover stack env``)."""
        path = self._dir / f"domain-{self.domain}.json"
        tmp = path.with_suffix(".tmp")
        tmp.write_text(json.dumps({"domain": self.domain, "pid": os.getpid(), **info}))
        tmp.replace(path)

    def release(self) -> None:
        """Remove the endpoints and drop the lock (idempotent)."""
        if self._fd < 0:
            return
        (self._dir / f"domain-{self.domain}.json").unlink(missing_ok=True)
        os.close(self._fd)
        self._fd = -1


def _try_lock(directory: Path, domain: int) -> int | None:
    fd = os.open(directory / f"domain-{domain}.lock", os.O_RDWR | os.O_CREAT, 0o600)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as exc:
        os.close(fd)
        if exc.errno in (errno.EAGAIN, errno.EWOULDBLOCK):
            return None
        raise
    return fd


@contextmanager
def claim(domain: int | None = None) -> Iterator[DomainClaim]:
    """Hold a domain for the ``with`` block: ``domain``, or the first free one.

    Raises:
        DomainBusyError: ``domain`` is held by another stack, or every one is.
    """
    directory = registry_dir()
    candidates = [domain] if domain is not None else list(STACK_DOMAINS)
    for candidate in candidates:
        fd = _try_lock(directory, candidate)
        if fd is not None:
            held = DomainClaim(candidate, fd, directory)
            try:
                yield held
            finally:
                held.release()
            return
    if domain is not None:
        raise DomainBusyError(
            f"ROS domain {domain} is held by another rover stack on this machine "
            "('rover stack env' lists them); give another --domain or none"
        )
    raise DomainBusyError(
        f"every domain of {STACK_DOMAINS.start}..{STACK_DOMAINS.stop - 1} is held by a stack"
    )


def running() -> list[dict[str, object]]:
    """The stacks alive on this machine (their published endpoints), by domain."""
    directory = registry_dir()
    found = []
    for path in sorted(directory.glob("domain-*.json")):
        try:
            info = json.loads(path.read_text())
            domain = int(info["domain"])
        except (OSError, ValueError, KeyError, TypeError):
            continue
        fd = _try_lock(directory, domain)
        if fd is not None:  # nobody holds it: a stack that died before cleaning up
            os.close(fd)
            path.unlink(missing_ok=True)
            continue
        found.append(info)
    return sorted(found, key=lambda i: str(i["domain"]).zfill(4))
