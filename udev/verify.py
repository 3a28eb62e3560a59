"""udev rules checked by udev itself: ``udevadm verify``, or udev's parser in a sandbox.

:func:`verify_rules` runs ``udevadm verify`` (systemd 254 and later) or, where it is
missing (Debian 12 ships 252), ``udevadm test``, which loads the rules directories with
the same parser but writes ``/dev`` and ``/run/udev``: so it runs in a private mount
namespace (``unshare --mount``, ``--map-root-user`` when not root) where the rules
directories hold only the files under check and ``/dev`` and ``/run`` are empty tmpfs.
Names are not resolved (udevd's job on the rover). :attr:`Verification.checker` says
which ran; where neither can, :class:`CheckUnavailableError`.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from udev.errors import UdevError
from udev.rules import Issue

__all__ = [
    "RULES_DIRS",
    "CheckUnavailableError",
    "Verification",
    "udevadm_version",
    "verify_rules",
]

RULES_DIRS = (
    "/etc/udev/rules.d",
    "/run/udev/rules.d",
    "/usr/local/lib/udev/rules.d",
    "/usr/lib/udev/rules.d",
    "/lib/udev/rules.d",
)
"""Where udev reads rules; in the sandbox the first that exists holds the files under
check and the others are empty."""

VERIFY_SINCE = 254
"""The first systemd release whose ``udevadm`` has ``verify``."""

_DEVICES = ("/sys/class/tty/tty", "/sys/class/tty/console", "/sys/class/mem/null")
"""Devices the sandboxed ``udevadm test`` may replay (any: rules parse before the event)."""

_TIMEOUT_S = 60.0

_SANDBOX = """set -e
rules=$1 empty=$2 device=$3
mount --make-rprivate /
first=1
for dir in {dirs}; do
    [ -d "$dir" ] || continue
    if [ $first = 1 ]; then mount --bind "$rules" "$dir"; first=0
    else mount --bind "$empty" "$dir"; fi
done
mount -t tmpfs tmpfs /run
mount -t tmpfs tmpfs /dev
exec udevadm test --action=add --resolve-names=late "$device"
""".format(dirs=" ".join(RULES_DIRS))

_AT_LINE = re.compile(r"^(?P<path>\S+?\.rules):(?P<line>\d+):? (?P<message>.+)$")
_UNREADABLE = re.compile(r"^Failed to read rules file (?P<path>\S+?\.rules), (?P<message>.+)$")


class CheckUnavailableError(UdevError):
    """Neither ``udevadm verify`` nor the sandboxed ``udevadm test`` can run here."""


@dataclass(frozen=True)
class Verification:
    """The outcome of a check: what checked, which files, what it found."""

    checker: str
    files: tuple[str, ...]
    findings: tuple[Issue, ...]

    @property
    def ok(self) -> bool:
        """Nothing found."""
        return not self.findings


def udevadm_version(udevadm: str) -> int:
    """The systemd release of ``udevadm`` (``252``).

    Raises:
        CheckUnavailableError: it does not run or does not say.
    """
    try:
        out = subprocess.run(
            [udevadm, "--version"], capture_output=True, text=True, timeout=_TIMEOUT_S, check=True
        ).stdout
    except (OSError, subprocess.SubprocessError) as exc:
        raise CheckUnavailableError(f"{udevadm} --version failed: {exc}") from exc
    found = re.match(r"\s*(\d+)", out)
    if found is None:
        raise CheckUnavailableError(f"{udevadm} --version said {out.strip()!r}")
    return int(found.group(1))


def verify_rules(
    paths: Sequence[str | Path], *, style: bool = True, udevadm: str | None = None
) -> Verification:
    """Check rules files with udev's own parser (see the module docstring).

    Args:
        paths: the files (names ending in ``.rules``, as udev reads no other).
        style: report style issues too (``udevadm verify`` only).
        udevadm: the program (default: ``udevadm`` on ``PATH``, then ``/sbin``).

    Raises:
        CheckUnavailableError: no udevadm, or neither way of checking can run here.
        ValueError: a path does not end in ``.rules``.
        OSError: a file cannot be read.
    """
    files = [Path(p) for p in paths]
    for f in files:
        if f.suffix != ".rules":
            raise ValueError(f"{f}: udev reads only files ending in .rules")
        f.read_bytes()  # unreadable: an OSError now, not a finding of udev's
    program = udevadm or shutil.which("udevadm") or shutil.which("udevadm", path="/sbin:/bin")
    if program is None:
        raise CheckUnavailableError("udevadm is not installed here (Debian: apt-get install udev)")
    release = udevadm_version(program)
    if release >= VERIFY_SINCE:
        return _verify(program, release, files, style)
    return _sandboxed_test(program, release, files)


def _verify(program: str, release: int, files: list[Path], style: bool) -> Verification:
    argv = [program, "verify", "--resolve-names=never", *([] if style else ["--no-style"])]
    done = _run([*argv, *map(str, files)])
    by_arg = {str(f): str(f) for f in files}
    findings = _findings(done.stdout + done.stderr, by_arg)
    if done.returncode != 0 and not findings:
        why = (done.stderr or done.stdout).strip().splitlines()
        findings = [Issue("", 0, why[-1] if why else f"exit status {done.returncode}")]
    return Verification(
        f"udevadm verify (systemd {release})", tuple(map(str, files)), tuple(findings)
    )


def _sandboxed_test(program: str, release: int, files: list[Path]) -> Verification:
    names = [f.name for f in files]
    if len(set(names)) != len(names):
        raise ValueError("udev reads one file per name: check files of the same name apart")
    device = next((d for d in _DEVICES if Path(d).exists()), None)
    if device is None:
        raise CheckUnavailableError(f"no device to replay in /sys (tried {', '.join(_DEVICES)})")
    unshare = shutil.which("unshare") or shutil.which("unshare", path="/usr/bin:/bin")
    if unshare is None:
        raise CheckUnavailableError("unshare (util-linux) is not installed here")
    mapping = [] if os.geteuid() == 0 else ["--map-root-user"]
    with tempfile.TemporaryDirectory(prefix="rover-udev-check-") as tmp:
        rules, empty = Path(tmp, "rules"), Path(tmp, "empty")
        rules.mkdir()
        empty.mkdir()
        for f in files:
            shutil.copyfile(f, rules / f.name)
        sandbox = ["sh", "-c", _SANDBOX, "sh", str(rules), str(empty), device]
        path = f"{Path(program).parent}:{os.environ.get('PATH', '')}"
        done = _run(
            [unshare, "--mount", *mapping, "--", *sandbox], env={**os.environ, "PATH": path}
        )
    out = done.stdout + done.stderr
    if done.returncode != 0 or "Reading rules file" not in out:
        tail = " / ".join(out.strip().splitlines()[-3:]) or f"exit status {done.returncode}"
        raise CheckUnavailableError(
            f"systemd {release}'s udevadm has no verify (systemd {VERIFY_SINCE}+), and its "
            f"'udevadm test' could not run in a private mount namespace here: {tail}"
        )
    dirs = [Path(d) for d in RULES_DIRS]
    by_path = {str(d / f.name): str(f) for d in dirs for f in files}
    return Verification(
        f"udevadm test in a private mount namespace (systemd {release} has no verify)",
        tuple(map(str, files)),
        tuple(_findings(out, by_path)),
    )


def _run(argv: list[str], env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    try:
        return subprocess.run(
            argv,
            capture_output=True,
            text=True,
            timeout=_TIMEOUT_S,
            check=False,
            env=env,
            stdin=subprocess.DEVNULL,
        )
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise CheckUnavailableError(f"{argv[0]} failed: {exc}") from exc


def _findings(output: str, paths: dict[str, str]) -> list[Issue]:
    """The lines of ``output`` about ``paths`` (udev's name -> caller's), in order, once."""
    found: list[Issue] = []
    for line in output.splitlines():
        at = _AT_LINE.match(line.strip())
        if at is not None and at.group("path") in paths:
            item = Issue(paths[at.group("path")], int(at.group("line")), at.group("message"))
        else:
            whole = _UNREADABLE.match(line.strip())
            if whole is None or whole.group("path") not in paths:
                continue
            item = Issue(paths[whole.group("path")], 0, whole.group("message"))
        if item not in found:
            found.append(item)
    return found
