"""udev rules files: parser, syntax checker and a small evaluator.

``udevadm verify`` is not on the machines this project runs on, so this module checks
rules the way ``systemd-udevd`` parses them (``src/udev/udev-rules.c``, udev(7)):

- physical lines: a line whose first non-blank character is ``#`` is a comment, even
  inside a continuation; a line ending in a backslash continues on the next one (the
  next line's leading blanks are dropped); blank lines separate nothing;
- a rule is comma-separated ``KEY[{attribute}] OP "value"`` tokens; the operators are
  ``==`` and ``!=`` (match) and ``=``, ``+=``, ``-=``, ``:=`` (assignment); which key
  takes which operator, whether it takes an ``{attribute}`` and which values it accepts
  is the :data:`KEYS` table;
- values are double-quoted; ``\\"`` is the only escape of a plain value, an ``e"..."``
  value takes C escapes, an ``i"..."`` value matches case-insensitively (``==``/``!=``
  only); assigned values may use ``$kernel``/``%k``-style substitutions, which must be
  known ones (``$$`` and ``%%`` for a literal);
- ``GOTO`` jumps forward only, to a ``LABEL`` later in the same file.

Every finding is an :class:`Issue`: ``error`` where udev would reject or ignore the
token or the rule, ``warning`` where it accepts it with another meaning than written or
reports a style problem. :func:`parse_rules` never raises on bad rules; it returns them
with their issues.

The evaluator (:func:`evaluate`) replays an ``add`` event through parsed rules to tell
which rule would name a device, for ``rover devices``: it evaluates the keys that a
description of the device can answer (``ACTION``, ``KERNEL``, ``SUBSYSTEM``,
``DRIVER``, ``ATTR``, ``ENV``, ``NAME``, ``SYMLINK`` and the parent keys ``KERNELS``,
``SUBSYSTEMS``, ``DRIVERS``, ``ATTRS``) and assumes the others true, listing them in
:attr:`Outcome.assumed`.

Exceptions::

    UdevError (RuntimeError)        root of the udev tooling in bridge
     +-- udev.install.InstallError   install refused or failed
"""

from __future__ import annotations

import difflib
import enum
import fnmatch
import logging
import re
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

__all__ = [
    "BUILTINS",
    "KEYS",
    "MAX_LINE_CHARS",
    "DeviceNode",
    "Issue",
    "KeySpec",
    "Op",
    "Outcome",
    "Rule",
    "RuleHit",
    "RulesFile",
    "Token",
    "UdevError",
    "UdevEvent",
    "check_files",
    "evaluate",
    "load_rules",
    "parse_rules",
]

logger = logging.getLogger(__name__)

#: udev ignores a logical line longer than this (UDEV_LINE_SIZE).
MAX_LINE_CHARS = 16384


class UdevError(RuntimeError):
    """Root of the errors of the udev tooling (rules, devices, install)."""


class Op(enum.Enum):
    """A udev operator; the value is its spelling."""

    MATCH = "=="
    NOMATCH = "!="
    ADD = "+="
    REMOVE = "-="
    ASSIGN = "="
    ASSIGN_FINAL = ":="

    @property
    def is_match(self) -> bool:
        return self in (Op.MATCH, Op.NOMATCH)


_MATCH_OPS = frozenset({Op.MATCH, Op.NOMATCH})


@dataclass(frozen=True)
class KeySpec:
    """What udev accepts for one key.

    ``attr`` is ``"none"`` (no ``{attribute}``), ``"required"`` or ``"optional"``;
    ``attr_values`` restricts it to a set when not None. ``match`` says whether the key
    takes ``==``/``!=``. ``assign`` are the assignment operators taken as written;
    ``assumed`` those udev takes with a warning, as ``=``; ``as_match`` those udev
    silently treats as ``==`` (``PROGRAM``, ``IMPORT``). Any other operator is an error.
    ``nonempty``: an empty value is an error. ``formatted``: the value may hold
    ``$``/``%`` substitutions, which are checked. ``case_prefix``: the ``i`` prefix is
    allowed (with ``==``/``!=``). ``parent``: a match key evaluated on the device or
    one of its parents, all such keys of a rule on the same one.
    """

    name: str
    attr: str = "none"
    attr_values: frozenset[str] | None = None
    match: bool = True
    assign: frozenset[Op] = frozenset()
    assumed: frozenset[Op] = frozenset()
    as_match: frozenset[Op] = frozenset()
    nonempty: bool = False
    formatted: bool = False
    case_prefix: bool = True
    parent: bool = False

    def accepted(self) -> list[Op]:
        """Operators this key takes without complaint, in udev's documentation order."""
        ok = (_MATCH_OPS if self.match else frozenset()) | self.assign
        return [op for op in Op if op in ok]


def _ops(*spellings: str) -> frozenset[Op]:
    return frozenset(Op(s) for s in spellings)


_ALL_ASSIGN = _ops("=", "+=", "-=", ":=")

#: Every key udev knows, by name (systemd-udevd's parse_token()).
KEYS: Mapping[str, KeySpec] = {
    spec.name: spec
    for spec in (
        KeySpec("ACTION"),
        KeySpec("DEVPATH"),
        KeySpec("KERNEL"),
        KeySpec("SUBSYSTEM"),
        KeySpec("DRIVER"),
        KeySpec("RESULT"),
        KeySpec("CONST", attr="required", attr_values=frozenset({"arch", "virt"})),
        KeySpec("KERNELS", parent=True),
        KeySpec("SUBSYSTEMS", parent=True),
        KeySpec("DRIVERS", parent=True),
        KeySpec("TAGS", parent=True),
        KeySpec("ATTRS", attr="required", parent=True),
        KeySpec("SYMLINK", assign=_ALL_ASSIGN, formatted=True),
        KeySpec("NAME", assign=_ops("=", ":="), assumed=_ops("+="), formatted=True),
        KeySpec("ENV", attr="required", assign=_ops("=", "+="), assumed=_ops(":="), formatted=True),
        KeySpec("TAG", assign=_ops("=", "+=", "-="), assumed=_ops(":="), formatted=True),
        KeySpec(
            "ATTR", attr="required", assign=_ops("="), assumed=_ops("+=", ":="), formatted=True
        ),
        KeySpec(
            "SYSCTL", attr="required", assign=_ops("="), assumed=_ops("+=", ":="), formatted=True
        ),
        KeySpec("TEST", attr="optional", nonempty=True, formatted=True, case_prefix=False),
        KeySpec(
            "PROGRAM",
            as_match=_ops("=", "+=", ":="),
            nonempty=True,
            formatted=True,
            case_prefix=False,
        ),
        KeySpec(
            "IMPORT",
            attr="required",
            attr_values=frozenset({"file", "program", "builtin", "db", "cmdline", "parent"}),
            as_match=_ops("=", "+=", ":="),
            nonempty=True,
            formatted=True,
            case_prefix=False,
        ),
        KeySpec("OPTIONS", match=False, assign=_ops("=", "+=", ":=")),
        KeySpec("OWNER", match=False, assign=_ops("=", ":="), assumed=_ops("+="), nonempty=True),
        KeySpec("GROUP", match=False, assign=_ops("=", ":="), assumed=_ops("+="), nonempty=True),
        KeySpec("MODE", match=False, assign=_ops("=", ":="), assumed=_ops("+="), nonempty=True),
        KeySpec(
            "SECLABEL",
            attr="required",
            match=False,
            assign=_ops("=", "+="),
            assumed=_ops(":="),
            nonempty=True,
            formatted=True,
        ),
        KeySpec(
            "RUN",
            attr="optional",
            attr_values=frozenset({"program", "builtin"}),
            match=False,
            assign=_ops("=", "+=", ":="),
            nonempty=True,
            formatted=True,
        ),
        KeySpec("GOTO", match=False, assign=_ops("=")),
        KeySpec("LABEL", match=False, assign=_ops("=")),
    )
}

#: Keys of old udev versions, with what replaced them.
_REMOVED_KEYS = {
    "BUS": "SUBSYSTEMS",
    "SYSFS": "ATTRS{...}",
    "ID": "KERNELS",
    "DRIVERS_OF": "DRIVERS",
    "WAIT_FOR": "TEST{...}",
    "WAIT_FOR_SYSFS": "TEST{...}",
}

#: udev built-in commands (IMPORT{builtin}, RUN{builtin}).
BUILTINS = frozenset(
    {
        "blkid",
        "btrfs",
        "dissect_image",
        "factory_reset",
        "hwdb",
        "input_id",
        "keyboard",
        "kmod",
        "net_driver",
        "net_id",
        "net_setup_link",
        "path_id",
        "tpm2_id",
        "uaccess",
        "usb_id",
    }
)

# Substitutions: long form $name and short form %c (udev-format.c).
_SUBST_LONG = {
    "devnode": "N",
    "tempnode": "N",
    "attr": "s",
    "sysfs": "s",
    "env": "E",
    "kernel": "k",
    "number": "n",
    "driver": "d",
    "devpath": "p",
    "id": "b",
    "major": "M",
    "minor": "m",
    "result": "c",
    "parent": "P",
    "name": "D",
    "links": "L",
    "root": "r",
    "sys": "S",
}
_SUBST_SHORT = frozenset(_SUBST_LONG.values())

# Properties the kernel or udevd own; ENV{...}= may not set them (device_property_can_set).
_READONLY_ENV = frozenset(
    {
        "ACTION",
        "SEQNUM",
        "SYNTH_UUID",
        "DEVPATH",
        "DEVPATH_OLD",
        "SUBSYSTEM",
        "DEVTYPE",
        "DRIVER",
        "MODALIAS",
        "DEVNAME",
        "DEVMODE",
        "DEVUID",
        "DEVGID",
        "MAJOR",
        "MINOR",
        "DISKSEQ",
        "PARTN",
        "IFINDEX",
        "INTERFACE",
        "INTERFACE_OLD",
        "DEVLINKS",
        "TAGS",
        "CURRENT_TAGS",
        "USEC_INITIALIZED",
        "UDEV_DATABASE_VERSION",
    }
)

_LOG_LEVELS = frozenset(
    {"emerg", "alert", "crit", "err", "warning", "notice", "info", "debug", "reset"}
    | {str(n) for n in range(8)}
)
_OPTIONS_PLAIN = frozenset(
    {"dump", "string_escape=none", "string_escape=replace", "db_persist", "watch", "nowatch"}
)

_WHITESPACE = " \t\n\r"


@dataclass(frozen=True)
class Issue:
    """One finding of the checker: ``path:line: severity: message``."""

    path: str
    line: int
    severity: str  # "error" or "warning"
    message: str

    def __str__(self) -> str:
        return f"{self.path}:{self.line}: {self.severity}: {self.message}"


@dataclass(frozen=True)
class Token:
    """One ``KEY{attr} OP "value"`` of a rule; ``line`` is its physical line."""

    key: str
    attr: str | None
    op: Op
    value: str
    line: int
    case_insensitive: bool = False

    @property
    def spec(self) -> KeySpec | None:
        return KEYS.get(self.key)

    def __str__(self) -> str:
        attr = f"{{{self.attr}}}" if self.attr is not None else ""
        prefix = "i" if self.case_insensitive else ""
        escaped = self.value.replace('"', '\\"')
        return f'{self.key}{attr}{self.op.value}{prefix}"{escaped}"'


@dataclass(frozen=True)
class Rule:
    """One logical rule line: its tokens, where it starts and ends."""

    path: str
    line: int
    end_line: int
    text: str
    tokens: tuple[Token, ...]

    @property
    def label(self) -> str | None:
        return next((t.value for t in self.tokens if t.key == "LABEL"), None)

    @property
    def goto(self) -> str | None:
        return next((t.value for t in self.tokens if t.key == "GOTO"), None)


@dataclass(frozen=True)
class RulesFile:
    """A parsed rules file: the rules udev would load and every issue found."""

    path: str
    rules: tuple[Rule, ...]
    issues: tuple[Issue, ...]

    @property
    def errors(self) -> tuple[Issue, ...]:
        return tuple(i for i in self.issues if i.severity == "error")


# --------------------------------------------------------------------------- parsing


@dataclass
class _Logical:
    text: str
    first: int
    last: int
    # (offset in text, physical line number) for each joined piece
    pieces: list[tuple[int, int]] = field(default_factory=list)

    def line_at(self, offset: int) -> int:
        line = self.first
        for start, number in self.pieces:
            if start <= offset:
                line = number
        return line


def _logical_lines(text: str, path: str, issues: list[Issue]) -> list[_Logical]:
    """Join continuations and drop comments and blank lines, as udev reads a file."""
    out: list[_Logical] = []
    pending: _Logical | None = None
    number = 0
    for number, raw in enumerate(text.splitlines(), start=1):
        line = raw.lstrip(_WHITESPACE)
        if line.startswith("#"):
            continue
        stripped = line.rstrip(" \t")
        broken = stripped.endswith("\\") and stripped != line
        if broken:
            issues.append(
                Issue(
                    path,
                    number,
                    "error",
                    "backslash followed by trailing blanks: this is not a line continuation, "
                    "so udev ends the rule here and ignores it for the stray backslash",
                )
            )
        if pending is not None:
            pending.pieces.append((len(pending.text), number))
            pending.text += line
            pending.last = number
            current = pending
        else:
            current = _Logical(line, number, number, [(0, number)])
        if current.text.endswith("\\"):
            current.text = current.text[:-1]
            pending = current
            continue
        pending = None
        if broken:
            continue
        if len(current.text) >= MAX_LINE_CHARS:
            issues.append(
                Issue(path, current.first, "error", f"rule longer than {MAX_LINE_CHARS} characters")
            )
            continue
        if current.text.strip(_WHITESPACE):
            out.append(current)
    if pending is not None:
        issues.append(
            Issue(
                path,
                number,
                "error",
                "file ends inside a line continuation (last line ends with a backslash): "
                "udev ignores this rule",
            )
        )
    return out


def _c_unescape_problem(body: str) -> str | None:
    """Why an ``e"..."`` value is not valid C escaping, or None."""
    i = 0
    simple = set("abfnrtv\\\"'?")
    while i < len(body):
        if body[i] != "\\":
            i += 1
            continue
        if i + 1 >= len(body):
            return "ends with a lone backslash"
        c = body[i + 1]
        if c in simple:
            i += 2
        elif c == "x":
            if not re.match(r"[0-9A-Fa-f]{2}", body[i + 2 : i + 4]):
                return f"'\\x' needs two hex digits (at {body[i : i + 4]!r})"
            i += 4
        elif c in "01234567":
            if not re.match(r"[0-7]{3}", body[i + 1 : i + 4]):
                return f"octal escape needs three digits (at {body[i : i + 4]!r})"
            i += 4
        elif c in "uU":
            n = 4 if c == "u" else 8
            if not re.match(rf"[0-9A-Fa-f]{{{n}}}", body[i + 2 : i + 2 + n]):
                return f"'\\{c}' needs {n} hex digits"
            i += 2 + n
        else:
            return f"unknown escape '\\{c}'"
    return None


def _format_problem(value: str) -> str | None:
    """Why ``value`` has an invalid substitution, or None (udev_check_format)."""
    i = 0
    while i < len(value):
        c = value[i]
        if c not in "$%":
            i += 1
            continue
        rest = value[i + 1 :]
        if rest.startswith(c):
            i += 2
            continue
        kind: str | None = None
        length = 0
        if c == "$":
            for name, short in _SUBST_LONG.items():
                if rest.startswith(name):
                    kind, length = short, len(name)
                    break
            if kind is None:
                word = re.match(r"[A-Za-z_]*", rest)
                shown = word.group(0) if word else ""
                return (
                    f"unknown substitution '${shown}' at character {i + 1} "
                    f"(write '$$' for a literal '$')"
                )
        elif rest[:1] in _SUBST_SHORT:
            kind, length = rest[0], 1
        else:
            return (
                f"unknown substitution '%{rest[:1]}' at character {i + 1} "
                f"(write '%%' for a literal '%')"
            )
        j = i + 1 + length
        attr = ""
        if value[j : j + 1] == "{":
            end = value.find("}", j + 1)
            if end < 0:
                return f"unterminated '{{' in substitution at character {i + 1}"
            attr = value[j + 1 : end]
            if not attr:
                return f"empty '{{}}' in substitution at character {i + 1}"
            j = end + 1
        if kind in ("s", "E") and not attr:
            return (
                f"substitution at character {i + 1} needs an {{attribute}} ($attr{{x}}, $env{{X}})"
            )
        if kind == "c" and attr and not re.fullmatch(r"[0-9]+\+?", attr):
            return (
                f"'$result{{{attr}}}' at character {i + 1}: "
                "the part must be a number, e.g. {2} or {2+}"
            )
        i = j
    return None


def _suggest(key: str) -> str:
    if key in _REMOVED_KEYS:
        return f" (removed from udev; use {_REMOVED_KEYS[key]})"
    close = difflib.get_close_matches(key.upper(), KEYS, n=1, cutoff=0.6)
    return f" (did you mean {close[0]}?)" if close else ""


def _describe_ops(ops: Iterable[Op]) -> str:
    spelled = [f"'{op.value}'" for op in ops]
    return ", ".join(spelled[:-1]) + f" or {spelled[-1]}" if len(spelled) > 1 else spelled[0]


class _TokenError(Exception):
    def __init__(self, offset: int, message: str) -> None:
        super().__init__(message)
        self.offset = offset
        self.message = message


def _scan_tokens(text: str) -> tuple[list[tuple[int, str, str | None, Op, str, bool]], list[str]]:
    """Split one logical line into raw tokens, as udev's parse_line() does.

    Returns ``(offset, key, attr, op, value, case_insensitive)`` tuples and style
    notes; raises :class:`_TokenError` at the first token udev cannot parse.
    """
    tokens: list[tuple[int, str, str | None, Op, str, bool]] = []
    notes: list[str] = []
    pos = 0
    n = len(text)
    first = True
    while True:
        commas = 0
        while pos < n and (text[pos] in _WHITESPACE or text[pos] == ","):
            commas += text[pos] == ","
            pos += 1
        if pos >= n:
            if commas and tokens:
                notes.append("stray comma at the end of the rule")
            break
        if first and commas:
            notes.append("stray comma at the start of the rule")
        elif not first and commas == 0:
            notes.append(f"a comma is expected between tokens (before {text[pos : pos + 12]!r})")
        elif not first and commas > 1:
            notes.append("more than one comma between tokens")
        first = False
        key_start = pos
        while True:
            if pos >= n:
                raise _TokenError(key_start, f"{text[key_start:].strip()!r}: no operator and value")
            c = text[pos]
            if c in _WHITESPACE or c in "={":
                break
            if c in "+-!:" and pos + 1 < n and text[pos + 1] == "=":
                break
            if c == '"':
                raise _TokenError(
                    key_start, f"{text[key_start:pos]!r}: missing operator before value"
                )
            pos += 1
        key = text[key_start:pos]
        if not key:
            raise _TokenError(key_start, f"expected a key before {text[pos : pos + 10]!r}")
        attr: str | None = None
        if pos < n and text[pos] == "{":
            close = text.find("}", pos + 1)
            if close < 0:
                raise _TokenError(key_start, f"{key}: unterminated '{{' (missing '}}')")
            attr = text[pos + 1 : close]
            pos = close + 1
        while pos < n and text[pos] in _WHITESPACE:
            pos += 1
        op: Op | None = None
        for candidate in (Op.MATCH, Op.NOMATCH, Op.ADD, Op.REMOVE, Op.ASSIGN_FINAL, Op.ASSIGN):
            if text.startswith(candidate.value, pos):
                op = candidate
                break
        if op is None:
            found = text[pos : pos + 2] or "end of rule"
            raise _TokenError(
                key_start,
                f"{key}: missing or invalid operator (found {found!r}; "
                "expected ==, !=, =, +=, -= or :=)",
            )
        pos += len(op.value)
        if op is Op.ASSIGN and pos < n and text[pos] in "=~<>":
            raise _TokenError(key_start, f"{key}: invalid operator '={text[pos]}'")
        while pos < n and text[pos] in _WHITESPACE:
            pos += 1
        escaped = case_insensitive = False
        prefix_start = pos
        while pos < n and pos - prefix_start < 2 and text[pos] in "ei":
            if text[pos] == "e" and not escaped:
                escaped = True
            elif text[pos] == "i" and not case_insensitive:
                case_insensitive = True
            else:
                break
            pos += 1
        if pos >= n or text[pos] != '"':
            shown = text[prefix_start : prefix_start + 12] or "end of rule"
            raise _TokenError(key_start, f"{key}: value must be in double quotes (found {shown!r})")
        pos += 1
        chars: list[str] = []
        while True:
            if pos >= n:
                raise _TokenError(key_start, f"{key}: unterminated double-quoted value")
            c = text[pos]
            if c == '"':
                pos += 1
                break
            if c == "\\" and pos + 1 < n:
                if escaped:
                    chars.append(text[pos : pos + 2])
                    pos += 2
                    continue
                if text[pos + 1] == '"':
                    chars.append('"')
                    pos += 2
                    continue
            chars.append(c)
            pos += 1
        value = "".join(chars)
        if escaped:
            problem = _c_unescape_problem(value)
            if problem:
                raise _TokenError(key_start, f'{key}: invalid escape in e"..." value: {problem}')
            value = value.encode("latin-1", "backslashreplace").decode("unicode_escape")
        tokens.append((key_start, key, attr, op, value, case_insensitive))
    return tokens, notes


def _check_token(tok: Token, add: Callable[[tuple[str, str]], object]) -> Token | None:
    """Check one token against :data:`KEYS`; report through ``add(severity, message)``.

    Returns the token as udev would use it (operator normalised), or None when udev
    would reject it.
    """
    spec = KEYS.get(tok.key)
    if spec is None:
        add(("error", f"unknown key {tok.key!r}{_suggest(tok.key)}"))
        return None
    name = tok.key
    if tok.case_insensitive and not tok.op.is_match:
        add(("error", f"{name}: the 'i' prefix is only for '==' and '!=', not {tok.op.value!r}"))
        return None
    if tok.case_insensitive and not spec.case_prefix:
        add(("error", f"{name} does not take the 'i' (case-insensitive) prefix"))
        return None
    # attribute
    if spec.attr == "none" and tok.attr is not None:
        add(("error", f"{name} takes no {{attribute}} (found {name}{{{tok.attr}}})"))
        return None
    if spec.attr == "required" and not tok.attr:
        example = {"ATTRS": "idVendor", "ATTR": "type", "ENV": "ID_VENDOR_ID"}.get(name, "...")
        add(("error", f"{name} needs an attribute in braces, e.g. {name}{{{example}}}"))
        return None
    if tok.attr is not None and spec.attr_values is not None and tok.attr not in spec.attr_values:
        allowed = ", ".join(sorted(spec.attr_values))
        add(("error", f"{name}{{{tok.attr}}}: the attribute must be one of {allowed}"))
        return None
    if name == "TEST" and tok.attr and not re.fullmatch(r"0?[0-7]{1,4}", tok.attr):
        add(("error", f"TEST{{{tok.attr}}}: the attribute must be an octal file mode"))
        return None
    if tok.attr is not None and name in ("ATTR", "ATTRS", "SYSCTL"):
        problem = _format_problem(tok.attr)
        if problem:
            add(("error", f"{name}{{{tok.attr}}}: {problem}"))
    # operator
    op = tok.op
    if op.is_match and not spec.match:
        add(
            (
                "error",
                f"{name} is an assignment key: it takes {_describe_ops(spec.accepted())}, "
                f"not {op.value!r}",
            )
        )
        return None
    if not op.is_match and op not in spec.assign:
        if op in spec.assumed:
            add(
                (
                    "warning",
                    f"{name} does not take {op.value!r}; udev assumes '=' "
                    f"(it takes {_describe_ops(spec.accepted())})",
                )
            )
            op = Op.ASSIGN
        elif op in spec.as_match:
            op = Op.MATCH  # udev's own rules write IMPORT{builtin}="usb_id": no complaint
        elif not spec.assign and spec.match:
            add(("error", f"{name} is a match key: it takes '==' or '!=', not {op.value!r}"))
            return None
        else:
            add(
                (
                    "error",
                    f"{name} does not take {op.value!r}; it takes {_describe_ops(spec.accepted())}",
                )
            )
            return None
    value = tok.value
    # value
    assigning = not op.is_match
    if spec.nonempty and not value:
        add(("error", f"{name}: empty value"))
        return None
    if name == "TAG" and assigning and not value:
        add(("error", "TAG: empty value"))
        return None
    if spec.formatted and (assigning or name in ("TEST", "PROGRAM", "IMPORT")):
        problem = _format_problem(value)
        if problem:
            add(("error", f"{name}: {problem}"))
            return None
    if assigning:
        if name == "NAME" and value in ("", "%k", "$kernel"):
            add(("error", f'NAME="{value}" has no effect; udev ignores it'))
            return None
        if name == "ENV" and tok.attr is not None and tok.attr in _READONLY_ENV:
            add(("error", f"ENV{{{tok.attr}}} cannot be set: the kernel or udevd owns it"))
            return None
        substituted = "$" in value or "%" in value
        if name == "MODE" and not substituted and not re.fullmatch(r"0?[0-7]{1,4}", value):
            add(("error", f'MODE="{value}" is not an octal file mode (e.g. "0660")'))
            return None
        if (
            name in ("OWNER", "GROUP")
            and not substituted
            and not re.fullmatch(r"[A-Za-z0-9_][A-Za-z0-9_.-]*\$?", value)
        ):
            add(("error", f'{name}="{value}" is not a user or group name'))
            return None
        if name == "OPTIONS":
            problem = _options_problem(value)
            if problem:
                add(("error", f"OPTIONS: {problem}"))
                return None
        if name == "RUN" and tok.attr == "builtin" and value.split()[0] not in BUILTINS:
            add(("error", f"RUN{{builtin}}: unknown builtin {value.split()[0]!r}"))
            return None
        if name in ("SYMLINK", "NAME") and value.startswith("/"):
            add(("warning", f"{name}: the value is relative to /dev; drop the leading '/'"))
    if name == "IMPORT" and tok.attr == "builtin" and value.split()[0] not in BUILTINS:
        add(("error", f"IMPORT{{builtin}}: unknown builtin {value.split()[0]!r}"))
        return None
    if name == "SUBSYSTEM" and value in ("bus", "class"):
        add(("warning", f'SUBSYSTEM=="{value}" must be written as "subsystem"'))
    if op is tok.op:
        return tok
    return Token(tok.key, tok.attr, op, tok.value, tok.line, tok.case_insensitive)


def _options_problem(value: str) -> str | None:
    if value in _OPTIONS_PLAIN:
        return None
    key, sep, arg = value.partition("=")
    if sep and key == "static_node":
        return None if arg else "static_node= needs a device node name"
    if sep and key == "link_priority":
        return (
            None
            if re.fullmatch(r"[+-]?[0-9]+", arg)
            else f"link_priority {arg!r} is not an integer"
        )
    if sep and key == "log_level":
        return None if arg in _LOG_LEVELS else f"unknown log level {arg!r}"
    known = sorted(_OPTIONS_PLAIN | {"static_node=", "link_priority=", "log_level="})
    return f"unknown option {value!r} (udev ignores it; known: {', '.join(known)})"


def parse_rules(text: str, path: str = "<rules>") -> RulesFile:
    """Parse and check the text of one rules file.

    Never raises on bad rules: a rule udev would reject is left out of
    :attr:`RulesFile.rules` and explained in :attr:`RulesFile.issues`.
    """
    issues: list[Issue] = []
    rules: list[Rule] = []
    for logical in _logical_lines(text, path, issues):
        try:
            raw, notes = _scan_tokens(logical.text)
        except _TokenError as exc:
            issues.append(
                Issue(
                    path,
                    logical.line_at(exc.offset),
                    "error",
                    f"{exc.message}; udev ignores this rule",
                )
            )
            continue
        for note in notes:
            issues.append(Issue(path, logical.first, "warning", note))
        tokens: list[Token] = []
        rejected = False
        for offset, key, attr, op, value, ci in raw:
            line = logical.line_at(offset)
            found: list[tuple[str, str]] = []
            tok = _check_token(Token(key, attr, op, value, line, ci), found.append)
            for severity, message in found:
                issues.append(Issue(path, line, severity, message))
            if tok is None:
                rejected = True
            else:
                tokens.append(tok)
        if rejected:
            continue
        gotos = [t for t in tokens if t.key == "GOTO"]
        labels = [t for t in tokens if t.key == "LABEL"]
        if len(gotos) > 1:
            issues.append(
                Issue(path, logical.first, "warning", "more than one GOTO; udev uses the first")
            )
        if len(labels) > 1:
            issues.append(
                Issue(path, logical.first, "warning", "more than one LABEL; udev uses the last")
            )
        effective = any(not t.op.is_match or t.key in ("PROGRAM", "IMPORT") for t in tokens)
        if not effective:
            issues.append(
                Issue(
                    path,
                    logical.first,
                    "warning",
                    "the rule only matches and assigns nothing: it has no effect",
                )
            )
        rules.append(Rule(path, logical.first, logical.last, logical.text, tuple(tokens)))
    _check_gotos(path, rules, issues)
    issues.sort(key=lambda i: (i.line, i.severity != "error"))
    return RulesFile(path, tuple(rules), tuple(issues))


def _check_gotos(path: str, rules: Sequence[Rule], issues: list[Issue]) -> None:
    labels_at: dict[str, list[int]] = {}
    for index, rule in enumerate(rules):
        for tok in rule.tokens:
            if tok.key == "LABEL":
                labels_at.setdefault(tok.value, []).append(index)
    used: set[str] = set()
    for index, rule in enumerate(rules):
        target = rule.goto
        if target is None:
            continue
        later = [i for i in labels_at.get(target, []) if i > index]
        if later:
            used.add(target)
            continue
        earlier = labels_at.get(target)
        if earlier:
            issues.append(
                Issue(
                    path,
                    rule.line,
                    "error",
                    f'GOTO="{target}" jumps backwards to line {rules[earlier[0]].line}: '
                    "udev only jumps forward, to a LABEL later in the same file",
                )
            )
        else:
            close = difflib.get_close_matches(target, labels_at, n=1)
            hint = f' (did you mean "{close[0]}"?)' if close else ""
            issues.append(
                Issue(
                    path,
                    rule.line,
                    "error",
                    f'GOTO="{target}" has no matching LABEL later in this file{hint}',
                )
            )
    for label, indexes in labels_at.items():
        if label not in used:
            issues.append(
                Issue(path, rules[indexes[0]].line, "warning", f'LABEL="{label}" is never used')
            )


def load_rules(path: str | Path) -> RulesFile:
    """Read and parse one rules file (UTF-8). Raises OSError if it cannot be read."""
    p = Path(path)
    return parse_rules(p.read_text(encoding="utf-8"), str(p))


def check_files(paths: Iterable[str | Path], *, strict: bool = True) -> list[Issue]:
    """Issues of every rules file in ``paths``: errors, and warnings too if ``strict``."""
    found: list[Issue] = []
    for path in paths:
        parsed = load_rules(path)
        found.extend(i for i in parsed.issues if strict or i.severity == "error")
        logger.debug("%s: %d rules, %d issues", path, len(parsed.rules), len(parsed.issues))
    return found


# ------------------------------------------------------------------------ evaluation


@dataclass(frozen=True)
class DeviceNode:
    """One device of a sysfs chain: its kernel name, subsystem, driver and attributes."""

    kernel: str
    subsystem: str
    driver: str | None = None
    attrs: Mapping[str, str] = field(default_factory=dict)


@dataclass(frozen=True)
class UdevEvent:
    """A uevent to replay: the device first in ``chain``, then its parents upwards."""

    chain: tuple[DeviceNode, ...]
    env: Mapping[str, str] = field(default_factory=dict)
    action: str = "add"


@dataclass(frozen=True)
class RuleHit:
    """A rule that matched the event and assigned something."""

    path: str
    line: int
    assigned: tuple[str, ...]

    @property
    def where(self) -> str:
        return f"{Path(self.path).name}:{self.line}"


@dataclass(frozen=True)
class Outcome:
    """What the rules would do to the event (see :func:`evaluate`)."""

    symlinks: tuple[str, ...] = ()
    name: str | None = None
    owner: str | None = None
    group: str | None = None
    mode: str | None = None
    env: Mapping[str, str] = field(default_factory=dict)
    hits: tuple[RuleHit, ...] = ()
    assumed: tuple[str, ...] = ()


_UNEVALUATED = frozenset(
    {"DEVPATH", "RESULT", "CONST", "TAGS", "TEST", "PROGRAM", "IMPORT", "SYSCTL", "TAG"}
)


def _glob_hit(value: str, tok: Token) -> bool:
    """Whether ``value`` matches one of the ``|``-separated globs of ``tok``."""
    pattern = tok.value
    if tok.case_insensitive:
        value, pattern = value.lower(), pattern.lower()
    alternatives = pattern.split("|") if pattern else [""]
    return any(
        (value == "" if alt == "" else fnmatch.fnmatchcase(value, alt)) for alt in alternatives
    )


def _glob_match(value: str | None, tok: Token) -> bool:
    """udev's verdict on a match token; a missing value (None) never matches."""
    if value is None:
        return False
    return _glob_hit(value, tok) == (tok.op is Op.MATCH)


def _device_value(tok: Token, node: DeviceNode, event: UdevEvent, state: _State) -> str | None:
    if tok.key == "ACTION":
        return event.action
    if tok.key in ("KERNEL", "KERNELS"):
        return node.kernel
    if tok.key in ("SUBSYSTEM", "SUBSYSTEMS"):
        return node.subsystem
    if tok.key in ("DRIVER", "DRIVERS"):
        return node.driver or ""
    if tok.key in ("ATTR", "ATTRS"):
        value = node.attrs.get(tok.attr or "")
        return value.rstrip() if value is not None else None
    if tok.key == "ENV":
        return state.env.get(tok.attr or "", "")
    if tok.key == "NAME":
        return state.name or ""
    if tok.key == "SYMLINK":
        return " ".join(state.symlinks)
    return None


@dataclass
class _State:
    env: dict[str, str]
    symlinks: list[str] = field(default_factory=list)
    name: str | None = None
    owner: str | None = None
    group: str | None = None
    mode: str | None = None
    final: set[str] = field(default_factory=set)


def _rule_matches(rule: Rule, event: UdevEvent, state: _State, assumed: list[str]) -> bool:
    device = event.chain[0]
    parent_tokens: list[Token] = []
    for tok in rule.tokens:
        if not tok.op.is_match:
            continue
        spec = KEYS[tok.key]
        if tok.key in _UNEVALUATED:
            assumed.append(f"{Path(rule.path).name}:{tok.line}: {tok}")
            continue
        if spec.parent:
            parent_tokens.append(tok)
            continue
        if tok.key == "SYMLINK":
            hit = any(_glob_hit(link, tok) for link in state.symlinks)
            if hit != (tok.op is Op.MATCH):
                return False
            continue
        if not _glob_match(_device_value(tok, device, event, state), tok):
            return False
    if not parent_tokens:
        return True
    return any(
        all(_glob_match(_device_value(t, node, event, state), t) for t in parent_tokens)
        for node in event.chain
    )


def _expand(value: str, event: UdevEvent, state: _State) -> str:
    """The few substitutions the evaluator resolves; the others stay as written."""
    device = event.chain[0]
    value = re.sub(r"(?:\$env|%E)\{([^}]*)\}", lambda m: state.env.get(m.group(1), ""), value)
    return value.replace("$kernel", device.kernel).replace("%k", device.kernel)


def _apply(rule: Rule, event: UdevEvent, state: _State) -> tuple[str, ...]:
    done: list[str] = []
    for tok in rule.tokens:
        if tok.op.is_match or tok.key in ("GOTO", "LABEL"):
            continue
        value = _expand(tok.value, event, state)
        key = tok.key
        if key in state.final and key in ("SYMLINK", "NAME", "OWNER", "GROUP", "MODE"):
            continue
        if tok.op is Op.ASSIGN_FINAL:
            state.final.add(key)
        if key == "SYMLINK":
            links = value.split()
            if tok.op in (Op.ASSIGN, Op.ASSIGN_FINAL):
                state.symlinks = links
            elif tok.op is Op.ADD:
                state.symlinks.extend(link for link in links if link not in state.symlinks)
            elif tok.op is Op.REMOVE:
                state.symlinks = [link for link in state.symlinks if link not in links]
        elif key == "NAME":
            state.name = value
        elif key == "OWNER":
            state.owner = value
        elif key == "GROUP":
            state.group = value
        elif key == "MODE":
            state.mode = value
        elif key == "ENV" and tok.attr:
            if tok.op is Op.ADD and state.env.get(tok.attr):
                state.env[tok.attr] = f"{state.env[tok.attr]} {value}"
            else:
                state.env[tok.attr] = value
        else:
            continue
        done.append(str(tok))
    return tuple(done)


def evaluate(files: Sequence[RulesFile], event: UdevEvent) -> Outcome:
    """Replay ``event`` through ``files`` (in the order given, as udev orders them).

    Rules with issues that udev would reject are already absent from the files. Keys
    the event cannot answer (``PROGRAM``, ``TEST``, ``IMPORT``, ...) are assumed to
    match and are listed in :attr:`Outcome.assumed`. ``GOTO`` jumps within a file.
    """
    if not event.chain:
        raise ValueError("an event needs at least the device itself in its chain")
    state = _State(env=dict(event.env))
    hits: list[RuleHit] = []
    assumed: list[str] = []
    for rules_file in files:
        rules = rules_file.rules
        index = 0
        while index < len(rules):
            rule = rules[index]
            index += 1
            probe: list[str] = []
            if not _rule_matches(rule, event, state, probe):
                continue
            assumed.extend(probe)
            assigned = _apply(rule, event, state)
            if assigned:
                hits.append(RuleHit(rule.path, rule.line, assigned))
            target = rule.goto
            if target is not None:
                for later in range(index, len(rules)):
                    if rules[later].label == target:
                        index = later
                        break
    return Outcome(
        symlinks=tuple(state.symlinks),
        name=state.name,
        owner=state.owner,
        group=state.group,
        mode=state.mode,
        env=state.env,
        hits=tuple(hits),
        assumed=tuple(assumed),
    )
