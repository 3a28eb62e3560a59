"""The udev rules checker: our files pass it, and it rejects what udev would reject.

The checker stands in for ``udevadm verify``, which these machines lack, so it is proven
both ways: every rule line of ``udev/*.rules`` passes with no issue at all, and each
deliberately broken line is reported, with a message that names the problem.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from udev.rules import (
    KEYS,
    DeviceNode,
    Op,
    UdevEvent,
    check_files,
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
def test_every_rule_line_of_our_files_passes(path: Path):
    parsed = load_rules(path)
    assert [str(i) for i in parsed.issues] == []
    # Every non-comment, non-blank physical line belongs to exactly one parsed rule: none
    # was dropped by the parser.
    covered = {n for rule in parsed.rules for n in range(rule.line, rule.end_line + 1)}
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        if line.strip() and not line.lstrip().startswith("#"):
            assert number in covered, f"{path.name}:{number} was not parsed: {line!r}"


def test_check_files_on_our_files_is_clean():
    assert check_files(OUR_RULES, strict=True) == []


# (rules text, substring the message must contain). Each is broken in one way.
BROKEN = [
    ('SUBSYSTEM="tty", SYMLINK+="x"', "SUBSYSTEM is a match key: it takes '==' or '!=', not '='"),
    ('KERNEL+="ttyUSB0", SYMLINK+="x"', "KERNEL is a match key"),
    ('ATTRS{idVendor}="0403", SYMLINK+="x"', "ATTRS is a match key"),
    (
        'GROUP=="dialout", SYMLINK+="x"',
        "GROUP is an assignment key: it takes '=' or ':=', not '=='",
    ),
    ('SUBSYSTEM=="tty", MODE!="0660"', "MODE is an assignment key"),
    ('SUBSYSTEM=="tty", LABEL=="x"', "LABEL is an assignment key: it takes '=', not '=='"),
    ('SUBSYSTEM=="tty", GOTO+="end"\nLABEL="end"', "GOTO does not take '+='; it takes '='"),
    ('SUBSYSTEM=="tty", NAME-="x"', "NAME does not take '-='"),
    ('SUBSYSTEM=="tty", ENV{X}-="1"', "ENV does not take '-='"),
    ('SUBSYSTEM=="tty", OPTIONS-="watch"', "OPTIONS does not take '-='"),
    ('SUBSYSTEM=="tty", MODE+="0660"', "MODE does not take '+='; udev assumes '='"),
    ('SUBSYSTEM=="tty", ATTR{power/control}+="on"', "ATTR does not take '+='; udev assumes '='"),
    ('SUBSYSTEM=="tty", ENV{X}:="1"', "ENV does not take ':='; udev assumes '='"),
    ('SUBSYTEM=="tty", SYMLINK+="x"', "unknown key 'SUBSYTEM' (did you mean SUBSYSTEM?)"),
    ('subsystem=="tty", SYMLINK+="x"', "unknown key 'subsystem' (did you mean SUBSYSTEM?)"),
    ('BUS=="usb", SYMLINK+="x"', "unknown key 'BUS' (removed from udev; use SUBSYSTEMS)"),
    ('SYSFS{idVendor}=="0403", SYMLINK+="x"', "removed from udev; use ATTRS"),
    ('ATTRS=="0403", SYMLINK+="x"', "ATTRS needs an attribute in braces, e.g. ATTRS{idVendor}"),
    ('ENV=="1", SYMLINK+="x"', "ENV needs an attribute in braces"),
    ('KERNEL{x}=="ttyUSB0", SYMLINK+="x"', "KERNEL takes no {attribute}"),
    ('CONST{color}=="red", SYMLINK+="x"', "CONST{color}: the attribute must be one of arch, virt"),
    ('SUBSYSTEM=="tty", IMPORT{web}="x"', "IMPORT{web}: the attribute must be one of"),
    ('SUBSYSTEM=="tty", RUN{shell}+="/bin/true"', "RUN{shell}: the attribute must be one of"),
    ('TEST{rw}=="/dev/x", SYMLINK+="x"', "TEST{rw}: the attribute must be an octal file mode"),
    ('SUBSYSTEM=="tty", SYMLINK+=rover-motor', "SYMLINK: value must be in double quotes"),
    ("SUBSYSTEM=='tty', SYMLINK+=\"x\"", "SUBSYSTEM: value must be in double quotes"),
    ('SUBSYSTEM=="tty", SYMLINK+="rover-motor', "SYMLINK: unterminated double-quoted value"),
    ('SUBSYSTEM=="tty", SYMLINK+="a\\"', "unterminated double-quoted value"),
    ('SUBSYSTEM=="tty", SYMLINK=>"x"', "SYMLINK: invalid operator '=>'"),
    ('SUBSYSTEM=="tty", SYMLINK ~= "x"', "SYMLINK: missing or invalid operator"),
    ('SUBSYSTEM=="tty", SYMLINK', "'SYMLINK': no operator and value"),
    ('SUBSYSTEM=="tty", "x"', "missing operator before value"),
    ('SUBSYSTEM=="tty", {idVendor}=="x"', "expected a key before '{idVendor}'"),
    ('ATTRS{idVendor=="0403", SYMLINK+="x"', "ATTRS: unterminated '{' (missing '}')"),
    ('SUBSYSTEM=="tty", SYMLINK+=i"x"', "the 'i' prefix is only for '==' and '!='"),
    ('PROGRAM==i"/bin/true", SYMLINK+="x"', "PROGRAM does not take the 'i' (case-insensitive)"),
    ('SUBSYSTEM=="tty", ENV{X}=e"\\q"', "invalid escape in e\"...\" value: unknown escape '\\q'"),
    ('SUBSYSTEM=="tty", ENV{X}=e"\\x4"', "'\\x' needs two hex digits"),
    ('SUBSYSTEM=="tty", MODE="rw-rw----"', 'MODE="rw-rw----" is not an octal file mode'),
    ('SUBSYSTEM=="tty", MODE="0999"', "is not an octal file mode"),
    ('SUBSYSTEM=="tty", GROUP="dial out"', 'GROUP="dial out" is not a user or group name'),
    ('SUBSYSTEM=="tty", GROUP=""', "GROUP: empty value"),
    ('SUBSYSTEM=="tty", RUN+=""', "RUN: empty value"),
    ('SUBSYSTEM=="net", NAME="%k"', 'NAME="%k" has no effect'),
    ('SUBSYSTEM=="net", NAME=""', 'NAME="" has no effect'),
    ('SUBSYSTEM=="tty", ENV{DEVNAME}="x"', "ENV{DEVNAME} cannot be set"),
    ('SUBSYSTEM=="tty", OPTIONS+="last_rule"', "OPTIONS: unknown option 'last_rule'"),
    ('SUBSYSTEM=="tty", OPTIONS+="link_priority=high"', "link_priority 'high' is not an integer"),
    ('SUBSYSTEM=="tty", OPTIONS="log_level=loud"', "unknown log level 'loud'"),
    ('SUBSYSTEM=="tty", IMPORT{builtin}="usbid"', "IMPORT{builtin}: unknown builtin 'usbid'"),
    ('SUBSYSTEM=="tty", RUN{builtin}+="frobnicate"', "RUN{builtin}: unknown builtin 'frobnicate'"),
    ('SUBSYSTEM=="tty", SYMLINK+="$devname"', "unknown substitution '$devname'"),
    ('SUBSYSTEM=="tty", SYMLINK+="motor-%q"', "unknown substitution '%q'"),
    ('SUBSYSTEM=="tty", SYMLINK+="$attr"', "needs an {attribute}"),
    ('SUBSYSTEM=="tty", SYMLINK+="$env{"', "unterminated '{' in substitution"),
    ('SUBSYSTEM=="tty", SYMLINK+="x$result{two}"', "the part must be a number"),
    ('SUBSYSTEM=="tty", GOTO="nowhere"', 'GOTO="nowhere" has no matching LABEL later in this file'),
    ('SUBSYSTEM=="tty", GOTO="rover_ends"\nLABEL="rover_end"', 'did you mean "rover_end"?'),
    ('LABEL="top"\nSUBSYSTEM=="tty", GOTO="top"', "udev only jumps forward"),
    ('SUBSYSTEM=="tty", GOTO="a", GOTO="b"\nLABEL="a"\nLABEL="b"', "more than one GOTO"),
    ('SUBSYSTEM=="tty", LABEL="unused"', 'LABEL="unused" is never used'),
    ('SUBSYSTEM=="tty", ATTRS{idVendor}=="0403"', "only matches and assigns nothing"),
    ('SUBSYSTEM=="tty" SYMLINK+="x"', "a comma is expected between tokens"),
    ('SUBSYSTEM=="tty",, SYMLINK+="x"', "more than one comma between tokens"),
    ('SUBSYSTEM=="tty", SYMLINK+="x",', "stray comma at the end of the rule"),
    (', SUBSYSTEM=="tty", SYMLINK+="x"', "stray comma at the start of the rule"),
    ('SUBSYSTEM=="tty", SYMLINK+="/dev/rover-motor"', "relative to /dev; drop the leading '/'"),
    ('SUBSYSTEM=="bus", SYMLINK+="x"', 'must be written as "subsystem"'),
    ('SUBSYSTEM=="tty", \\ \n    SYMLINK+="x"', "backslash followed by trailing blanks"),
    ('SUBSYSTEM=="tty", \\', "file ends inside a line continuation"),
    ('SUBSYSTEM=="tty", SYMLINK+="' + "x" * 17000 + '"', "rule longer than 16384 characters"),
]


@pytest.mark.parametrize(("text", "expected"), BROKEN, ids=[b[1][:40] for b in BROKEN])
def test_broken_line_is_rejected_with_a_message_naming_the_problem(text: str, expected: str):
    parsed = parse_rules(text, "broken.rules")
    messages = [i.message for i in parsed.issues]
    assert messages, f"not reported: {text!r}"
    assert any(expected in m for m in messages), messages
    assert all(str(i).startswith("broken.rules:") for i in parsed.issues)


# Rules written the way udev's own files and vendors' files write them; all valid.
GOOD = [
    'ACTION=="remove", GOTO="x_end"\nSUBSYSTEM!="tty", GOTO="x_end"\n'
    'KERNEL=="ttyUSB*", SYMLINK+="x"\nLABEL="x_end"',
    'SUBSYSTEMS=="usb", IMPORT{builtin}="usb_id", IMPORT{builtin}="hwdb --subsystem=usb"',
    'KERNEL=="ttyUSB[0-9]*|ttyACM[0-9]*", ENV{ID_PATH}=="?*", '
    'SYMLINK+="serial/by-path/$env{ID_PATH}"',
    'SUBSYSTEMS=="usb-serial", ENV{.ID_PORT}="$attr{port_number}"',
    'KERNEL=="sd*", ATTRS{vendor}==i"acme*", OPTIONS+="link_priority=10", MODE:="0600"',
    'SUBSYSTEM=="net", ACTION=="add", DRIVERS=="?*", ATTR{address}=="00:11:22:33:44:55", '
    'NAME="lan0"',
    'TEST{0644}=="/sys/class/x", RUN+="/bin/logger %k $$HOME 100%%"',
    'PROGRAM="/bin/echo a b", RESULT=="a *", SYMLINK+="by-result/%c{2}", SYMLINK+="$result{1+}"',
    'SUBSYSTEM=="tty", ENV{MY_VAR}=e"tab\\there \\x41\\101", TAG+="uaccess"',
    'SUBSYSTEM=="block", CONST{virt}=="kvm", SYMLINK-="old", TAG-="seat"',
    'SUBSYSTEM=="tty", OPTIONS="watch", RUN{builtin}+="kmod load vcan"',
    'SUBSYSTEM=="tty", GROUP="dialout", OWNER="root", MODE="660", '
    'SECLABEL{selinux}="system_u:object_r:tty_device_t"',
    'ENV{ID_INPUT}=="1", IMPORT{program}="/lib/udev/x %p", IMPORT{parent}="ID_*", '
    'IMPORT{db}="X", IMPORT{cmdline}="quiet", IMPORT{file}="/run/x"',
    'ATTR{power/control}="auto", SYSCTL{net.ipv4.conf.all.forwarding}="1"',
    'SUBSYSTEM=="tty", ATTRS{product}=="Say \\"hi\\"", SYMLINK+="quoted"',
    'KERNEL=="ttyS[0-9]", NAME:="x", OPTIONS+="log_level=debug", OPTIONS+="static_node=ttyS0"',
    'SUBSYSTEM=="tty", \\\n# a comment inside a continuation is skipped, as udev does\n'
    '    ATTRS{idVendor}=="0403", \\\n    SYMLINK+="x"',
]


@pytest.mark.parametrize("text", GOOD, ids=range(len(GOOD)))
def test_valid_rules_pass(text: str):
    parsed = parse_rules(text, "good.rules")
    assert [str(i) for i in parsed.issues] == []
    assert parsed.rules


def test_continuation_joins_lines_and_reports_the_physical_line():
    text = 'SUBSYSTEM=="tty", \\\n  # comment\n  ATTRS{idVendor}=="0403", \\\n  MODE="rw"\n'
    parsed = parse_rules(text, "c.rules")
    (issue,) = parsed.issues
    assert issue.line == 4  # the MODE token's own line, not the rule's first
    assert "MODE" in issue.message
    good = parse_rules(text.replace('"rw"', '"0660"'), "c.rules")
    (rule,) = good.rules
    assert (rule.line, rule.end_line) == (1, 4)
    assert [t.key for t in rule.tokens] == ["SUBSYSTEM", "ATTRS", "MODE"]


def test_a_rejected_rule_is_left_out_and_the_others_kept():
    parsed = parse_rules('SUBSYSTEM="tty", SYMLINK+="a"\nSUBSYSTEM=="tty", SYMLINK+="b"\n')
    assert len(parsed.rules) == 1
    assert parsed.rules[0].tokens[1].value == "b"
    assert len(parsed.errors) == 1


def test_values_unescape_quotes_and_keep_other_backslashes():
    (rule,) = parse_rules('ATTRS{x}=="a\\"b\\d", SYMLINK+="y"').rules
    assert rule.tokens[0].value == 'a"b\\d'
    (rule,) = parse_rules('ENV{X}=e"1\\t2", SYMLINK+="y"').rules
    assert rule.tokens[0].value == "1\t2"


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


def test_key_table_covers_udevs_keys():
    expected = {
        "ACTION", "DEVPATH", "KERNEL", "NAME", "SYMLINK", "SUBSYSTEM", "DRIVER", "ATTR",
        "SYSCTL", "KERNELS", "SUBSYSTEMS", "DRIVERS", "ATTRS", "TAGS", "TAG", "ENV", "CONST",
        "TEST", "PROGRAM", "RESULT", "OWNER", "GROUP", "MODE", "SECLABEL", "RUN", "LABEL",
        "GOTO", "IMPORT", "OPTIONS",
    }  # fmt: skip
    assert set(KEYS) == expected
    match_only = {k for k, s in KEYS.items() if s.match and not s.assign and not s.as_match}
    assert match_only == {
        "ACTION", "DEVPATH", "KERNEL", "SUBSYSTEM", "DRIVER", "RESULT", "CONST", "KERNELS",
        "SUBSYSTEMS", "DRIVERS", "TAGS", "ATTRS", "TEST",
    }  # fmt: skip
    assign_only = {k for k, s in KEYS.items() if not s.match}
    assert assign_only == {"OPTIONS", "OWNER", "GROUP", "MODE", "SECLABEL", "RUN", "GOTO", "LABEL"}


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
    assert parsed.errors == ()
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
