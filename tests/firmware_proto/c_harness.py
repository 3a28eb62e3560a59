"""Build the C reference codec with its pipe harness and talk to it.

The harness (``firmware_proto/wire/c/tests/rp_tool.c``) reads lines on stdin and answers
lines on stdout; see its header comment for the modes. Every run is a subprocess that
is waited for with a timeout, so a hung or crashed harness fails the test instead of
leaking a child. The sanitizers abort the harness on the first error; their report goes
to stderr, which must stay empty.
"""

from __future__ import annotations

import os
import shutil
import subprocess
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from firmware_proto.wire.codegen import REPO_ROOT
from firmware_proto.wire.framing import Frame, FrameDecoder
from tests.cbuild import compile_cached

C_DIR = REPO_ROOT / "firmware_proto" / "wire" / "c"
LIBRARY_SOURCES = (C_DIR / "rover_msgs.c", C_DIR / "rover_proto.c")
WARNINGS = (
    "-std=c99",
    "-Wall",
    "-Wextra",
    "-Werror",
    "-pedantic",
    "-Wconversion",
    "-Wshadow",
)
"""Warnings every C file of the codec compiles clean with (as errors)."""
SANITIZERS = (
    "-g",
    "-O1",
    "-fno-omit-frame-pointer",
    "-fsanitize=address,undefined",
    "-fno-sanitize-recover=all",
)
"""The harness is built with these: any memory error or undefined behaviour aborts it."""
SANITIZER_ENV = {
    "ASAN_OPTIONS": "detect_leaks=1:halt_on_error=1:abort_on_error=0:exitcode=86",
    "UBSAN_OPTIONS": "halt_on_error=1:print_stacktrace=1",
}
TIMEOUT_S = 120.0
FUZZ_MAX_CHUNK = 64


class HarnessError(AssertionError):
    """The harness failed: non-zero exit, a sanitizer report, or unexpected output."""


def compiler() -> str | None:
    """The C compiler to use (``$CC`` or gcc), or ``None`` if there is none."""
    name = os.environ.get("CC", "gcc")
    return shutil.which(name)


def compile_c(args: Iterable[str | Path], timeout_s: float = TIMEOUT_S) -> None:
    """Run the compiler (or take its program from the test builds' cache:
    tests/cbuild.py); raises :class:`HarnessError` with its output on failure or on any
    output at all (a warning)."""
    cc = compiler()
    if cc is None:
        raise HarnessError("no C compiler")
    cmd = [cc, *map(str, args)]
    done = compile_cached(cmd, timeout_s=timeout_s)
    if done.returncode != 0 or done.stderr.strip():
        raise HarnessError(f"{' '.join(cmd)}\n{done.stdout}{done.stderr}")


@dataclass(frozen=True)
class Tool:
    """A built ``rp_tool`` binary."""

    path: Path

    def run(self, mode: str, stdin: bytes, *args: str) -> list[str]:
        """Run one mode over ``stdin``; its output lines. Raises :class:`HarnessError`."""
        env = {**os.environ, **SANITIZER_ENV}
        done = subprocess.run(
            [str(self.path), mode, *args],
            input=stdin,
            capture_output=True,
            timeout=TIMEOUT_S,
            env=env,
            check=False,
        )
        if done.returncode != 0 or done.stderr:
            raise HarnessError(
                f"rp_tool {mode} exited {done.returncode}:\n"
                f"{done.stderr.decode(errors='replace')[-4000:]}"
            )
        return done.stdout.decode().splitlines()

    def lines(self, mode: str, lines: Iterable[str], *args: str) -> list[str]:
        """Run a line mode over ``lines``."""
        text = "".join(line + "\n" for line in lines)
        return self.run(mode, text.encode(), *args)


def build_tool(out_dir: Path) -> Tool:
    """Compile the library and the harness, warnings as errors, with the sanitizers."""
    binary = out_dir / "rp_tool"
    compile_c(
        [
            *WARNINGS,
            *SANITIZERS,
            "-I",
            C_DIR,
            *LIBRARY_SOURCES,
            C_DIR / "tests" / "rp_tool.c",
            "-o",
            binary,
        ]
    )
    return Tool(binary)


# ------------------------------------------------------------------ output parsing


def parse_fields(tokens: Iterable[str]) -> dict[str, int]:
    """``["a=1", "b=-2"]`` -> ``{"a": 1, "b": -2}``."""
    out = {}
    for token in tokens:
        name, _, value = token.partition("=")
        out[name] = int(value)
    return out


def parse_decode(lines: list[str]) -> tuple[list[dict[str, Any]], dict[str, int]]:
    """Frames (``{"id", "seq", "fields"}``) and counters of a decode or fuzz run."""
    if not lines or not lines[-1].startswith("counters "):
        raise HarnessError(f"no counters line in {lines[-3:]}")
    frames = []
    for line in lines[:-1]:
        kind, msg_id, seq, *fields = line.split()
        if kind != "frame":
            raise HarnessError(f"unexpected line {line!r}")
        frames.append({"id": int(msg_id), "seq": int(seq), "fields": parse_fields(fields)})
    return frames, parse_fields(lines[-1].split()[1:])


def frame_dict(frame: Frame) -> dict[str, Any]:
    """A Python frame in the form of :func:`parse_decode` and the vectors."""
    return {"id": frame.message.MSG_ID, "seq": frame.seq, "fields": frame.message.to_dict()}


def python_decode(chunks: Iterable[bytes]) -> tuple[list[dict[str, Any]], dict[str, int]]:
    """What the Python reference decoder makes of ``chunks``, fed one by one."""
    decoder = FrameDecoder()
    frames = [frame_dict(f) for chunk in chunks for f in decoder.feed(chunk)]
    return frames, decoder.counters.as_dict()


def xorshift_chunks(data: bytes, seed: int, max_chunk: int = FUZZ_MAX_CHUNK) -> Iterator[bytes]:
    """The chunks ``rp_tool fuzz SEED MAXCHUNK`` cuts ``data`` into (same xorshift32)."""
    state = seed & 0xFFFFFFFF
    at = 0
    while at < len(data):
        state ^= (state << 13) & 0xFFFFFFFF
        state ^= state >> 17
        state ^= (state << 5) & 0xFFFFFFFF
        size = 1 + state % max_chunk
        yield data[at : at + size]
        at += size
