"""udev rules files, read and replayed: which of our rules would name a device.

:func:`parse_rules` reads a rules file the way ``systemd-udevd`` splits it (udev(7):
comments, continuations, ``KEY[{attribute}] OP "value"`` tokens, ``e"..."`` and
``i"..."`` values). It judges nothing (:mod:`udev.verify` asks udev): a rule it cannot
split, or with a key udev does not know, is left out and listed in
:attr:`RulesFile.issues`, as udev leaves it out.

:func:`evaluate` replays an ``add`` event through parsed rules to tell which rule would
name a device (``rover devices``), without the device plugged in or the rules
installed. Keys a device description cannot answer are assumed true and listed in
:attr:`UdevOutcome.assumed`.
"""

from __future__ import annotations

import enum
import fnmatch
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

__all__ = [
    "KEYS",
    "PARENT_KEYS",
    "DeviceNode",
    "Issue",
    "Op",
    "RuleHit",
    "RulesFile",
    "Token",
    "UdevEvent",
    "UdevOutcome",
    "UdevRule",
    "evaluate",
    "load_rules",
    "parse_rules",
]


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
        """``==`` or ``!=``."""
        return self in (Op.MATCH, Op.NOMATCH)


KEYS = frozenset(
    {
        "ACTION", "DEVPATH", "KERNEL", "SUBSYSTEM", "DRIVER", "RESULT", "CONST", "KERNELS",
        "SUBSYSTEMS", "DRIVERS", "TAGS", "ATTRS", "SYMLINK", "NAME", "ENV", "TAG", "ATTR",
        "SYSCTL", "TEST", "PROGRAM", "IMPORT", "OPTIONS", "OWNER", "GROUP", "MODE",
        "SECLABEL", "RUN", "GOTO", "LABEL",
    }
)  # fmt: skip
"""Every key udev knows (systemd-udevd's ``parse_token()``); a rule naming another is left out."""

PARENT_KEYS = frozenset({"KERNELS", "SUBSYSTEMS", "DRIVERS", "TAGS", "ATTRS"})
"""Match keys evaluated on the device or one of its parents: the same one for all of a rule's."""

_AS_MATCH = frozenset({"PROGRAM", "IMPORT"})
"""Keys that udev takes as a match whatever their operator (``IMPORT{builtin}="x"``)."""

_WHITESPACE = " \t\n\r"


@dataclass(frozen=True)
class Issue:
    """A problem at a line of a rules file, ``path:line: message``: a rule this reader
    left out, or what udev found (:mod:`udev.verify`; line 0: the file as a whole)."""

    path: str
    line: int
    message: str

    def __str__(self) -> str:
        return f"{self.path}:{self.line}: {self.message}"


@dataclass(frozen=True)
class Token:
    """One ``KEY{attr} OP "value"`` of a rule; ``line`` is its physical line."""

    key: str
    attr: str | None
    op: Op
    value: str
    line: int
    case_insensitive: bool = False

    def __str__(self) -> str:
        attr = f"{{{self.attr}}}" if self.attr is not None else ""
        prefix = "i" if self.case_insensitive else ""
        escaped = self.value.replace('"', '\\"')
        return f'{self.key}{attr}{self.op.value}{prefix}"{escaped}"'


@dataclass(frozen=True)
class UdevRule:
    """One logical rule line: its tokens, where it starts and ends."""

    path: str
    line: int
    end_line: int
    text: str
    tokens: tuple[Token, ...]

    @property
    def label(self) -> str | None:
        """The rule's ``LABEL``, if it has one."""
        return next((t.value for t in self.tokens if t.key == "LABEL"), None)

    @property
    def goto(self) -> str | None:
        """The rule's ``GOTO`` target, if it has one."""
        return next((t.value for t in self.tokens if t.key == "GOTO"), None)


@dataclass(frozen=True)
class RulesFile:
    """A read rules file: its rules and the rules it left out."""

    path: str
    rules: tuple[UdevRule, ...]
    issues: tuple[Issue, ...] = ()


# --------------------------------------------------------------------------- reading


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


def _logical_lines(text: str) -> list[_Logical]:
    """Join continuations and drop comments and blank lines, as udev reads a file."""
    out: list[_Logical] = []
    pending: _Logical | None = None
    for number, raw in enumerate(text.splitlines(), start=1):
        line = raw.lstrip(_WHITESPACE)
        if line.startswith("#"):
            continue
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
        if current.text.strip(_WHITESPACE):
            out.append(current)
    return out


class _UnreadableError(Exception):
    def __init__(self, offset: int, message: str) -> None:
        super().__init__(message)
        self.offset = offset
        self.message = message


_TOKEN = re.compile(r'([A-Za-z_.]+)(?:\{([^}]*)\})?\s*(==|!=|\+=|-=|:=|=)\s*([ei]{0,2})"')
"""``KEY{attr} OP`` and the value's prefix, up to its opening quote."""


def _tokens(text: str) -> list[tuple[int, str, str | None, Op, str, bool]]:
    """Split one logical line into ``(offset, key, attr, op, value, case_insensitive)``
    tuples, as udev's ``parse_line()`` does; :class:`_UnreadableError` where it cannot."""
    found: list[tuple[int, str, str | None, Op, str, bool]] = []
    pos, n = 0, len(text)
    while True:
        while pos < n and (text[pos] in _WHITESPACE or text[pos] == ","):
            pos += 1
        if pos >= n:
            return found
        start = pos
        match = _TOKEN.match(text, pos)
        if match is None:
            raise _UnreadableError(
                start, f'cannot read a KEY OP "value" at {text[pos : pos + 20]!r}'
            )
        key, attr, spelling, prefix = match.groups()
        pos = match.end()
        chars: list[str] = []
        while True:
            if pos >= n:
                raise _UnreadableError(start, f"{key}: unterminated double-quoted value")
            c = text[pos]
            if c == '"':
                pos += 1
                break
            if c == "\\" and pos + 1 < n and ("e" in prefix or text[pos + 1] == '"'):
                chars.append(text[pos : pos + 2] if "e" in prefix else '"')
                pos += 2
                continue
            chars.append(c)
            pos += 1
        value = "".join(chars)
        if "e" in prefix:
            try:
                value = value.encode("latin-1", "backslashreplace").decode("unicode_escape")
            except UnicodeDecodeError as exc:
                raise _UnreadableError(start, f'{key}: invalid escape in e"...": {exc}') from exc
        found.append((start, key, attr, Op(spelling), value, "i" in prefix))


def parse_rules(text: str, path: str = "<rules>") -> RulesFile:
    """Read the text of one rules file. Never raises on bad rules: one it cannot read
    is left out of :attr:`RulesFile.rules` and listed in :attr:`RulesFile.issues`."""
    issues: list[Issue] = []
    rules: list[UdevRule] = []
    for logical in _logical_lines(text):
        try:
            raw = _tokens(logical.text)
        except _UnreadableError as exc:
            issues.append(Issue(path, logical.line_at(exc.offset), exc.message))
            continue
        unknown = [key for _, key, *_ in raw if key not in KEYS]
        if unknown:
            issues.append(Issue(path, logical.first, f"unknown key {unknown[0]!r}"))
            continue
        tokens = tuple(
            Token(key, attr, Op.MATCH if key in _AS_MATCH else op, value, logical.line_at(at), ci)
            for at, key, attr, op, value, ci in raw
        )
        rules.append(UdevRule(path, logical.first, logical.last, logical.text, tokens))
    return RulesFile(path, tuple(rules), tuple(issues))


def load_rules(path: str | Path) -> RulesFile:
    """Read one rules file (UTF-8). Raises OSError if it cannot be read."""
    p = Path(path)
    return parse_rules(p.read_text(encoding="utf-8"), str(p))


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
class UdevOutcome:
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


def _rule_matches(rule: UdevRule, event: UdevEvent, state: _State, assumed: list[str]) -> bool:
    device = event.chain[0]
    parent_tokens: list[Token] = []
    for tok in rule.tokens:
        if not tok.op.is_match:
            continue
        if tok.key in _UNEVALUATED:
            assumed.append(f"{Path(rule.path).name}:{tok.line}: {tok}")
            continue
        if tok.key in PARENT_KEYS:
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


def _apply(rule: UdevRule, event: UdevEvent, state: _State) -> tuple[str, ...]:
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


def evaluate(files: Sequence[RulesFile], event: UdevEvent) -> UdevOutcome:
    """Replay ``event`` through ``files`` (in the order given, as udev orders them).

    Keys the event cannot answer (``PROGRAM``, ``TEST``, ...) are assumed to match and
    listed in :attr:`UdevOutcome.assumed`. ``GOTO`` jumps within a file.
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
    return UdevOutcome(
        symlinks=tuple(state.symlinks),
        name=state.name,
        owner=state.owner,
        group=state.group,
        mode=state.mode,
        env=state.env,
        hits=tuple(hits),
        assumed=tuple(assumed),
    )
