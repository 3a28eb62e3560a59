"""The test builds' cache (tests/cbuild.py): a build is reused only while every file it
reads is unchanged, with what the compiler printed; failures are never kept."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

from tests import cbuild
from tests.cbuild import compile_cached

pytestmark = pytest.mark.cc


@pytest.fixture
def gcc() -> str:
    path = shutil.which("gcc")
    if path is None:
        pytest.skip("gcc not found")
    return path


@pytest.fixture
def cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    directory = tmp_path / "cache"
    monkeypatch.setenv(cbuild.CACHE_ENV, str(directory))
    return directory


def _program(tmp_path: Path, answer: int) -> tuple[Path, Path]:
    """A source in ``src/`` that prints the ``ANSWER`` of ``inc/answer.h``."""
    (tmp_path / "inc").mkdir(exist_ok=True)
    (tmp_path / "src").mkdir(exist_ok=True)
    (tmp_path / "inc" / "answer.h").write_text(f"#define ANSWER {answer}\n")
    source = tmp_path / "src" / "main.c"
    source.write_text(
        '#include <stdio.h>\n#include "answer.h"\n#include "local.h"\n'
        'int main(void) { printf("%d %d\\n", ANSWER, LOCAL); return 0; }\n'
    )
    (tmp_path / "src" / "local.h").write_text("#define LOCAL 1\n")
    return source, tmp_path / "inc"


def _out(exe: Path) -> str:
    return subprocess.run([str(exe)], capture_output=True, text=True, check=True).stdout


def test_the_same_build_is_copied_and_a_changed_header_builds_again(
    gcc: str, tmp_path: Path, cache: Path
) -> None:
    source, inc = _program(tmp_path, 41)

    def build(name: str, *include: str) -> cbuild.Compiled:
        return compile_cached(
            [gcc, *include, str(source), "-o", str(tmp_path / name)], timeout_s=120
        )

    first = build("a", "-I", str(inc))
    assert first.returncode == 0 and not first.cached and _out(tmp_path / "a") == "41 1\n"
    again = build("b", "-I", str(inc))  # another output path: the same build
    assert again.cached and _out(tmp_path / "b") == "41 1\n"
    assert build("c", f"-I{inc}").cached is False  # another command
    (inc / "answer.h").write_text("#define ANSWER 42\n")  # a header under -I
    changed = build("d", "-I", str(inc))
    assert not changed.cached and _out(tmp_path / "d") == "42 1\n"
    (tmp_path / "src" / "local.h").write_text("#define LOCAL 2\n")  # beside the source
    beside = build("e", "-I", str(inc))
    assert not beside.cached and _out(tmp_path / "e") == "42 2\n"
    assert build("f", "-I", str(inc)).cached


def test_warnings_are_said_again_and_failures_are_not_kept(
    gcc: str, tmp_path: Path, cache: Path
) -> None:
    source = tmp_path / "warn.c"
    source.write_text("int main(void) { int unused; return 0; }\n")
    cmd = [gcc, "-Wall", str(source), "-o", str(tmp_path / "warn")]
    first = compile_cached(cmd, timeout_s=120)
    hit = compile_cached(cmd, timeout_s=120)
    assert hit.cached and "unused" in first.stderr and hit.stderr == first.stderr
    broken = tmp_path / "broken.c"
    broken.write_text("int main(void) { return }\n")
    cmd = [gcc, str(broken), "-o", str(tmp_path / "broken")]
    for _ in range(2):
        done = compile_cached(cmd, timeout_s=120)
        assert done.returncode != 0 and not done.cached and "error" in done.stderr


def test_off_builds_every_time_and_a_command_needs_one_output(
    gcc: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv(cbuild.CACHE_ENV, "off")
    assert cbuild.cache_dir() is None
    source, inc = _program(tmp_path, 7)
    cmd = [gcc, "-I", str(inc), str(source), "-o", str(tmp_path / "p")]
    assert not compile_cached(cmd, timeout_s=120).cached
    assert not compile_cached(cmd, timeout_s=120).cached
    with pytest.raises(ValueError, match="exactly one -o"):
        compile_cached([gcc, str(source)], timeout_s=120)


def test_only_the_programs_used_last_are_kept(
    gcc: str, tmp_path: Path, cache: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(cbuild, "MAX_ENTRIES", 2)
    source, inc = _program(tmp_path, 1)

    def build(define: str) -> bool:
        cmd = [gcc, f"-D{define}", "-I", str(inc), str(source), "-o", str(tmp_path / "x")]
        return compile_cached(cmd, timeout_s=120).cached

    assert not build("A") and not build("B")
    assert build("A")  # used last now: B is the oldest
    assert not build("C")  # B goes
    assert len(list(cache.glob("*.out"))) == 2
    assert build("A") and build("C") and not build("B")
