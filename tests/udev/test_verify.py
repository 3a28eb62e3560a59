"""udev's own check of rules files: our shipped rules pass it, a broken rule is reported
at its line in udev's words, and the check leaves nothing behind.

On this machine (Debian 12, systemd 252) the check is udev's parser run by ``udevadm
test`` in a private mount namespace; where systemd has ``udevadm verify`` (254+) it is
that. Where neither can run these tests skip, saying why; with
``ROVER_REQUIRE_UDEV_CHECK=1`` (set by .ci/test, whose bootstrap installs udev) they
fail instead (the ``udev_check`` fixture, tests/udev/conftest.py).
"""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from udev.errors import UdevError
from udev.verify import CheckUnavailableError, verify_rules

UDEV_DIR = Path(__file__).resolve().parents[2] / "udev"
OUR_RULES = sorted(UDEV_DIR.glob("*.rules"))


def test_our_shipped_rules_pass_udevs_own_check(udev_check: str) -> None:
    result = verify_rules(OUR_RULES)
    assert result.checker == udev_check
    assert result.files == tuple(map(str, OUR_RULES))
    assert [str(f) for f in result.findings] == []
    assert result.ok


# (rules text, the physical line udev names, a word of its message). Each is broken in
# one way that systemd 252's parser already reports.
BROKEN = [
    ('SUBSYSTEM="tty", SYMLINK+="x"', 1, "operator"),
    ('KERNEL=="tty*", GROUP=="dialout"', 1, "operator"),
    ('SUBSYTEM=="tty", SYMLINK+="x"', 1, "SUBSYTEM"),
    ('KERNEL{x}=="ttyUSB0", SYMLINK+="x"', 1, "attribute"),
    ('SUBSYSTEM=="tty", SYMLINK+="rover-motor', 1, "key/value"),
    ('SUBSYSTEM=="tty", SYMLINK+="$devname"', 1, "substitution"),
    ('SUBSYSTEM=="tty", GOTO="nowhere"', 1, "label"),
    ('SUBSYSTEM=="tty", OPTIONS+="last_rule"', 1, "OPTIONS"),
    ('# a comment\nSUBSYSTEM=="tty", \\\n  MODE!="0660"', 3, "operator"),
]


@pytest.mark.parametrize(("text", "line", "word"), BROKEN, ids=[b[0][:30] for b in BROKEN])
def test_a_broken_rule_is_reported_at_its_line_in_udevs_words(
    udev_check: str, tmp_path: Path, text: str, line: int, word: str
) -> None:
    bad = tmp_path / "50-broken.rules"
    bad.write_text(text + "\n")
    good = tmp_path / "60-good.rules"
    good.write_text('SUBSYSTEM=="tty", ATTRS{idVendor}=="0403", SYMLINK+="x"\n')
    result = verify_rules([bad, good])
    assert not result.ok
    assert {f.path for f in result.findings} == {str(bad)}
    assert any(f.line == line and word.lower() in f.message.lower() for f in result.findings), [
        str(f) for f in result.findings
    ]


def test_a_file_udev_cannot_read_is_a_finding_of_the_whole_file(
    udev_check: str, tmp_path: Path
) -> None:
    long = tmp_path / "50-long.rules"
    long.write_text('SUBSYSTEM=="tty", SYMLINK+="' + "x" * 17000 + '"\n')
    (finding,) = verify_rules([long]).findings
    assert (finding.path, finding.line) == (str(long), 0)


def test_the_check_leaves_nothing_behind(udev_check: str, tmp_path: Path) -> None:
    # Under systemd 252, udevadm test creates the links a rule names; not in the sandbox.
    rule = tmp_path / "50-leak.rules"
    rule.write_text('KERNEL=="tty|console|null", SYMLINK+="rover-check-leak-probe"\n')
    run_udev = Path("/run/udev").exists()
    assert verify_rules([rule]).ok
    assert not Path("/dev/rover-check-leak-probe").exists()
    assert Path("/run/udev").exists() == run_udev


def test_only_rules_files_and_readable_ones(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"only files ending in \.rules"):
        verify_rules([tmp_path / "notes.txt"])
    with pytest.raises(FileNotFoundError):
        verify_rules([tmp_path / "missing.rules"])


def test_without_udevadm_the_check_says_it_cannot_run(tmp_path: Path) -> None:
    rule = tmp_path / "50-ok.rules"
    rule.write_text('SUBSYSTEM=="tty", SYMLINK+="x"\n')
    with pytest.raises(CheckUnavailableError, match="--version failed") as err:
        verify_rules([rule], udevadm=str(tmp_path / "no-udevadm"))
    assert isinstance(err.value, UdevError)


def test_udevadm_verify_is_used_where_systemd_has_it(tmp_path: Path) -> None:
    """systemd 254+ (not on this machine): a stand-in udevadm answering as 255 does, its
    output in verify's format, shows which program runs and how its lines are read."""
    sh = shutil.which("sh")
    assert sh is not None
    rule = tmp_path / "50-style.rules"
    rule.write_text('SUBSYSTEM=="tty" SYMLINK+="x"\n')
    log = tmp_path / "argv"
    udevadm = tmp_path / "udevadm"
    udevadm.write_text(
        f"#!{sh}\n"
        'if [ "$1" = --version ]; then echo 255; exit 0; fi\n'
        f'echo "$@" > {log}\n'
        'for f in "$@"; do case "$f" in *.rules)\n'
        '  echo "$f:1 style: a comma between tokens is expected." >&2\n'
        '  echo "$f: udev rules have style issues." >&2;; esac; done\n'
        "exit 1\n"
    )
    udevadm.chmod(0o755)
    result = verify_rules([rule], udevadm=str(udevadm))
    assert result.checker == "udevadm verify (systemd 255)"
    assert [str(f) for f in result.findings] == [
        f"{rule}:1: style: a comma between tokens is expected."
    ]
    assert log.read_text().split() == ["verify", "--resolve-names=never", str(rule)]
    verify_rules([rule], udevadm=str(udevadm), style=False)
    assert "--no-style" in log.read_text().split()
