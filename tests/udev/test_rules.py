"""The rules reader: our files read whole, rules split the way udev splits them, and
the evaluator that tells which rule would name a device.

Whether udev accepts a rule is udev's to say: tests/udev/test_verify.py.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from udev.rules import (
    DeviceNode,
    Op,
    UdevEvent,
    evaluate,
    load_rules,
    parse_rules,
)

UDEV_DIR = Path(__file__).resolve().parents[2] / "udev"
OUR_RULES = sorted(UDEV_DIR.glob("*.rules"))


def test_our_rules_files_exist():
    names = {p.name for p in OUR_RULES}
    assert {"99-rover-motor.rules", "99-rover-motor-bench.rules", "70-rover-can.rules"} <= names


@pytest.mark.parametrize("path", OUR_RULES, ids=lambda p: p.name)
def test_every_rule_line_of_our_files_is_read(path: Path):
    parsed = load_rules(path)
    assert [str(i) for i in parsed.issues] == []
    # Every non-comment, non-blank physical line belongs to exactly one parsed rule: none
    # was dropped by the reader.
    covered = {n for rule in parsed.rules for n in range(rule.line, rule.end_line + 1)}
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        if line.strip() and not line.lstrip().startswith("#"):
            assert number in covered, f"{path.name}:{number} was not parsed: {line!r}"


def test_continuation_joins_lines_and_tokens_keep_their_physical_line():
    text = 'SUBSYSTEM=="tty", \\\n  # comment\n  ATTRS{idVendor}=="0403", \\\n  MODE="0660"\n'
    (rule,) = parse_rules(text, "c.rules").rules
    assert (rule.line, rule.end_line) == (1, 4)
    assert [t.key for t in rule.tokens] == ["SUBSYSTEM", "ATTRS", "MODE"]
    assert [t.line for t in rule.tokens] == [1, 3, 4]


@pytest.mark.parametrize(
    ("text", "why"),
    [
        ('SUBSYTEM=="tty", SYMLINK+="a"', "unknown key 'SUBSYTEM'"),
        ('SUBSYSTEM=="tty", SYMLINK+=a', "cannot read a KEY OP"),
        ('SUBSYSTEM=="tty", SYMLINK+="a', "SYMLINK: unterminated double-quoted value"),
    ],
)
def test_a_rule_it_cannot_read_is_left_out_and_the_others_kept(text: str, why: str):
    parsed = parse_rules(f'{text}\nSUBSYSTEM=="tty", SYMLINK+="b"\n', "x.rules")
    (rule,) = parsed.rules
    assert rule.tokens[1].value == "b"
    (issue,) = parsed.issues
    assert str(issue).startswith("x.rules:1: ") and why in issue.message


def test_values_unescape_quotes_and_keep_other_backslashes():
    (rule,) = parse_rules('ATTRS{x}=="a\\"b\\d", SYMLINK+="y"').rules
    assert rule.tokens[0].value == 'a"b\\d'
    (rule,) = parse_rules('ENV{X}=e"1\\t2", SYMLINK+="y"').rules
    assert rule.tokens[0].value == "1\t2"
    (rule,) = parse_rules('ATTRS{serial}==i"a1", SYMLINK+="y"').rules
    assert rule.tokens[0].case_insensitive


def test_operators_are_parsed_as_udev_spells_them():
    (rule,) = parse_rules(
        'KERNEL=="a", DRIVER!="b", SYMLINK+="c", SYMLINK-="d", NAME:="e", GROUP="f"'
    ).rules
    assert [t.op for t in rule.tokens] == [
        Op.MATCH,
        Op.NOMATCH,
        Op.ADD,
        Op.REMOVE,
        Op.ASSIGN_FINAL,
        Op.ASSIGN,
    ]
    (rule,) = parse_rules('SUBSYSTEMS=="usb", IMPORT{builtin}="usb_id"').rules
    assert rule.tokens[1].op is Op.MATCH  # udev takes IMPORT and PROGRAM as matches


# ----------------------------------------------------------------------- evaluator

USB_TTY = UdevEvent(
    chain=(
        DeviceNode("ttyUSB0", "tty"),
        DeviceNode("ttyUSB0", "usb-serial"),
        DeviceNode("1-1.2:1.0", "usb", "ftdi_sio", {"bInterfaceNumber": "00"}),
        DeviceNode(
            "1-1.2", "usb", "usb", {"idVendor": "0403", "idProduct": "6001", "serial": "A1"}
        ),
    ),
    env={"ID_USB_INTERFACE_NUM": "00"},
)


def _outcome(text: str, event: UdevEvent = USB_TTY):
    parsed = parse_rules(text, "e.rules")
    assert parsed.issues == ()
    return evaluate([parsed], event)


def test_parent_keys_must_all_match_on_one_device():
    # idVendor is on the USB device, bInterfaceNumber on the interface: never together,
    # which is why our FT2232 rule matches the interface through ENV{ID_USB_INTERFACE_NUM}.
    split = 'ATTRS{idVendor}=="0403", ATTRS{bInterfaceNumber}=="00", SYMLINK+="x"'
    assert _outcome(split).symlinks == ()
    env = 'ATTRS{idVendor}=="0403", ENV{ID_USB_INTERFACE_NUM}=="00", SYMLINK+="x"'
    assert _outcome(env).symlinks == ("x",)


def test_goto_skips_to_the_label_and_env_assignments_feed_later_matches():
    text = (
        'SUBSYSTEM!="tty", GOTO="end"\n'
        'ATTRS{idVendor}=="0403", ENV{ROVER}="1"\n'
        'ENV{ROVER}=="1", SYMLINK+="a"\n'
        'SUBSYSTEM=="tty", GOTO="end"\n'
        'SYMLINK+="skipped"\n'
        'LABEL="end"\n'
        'SYMLINK+="after", MODE="0600"'
    )
    out = _outcome(text)
    assert out.symlinks == ("a", "after")
    assert out.mode == "0600"
    assert out.env["ROVER"] == "1"


def test_symlink_list_operators_and_final_assignment():
    text = 'SYMLINK+="a b"\nSYMLINK-="a"\nGROUP:="dialout"\nGROUP="users", SYMLINK="c"'
    out = _outcome(text)
    assert out.symlinks == ("c",)
    assert out.group == "dialout"


def test_missing_attribute_never_matches_not_even_with_not_equal():
    assert _outcome('ATTRS{nonesuch}!="x", SYMLINK+="y"').symlinks == ()
    assert _outcome('ENV{UNSET}=="", SYMLINK+="y"').symlinks == ("y",)


def test_globs_alternatives_and_case_insensitive_match():
    assert _outcome('KERNEL=="ttyACM*|ttyUSB[0-9]", SYMLINK+="y"').symlinks == ("y",)
    assert _outcome('ATTRS{serial}==i"a1", SYMLINK+="y"').symlinks == ("y",)
    assert _outcome('ATTRS{serial}=="a1", SYMLINK+="y"').symlinks == ()


def test_keys_it_cannot_evaluate_are_assumed_and_listed():
    out = _outcome('PROGRAM=="/bin/true", SUBSYSTEM=="tty", SYMLINK+="y"')
    assert out.symlinks == ("y",)
    assert len(out.assumed) == 1
    assert "PROGRAM" in out.assumed[0]


def test_evaluate_needs_a_device():
    with pytest.raises(ValueError, match="at least the device"):
        evaluate([], UdevEvent(chain=()))
