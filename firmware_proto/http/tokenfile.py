"""Where a server's or a client's token comes from: a file or the environment, never
the command line (every user of the machine reads a process's arguments with ``ps``).

:func:`read_token_file` reads one; :func:`refuse_token_argument` is the message an
option such as ``--token`` now gives instead of taking the token.
"""

from __future__ import annotations

import logging
import stat
from pathlib import Path

from firmware_proto.errors import BindPolicyError

__all__ = ["read_token_file", "refuse_token_argument"]

logger = logging.getLogger(__name__)

_MAX_TOKEN_FILE_BYTES = 4096


def read_token_file(path: str | Path, *, what: str = "token") -> str:
    """The token in ``path``: its one line without surrounding whitespace; a file that others
    may read is used, with a warning. BindPolicyError when the file cannot be read, is
    empty, longer than 4 kB, or holds more than one line."""
    file = Path(path)
    try:
        mode = file.stat().st_mode
        with file.open("rb") as f:
            data = f.read(_MAX_TOKEN_FILE_BYTES + 1)
    except OSError as exc:
        raise BindPolicyError(f"cannot read the {what} file {file}: {exc}") from exc
    if len(data) > _MAX_TOKEN_FILE_BYTES:
        raise BindPolicyError(f"the {what} file {file} is over {_MAX_TOKEN_FILE_BYTES} bytes")
    try:
        text = data.decode("utf-8").strip()
    except UnicodeDecodeError as exc:
        raise BindPolicyError(f"the {what} file {file} is not UTF-8 text") from exc
    if not text or "\n" in text:
        raise BindPolicyError(f"the {what} file {file} must hold the {what} on one line")
    if mode & (stat.S_IRGRP | stat.S_IROTH):
        logger.warning("the %s file %s may be read by other users (chmod 600 it)", what, file)
    return text


def refuse_token_argument(option: str, file_option: str, env: str) -> BindPolicyError:
    """The error for a token given on the command line (``option``): what to use instead."""
    return BindPolicyError(
        f"{option} is no longer accepted: a token on the command line is shown to every "
        f"user of this machine (ps, /proc/PID/cmdline); put it in a file readable by you "
        f"only and give {file_option} FILE, or set {env}"
    )
