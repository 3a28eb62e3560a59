"""Host C built on demand into shared libraries, cached by content hash: the C firmware
core (:mod:`emulator.firmware`) and the batch twins' kernel (:mod:`emulator.batch_kernel`).

A library is named after its stem and the hash of the compiler's path, the machine's
architecture, the flags and every source and header, and kept in ``$ROVER_FIRMWARE_CACHE``, else
``$XDG_CACHE_HOME/rover/firmware``, else ``~/.cache/rover/firmware``: the same C is
compiled once per machine, and processes that build it at once each write their own
temporary file and rename it into place (the last one wins, with the same bytes).
"""

from __future__ import annotations

import contextlib
import hashlib
import logging
import os
import platform
import shutil
import subprocess
import tempfile
from collections.abc import Sequence
from pathlib import Path

from emulator.errors import NativeBuildError
from firmware_proto.runtime.cachedir import rover_cache_dir

__all__ = ["WARNINGS", "build_shared_library", "cache_dir", "compiler"]

logger = logging.getLogger(__name__)

WARNINGS = ("-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-Wconversion", "-Wshadow")
"""Warnings the project's C compiles clean with (as errors)."""


def cache_dir() -> Path:
    """Where built libraries are kept (not created here)."""
    return rover_cache_dir("firmware", "ROVER_FIRMWARE_CACHE")


def compiler(*, error: type[NativeBuildError], hint: str) -> str:
    """The C compiler: ``$CC`` (default ``gcc``), else ``cc``, resolved on ``PATH``.

    Raises:
        error: neither is on ``PATH``; the message ends with ``hint``.
    """
    name = os.environ.get("CC", "gcc")
    path = shutil.which(name) or shutil.which("cc")
    if path is None:
        raise error(f"no C compiler ({name!r} or cc) on PATH: {hint}")
    return path


def build_shared_library(
    stem: str,
    c_dir: Path,
    sources: Sequence[str],
    headers: Sequence[str],
    flags: Sequence[str],
    *,
    cc: str,
    error: type[NativeBuildError],
    libs: Sequence[str] = (),
    suffix: str = "",
    timeout_s: float = 120.0,
) -> Path:
    """``sources`` (paths relative to ``c_dir``, which is also on the include path)
    compiled with ``cc`` and ``flags`` (plus ``-fPIC -shared``), linked with ``libs``
    (such as ``-lm``), into
    ``lib{stem}-{hash}{suffix}.so`` in :func:`cache_dir`, or that file if it is there.

    Raises:
        error: the build failed (the command and its output are in the message), the
            compiler ran past ``timeout_s`` seconds, or it or the cache directory could
            not be used (the ``OSError`` in the message).
    """
    flags = [*flags, "-fPIC", "-shared"]
    digest = hashlib.sha256()
    digest.update(f"{cc}\0{platform.machine()}\0".encode())
    digest.update(" ".join([*flags, *libs]).encode())
    for name in (*sources, *headers):
        digest.update(name.encode())
        digest.update((c_dir / name).read_bytes())
    out_dir = cache_dir()
    target = out_dir / f"lib{stem}-{digest.hexdigest()[:16]}{suffix}.so"
    if target.exists():
        return target
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
        fd, tmp_name = tempfile.mkstemp(suffix=".so", dir=out_dir)
    except OSError as exc:
        raise error(f"cannot write the library to {out_dir}: {exc}") from exc
    os.close(fd)
    cmd = [cc, *flags, f"-I{c_dir}", *(str(c_dir / s) for s in sources), *libs, "-o", tmp_name]
    try:
        done = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s, check=False)
        if done.returncode != 0:
            raise error(f"{' '.join(cmd)}\n{done.stdout}{done.stderr}")
        os.replace(tmp_name, target)
    except subprocess.TimeoutExpired as exc:
        raise error(f"compiler timed out after {timeout_s} s") from exc
    except OSError as exc:
        raise error(f"cannot run {cc} or keep its library: {exc}") from exc
    finally:
        with contextlib.suppress(OSError):
            os.unlink(tmp_name)
    logger.info("built %s", target)
    return target
