"""Every pointer to a docs section names one that exists.

Docstrings, comments and the docs themselves defer to a section of a docs page as
``docs/<page>.md, "<Section>"`` (more sections may follow: ``, "<Other>"``, ``and
"<Other>"``). The section must be a heading of that page, or a bold paragraph label in it
(``**Label.**``); a heading may go on after the name (``"Latch and faults"`` names
``## Latch and faults: the rules``). Read from the docstrings and comments of every
module outside tests/ (code strings are not prose) and from docs/*.md.
"""

from __future__ import annotations

import ast
import io
import re
import subprocess
import tokenize
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"

_QUOTED = r'"([^"\n]{1,120})"'
POINTER = re.compile(
    r"(?:docs/)?([a-z0-9][a-z0-9_-]*\.md)(?:'s)?,?\s+(?:section\s+)?"
    + _QUOTED
    + r"((?:\s*(?:,|;|and|or)\s*"
    + _QUOTED
    + r")*)"
)


def _norm(text: str) -> str:
    return re.sub(r"\s+", " ", re.sub(r"[`*_]", "", text)).strip().lower().rstrip(".:?")


def _sections(page: Path) -> set[str]:
    """The page's headings and bold paragraph labels, normalised."""
    text = page.read_text(encoding="utf-8")
    found = {_norm(m) for m in re.findall(r"^#{1,6}\s+(.+?)\s*$", text, re.M)}
    found |= {_norm(m) for m in re.findall(r"\*\*([^*\n]{1,120}?)\*\*", text)}
    return found


def _names(section: str, sections: set[str]) -> bool:
    want = _norm(section)
    return any(s == want or re.match(re.escape(want) + r"\s*[:(,\-\u2014]", s) for s in sections)


def _prose(path: Path) -> str:
    """A module's docstrings and comments (every bare string statement, every comment)."""
    source = path.read_text(encoding="utf-8")
    parts = [
        node.value.value
        for node in ast.walk(ast.parse(source))
        if isinstance(node, ast.Expr)
        and isinstance(node.value, ast.Constant)
        and isinstance(node.value.value, str)
    ]
    parts += [
        tok.string.lstrip("#")
        for tok in tokenize.generate_tokens(io.StringIO(source).readline)
        if tok.type == tokenize.COMMENT
    ]
    return "\n".join(parts)


def _texts() -> dict[str, str]:
    listed = subprocess.run(
        ["git", "-C", str(ROOT), "ls-files", "*.py", "docs/*.md"],
        capture_output=True,
        text=True,
        timeout=60,
        check=True,
    ).stdout.split()
    texts = {}
    for name in listed:
        if name.startswith("tests/"):
            continue
        path = ROOT / name
        texts[name] = _prose(path) if name.endswith(".py") else path.read_text(encoding="utf-8")
    return texts


def _flat(text: str) -> str:
    """``text`` on one line: line breaks and comment leaders folded into spaces."""
    return re.sub(r"\s*\n\s*#?\s*", " ", text)


def _pointers() -> list[tuple[str, str, str]]:
    """(file, page, section) of every pointer, comment leaders and line breaks folded."""
    found = []
    for name, text in _texts().items():
        for m in POINTER.finditer(_flat(text)):
            for section in [m.group(2), *re.findall(_QUOTED, m.group(3))]:
                found.append((name, m.group(1), section))
    return found


def test_every_pointer_names_a_section_that_exists() -> None:
    pointers = _pointers()
    assert len(pointers) > 50  # the scan reads what it should
    pages = {page.name: _sections(page) for page in DOCS.glob("*.md")}
    broken = [
        f'{name}: {page}, "{section}"'
        for name, page, section in pointers
        if page in pages and not _names(section, pages[page])
    ]
    assert broken == []


def test_the_scan_finds_a_pointer_in_a_wrapped_docstring(tmp_path: Path) -> None:
    module = tmp_path / "m.py"
    module.write_text('"""Says so (docs/protocol.md,\n"Latch and faults", "Nowhere")."""\n')
    (m,) = POINTER.finditer(_flat(_prose(module)))
    assert (m.group(1), m.group(2), re.findall(_QUOTED, m.group(3))) == (
        "protocol.md",
        "Latch and faults",
        ["Nowhere"],
    )
    sections = _sections(DOCS / "protocol.md")
    assert _names("Latch and faults", sections)
    assert not _names("Nowhere", sections)
