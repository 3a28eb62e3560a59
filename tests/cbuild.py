"""A content-addressed cache for the C programs the tests build (the codec's harness, the
firmware core's self-tests and cross builds, the libFuzzer targets): the same compiler
given the same flags and the same sources writes the same program, so a test run whose C
has not changed copies last run's program instead of compiling again (about 20
CPU-seconds of a run of the test command: docs/testing.md, "Where the CPU goes").

The key is the compiler (its resolved path, size and modification time), the command with
its output path taken out, the contents of every file the command names, and the
contents of every C file (``.c``, ``.h``, ``.S``, ``.ld``) under each directory it names
(``-I DIR``, ``-IDIR``) and beside each named source: what a quoted or ``-I`` include
can read. System headers are the compiler's own, which a package upgrade changes along
with the compiler. Only successful builds are kept, with what the compiler printed,
which a hit prints again: a test that fails on a warning fails on a hit as on a miss.

The cache lives in ``$ROVER_TEST_BUILD_CACHE``, else ``$XDG_CACHE_HOME/rover/test-builds``,
else ``~/.cache/rover/test-builds``, outside the checkout as the firmware library's
(:mod:`emulator.firmware`); ``ROVER_TEST_BUILD_CACHE=off`` compiles every time. It keeps
the :data:`MAX_ENTRIES` programs used last. Programs built with ``-g`` keep the source
paths of the checkout that first built them (for a debugger, not for the tests).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import shutil
import subprocess
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from firmware_proto.runtime.cachedir import rover_cache_dir

__all__ = ["CACHE_ENV", "MAX_ENTRIES", "Compiled", "cache_dir", "compile_cached"]

CACHE_ENV = "ROVER_TEST_BUILD_CACHE"
MAX_ENTRIES = 200
"""Programs kept; past it the least recently used go (libFuzzer builds are a few MB)."""
_VERSION = b"rover-test-build 1\n"
_C_SUFFIXES = frozenset({".c", ".h", ".S", ".ld"})


@dataclass(frozen=True)
class Compiled:
    """The outcome of one compiler command; ``cached``: copied from the cache, not run."""

    returncode: int
    stdout: str
    stderr: str
    cached: bool


def cache_dir() -> Path | None:
    """Where the programs are kept, or ``None`` when ``ROVER_TEST_BUILD_CACHE=off``."""
    if os.environ.get(CACHE_ENV) == "off":
        return None
    return rover_cache_dir("test-builds", CACHE_ENV)


def _hash_file(digest: hashlib._Hash, path: Path) -> None:
    data = path.read_bytes()
    digest.update(len(data).to_bytes(8, "little"))
    digest.update(data)


def _hash_tree(digest: hashlib._Hash, root: Path, *, recursive: bool) -> None:
    files = root.rglob("*") if recursive else root.iterdir()
    for path in sorted(p for p in files if p.suffix in _C_SUFFIXES and p.is_file()):
        digest.update(str(path.relative_to(root)).encode() + b"\0")
        _hash_file(digest, path)


def _key(cmd: Sequence[str], out_index: int) -> str:
    digest = hashlib.sha256(_VERSION)
    compiler = shutil.which(cmd[0]) or cmd[0]
    real = os.path.realpath(compiler)
    st = os.stat(real)
    digest.update(f"{real}\0{st.st_size}\0{st.st_mtime_ns}\0".encode())
    beside: set[Path] = set()
    for index, arg in enumerate(cmd[1:], start=1):
        if index == out_index:
            digest.update(b"<out>\0")
        elif arg.startswith("-I") and len(arg) > 2 and os.path.isdir(arg[2:]):
            digest.update(b"-I<tree>\0")
            _hash_tree(digest, Path(arg[2:]), recursive=True)
        elif os.path.isdir(arg):  # as in "-I DIR"
            digest.update(b"<tree>\0")
            _hash_tree(digest, Path(arg), recursive=True)
        elif not arg.startswith("-") and os.path.isfile(arg):
            path = Path(arg)
            digest.update(f"<file {path.name}>\0".encode())
            _hash_file(digest, path)
            beside.add(path.resolve().parent)
        else:
            digest.update(arg.encode() + b"\0")
    for directory in sorted(beside):
        digest.update(b"<beside>\0")
        _hash_tree(digest, directory, recursive=False)
    return digest.hexdigest()[:32]


def _prune(directory: Path) -> None:
    programs = sorted(directory.glob("*.out"), key=lambda p: p.stat().st_mtime_ns)
    for old in programs[: max(0, len(programs) - MAX_ENTRIES)]:
        for path in (old, old.with_suffix(".json")):
            path.unlink(missing_ok=True)


def compile_cached(
    cmd: Sequence[str | os.PathLike[str]], *, timeout_s: float, env: dict[str, str] | None = None
) -> Compiled:
    """Run a compiler command that writes one file (``-o PATH``), or copy that file from
    the cache when the same command on the same contents succeeded before.

    Args:
        cmd: the compiler and its arguments, with exactly one ``-o PATH``.
        timeout_s: the compiler's time limit, s (``subprocess.TimeoutExpired`` past it).
        env: the compiler's environment (default: this process's).

    Raises:
        ValueError: the command names no single output.
    """
    args = tuple(map(str, cmd))
    outs = [i + 1 for i, arg in enumerate(args[:-1]) if arg == "-o"]
    if len(outs) != 1:
        raise ValueError(f"a cached build names exactly one -o PATH: {' '.join(args)}")
    out = Path(args[outs[0]])
    directory = cache_dir()
    key = _key(args, outs[0]) if directory is not None else ""
    if directory is not None:
        program = directory / f"{key}.out"
        try:
            said = json.loads(program.with_suffix(".json").read_text())
            shutil.copy2(program, out)
            os.utime(program)  # used last: kept by _prune
            return Compiled(0, said["stdout"], said["stderr"], cached=True)
        except (OSError, ValueError, KeyError):
            pass  # not built before (or half pruned): build it
    done = subprocess.run(
        args, capture_output=True, text=True, timeout=timeout_s, check=False, env=env
    )
    compiled = Compiled(done.returncode, done.stdout, done.stderr, cached=False)
    if directory is None or done.returncode != 0 or not out.is_file():
        return compiled
    # A cache that cannot be written costs the next run a build, nothing more.
    with contextlib.suppress(OSError):
        _store(directory, key, out, compiled)
    return compiled


def _store(directory: Path, key: str, out: Path, compiled: Compiled) -> None:
    """Keep ``out`` and what the compiler said under ``key``, each file replaced whole
    (concurrent runs may build the same key)."""
    directory.mkdir(parents=True, exist_ok=True)
    program = directory / f"{key}.out"
    said = program.with_suffix(".json")
    tmp = directory / f"{key}.{os.getpid()}.tmp"
    try:
        shutil.copy2(out, tmp)
        os.replace(tmp, program)
        tmp.write_text(json.dumps({"stdout": compiled.stdout, "stderr": compiled.stderr}))
        os.replace(tmp, said)  # last: a hit needs both
    finally:
        tmp.unlink(missing_ok=True)
    _prune(directory)
