"""Which ROS 2 domains the stacks on this machine hold, and where their parts are.

A running ``rover stack up`` holds an exclusive ``flock`` on ``domain-<N>.lock`` in
:func:`registry_dir` while it lives (the kernel drops it however the process ends) and
writes its endpoints beside it, ``domain-<N>.json``. :func:`claim` takes the first free
domain of :data:`STACK_DOMAINS` (or the one asked for, if free); :func:`running` lists
the stacks alive. Domains 0..99 are left to the tests and to ROS 2 by hand.

The registry is this user's alone (the endpoints hold the console token): the directory
is made 0700 and refused (:class:`~planner.errors.StackRegistryError`) when it is a
link, another user's, or writable by others; its files are created 0600, never through
a link; an endpoints file of another owner is ignored, a lock file refused.
"""

from __future__ import annotations

import errno
import fcntl
import json
import logging
import os
import stat
import tempfile
from collections.abc import Iterator, Mapping
from contextlib import contextmanager, suppress
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import urlsplit

from planner.errors import DomainBusyError, StackRegistryError
from planner.ground.console_client import CONSOLE_ENV

__all__ = [
    "DIR_ENV",
    "RUNTIME_ENV",
    "STACK_DOMAINS",
    "TOKEN_KEY",
    "DomainBusyError",
    "DomainClaim",
    "StackRegistryError",
    "claim",
    "console_token",
    "registry_dir",
    "running",
]

logger = logging.getLogger(__name__)

DIR_ENV = "ROVER_STACK_DIR"
"""Overrides :func:`registry_dir` (tests give each run its own)."""
RUNTIME_ENV = "XDG_RUNTIME_DIR"
"""The user's runtime directory (systemd makes it, 0700): the registry's home where set."""
STACK_DOMAINS = range(101, 233)
"""Domains ``rover stack up`` picks from, lowest free first (Fast DDS on Linux takes 0..232)."""
TOKEN_KEY = "console_token"
"""The endpoints file's key of the stack's console token."""
_PRIVATE = 0o700
_FILE_MODE = 0o600
_MAX_FILE_BYTES = 65536


def registry_dir() -> Path:
    """``$ROVER_STACK_DIR``, else ``rover-stacks`` in ``$XDG_RUNTIME_DIR``, else
    ``rover-stacks-<uid>`` in the temporary directory; created 0700, checked.

    Raises:
        StackRegistryError: the directory is not this user's alone.
    """
    env = os.environ.get(DIR_ENV)
    runtime = os.environ.get(RUNTIME_ENV, "")
    if env:
        path = Path(env)
    elif runtime and os.path.isabs(runtime) and os.path.isdir(runtime):
        path = Path(runtime) / "rover-stacks"
    else:
        path = Path(tempfile.gettempdir()) / f"rover-stacks-{os.getuid()}"
    _make_private(path)
    return path


def _make_private(path: Path) -> None:
    """Create ``path`` 0700, or check that the one there is this user's alone."""
    if path.parent != path:
        path.parent.mkdir(parents=True, exist_ok=True)
    with suppress(FileExistsError):
        path.mkdir(mode=_PRIVATE)
    fix = f"remove it, or set {DIR_ENV} to a directory of your own with mode 0700"
    info = os.lstat(path)
    if stat.S_ISLNK(info.st_mode):
        raise StackRegistryError(
            f"the stack registry {path} is a symbolic link (it may have been planted): {fix}"
        )
    if not stat.S_ISDIR(info.st_mode):
        raise StackRegistryError(f"the stack registry {path} is not a directory: {fix}")
    if info.st_uid != os.getuid():
        raise StackRegistryError(
            f"the stack registry {path} belongs to uid {info.st_uid}, not to you "
            f"(uid {os.getuid()}): another user may have planted it to point rover stop "
            f"at a console of theirs; {fix}"
        )
    mode = stat.S_IMODE(info.st_mode)
    if mode & 0o022:
        raise StackRegistryError(
            f"the stack registry {path} has mode {mode:04o}: other users may have put "
            f"files in it; {fix}"
        )
    if mode & 0o077:
        # Only this user could write in it: nothing is planted. Its files were readable.
        os.chmod(path, _PRIVATE)
        logger.warning("the stack registry %s had mode %04o; made 0700", path, mode)


def _open_private(path: Path, flags: int) -> int:
    """``os.open`` of a file of the registry: never through a link, created 0600, and
    this user's (refused otherwise)."""
    fd = os.open(path, flags | os.O_NOFOLLOW | os.O_CLOEXEC, _FILE_MODE)
    info = os.fstat(fd)
    if info.st_uid != os.getuid():
        os.close(fd)
        raise StackRegistryError(f"{path} belongs to uid {info.st_uid}, not to you: remove it")
    if stat.S_IMODE(info.st_mode) & 0o077:
        os.fchmod(fd, _FILE_MODE)
    return fd


@dataclass
class DomainClaim:
    """A domain held by this process (its lock file's ``flock``)."""

    domain: int
    _fd: int
    _dir: Path

    def publish(self, info: Mapping[str, object]) -> None:
        """Write the stack's endpoints beside the lock (for ``rover stack env``, and the
        console's token for the commands: :func:`console_token`), readable by this user
        only."""
        path = self._dir / f"domain-{self.domain}.json"
        tmp = path.with_suffix(".tmp")
        fd = _open_private(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC)
        with os.fdopen(fd, "w") as f:
            f.write(json.dumps({"domain": self.domain, "pid": os.getpid(), **info}))
        tmp.replace(path)

    def release(self) -> None:
        """Remove the endpoints and drop the lock (idempotent)."""
        if self._fd < 0:
            return
        (self._dir / f"domain-{self.domain}.json").unlink(missing_ok=True)
        os.close(self._fd)
        self._fd = -1


def _try_lock(directory: Path, domain: int) -> int | None:
    fd = _open_private(directory / f"domain-{domain}.lock", os.O_RDWR | os.O_CREAT)
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
        StackRegistryError: the registry is not this user's alone.
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


def _read(path: Path) -> dict[str, object] | None:
    """An endpoints file, ``None`` when it cannot be read, is not this user's, or is not
    an object naming its domain."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC)
    except OSError:
        return None
    with os.fdopen(fd, "rb") as f:
        if os.fstat(f.fileno()).st_uid != os.getuid():
            logger.warning("ignoring %s: it belongs to another user", path)
            return None
        data = f.read(_MAX_FILE_BYTES + 1)
    try:
        info = json.loads(data)
        int(info["domain"])
    except (ValueError, KeyError, TypeError):
        return None
    return info if isinstance(info, dict) else None


def running() -> list[dict[str, object]]:
    """The stacks alive on this machine (their published endpoints), by domain
    (:class:`StackRegistryError`: the registry is not this user's alone)."""
    directory = registry_dir()
    found = []
    for path in sorted(directory.glob("domain-*.json")):
        info = _read(path)
        if info is None:
            continue
        fd = _try_lock(directory, int(str(info["domain"])))
        if fd is not None:  # nobody holds it: a stack that died before cleaning up
            os.close(fd)
            path.unlink(missing_ok=True)
            continue
        found.append(info)
    return sorted(found, key=lambda i: str(i["domain"]).zfill(4))


def _authority(url: str) -> tuple[str, int | None]:
    try:
        parts = urlsplit(url.strip())
        host, port = (parts.hostname or "").lower(), parts.port
    except ValueError:
        return "", None
    return ("127.0.0.1" if host == "localhost" else host), port


def console_token(url: str) -> str | None:
    """The token of the running stack whose console is ``url`` (its export line's
    ``ROVER_STACK_CONSOLE``; ``localhost`` and ``127.0.0.1`` alike), ``None`` when no
    stack of this user serves it.

    Raises:
        StackRegistryError: the registry is not this user's alone.
    """
    wanted = _authority(url)
    if wanted[1] is None:
        return None
    for info in running():
        env = info.get("env")
        token = info.get(TOKEN_KEY)
        if (
            isinstance(env, dict)
            and isinstance(token, str)
            and token
            and _authority(str(env.get(CONSOLE_ENV, ""))) == wanted
        ):
            return token
    return None
