"""README.md: one screen to the two commands, the command CI runs is the one it gives, and
its index names every page of docs/ and nothing that is not there."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text(encoding="utf-8")
DEMO = "bash .ci/bootstrap && .venv/bin/rover demo"
TEST = "bash .ci/test"


def test_the_two_commands_come_within_the_first_screen() -> None:
    first_screen = "\n".join(README.splitlines()[:24])
    assert f"`{DEMO}`" in first_screen and f"`{TEST}`" in first_screen
    assert len(README.splitlines()) <= 50


def test_ci_runs_the_test_command_the_readme_gives() -> None:
    run = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    commands = [
        line for line in run.splitlines() if line and not line.startswith(("#", "set ", "cd "))
    ]
    assert commands == [f"exec {TEST}"]


def test_the_index_names_every_doc_and_each_link_exists() -> None:
    links = re.findall(r"\]\(([^)#]+)\)", README)
    assert all((ROOT / link).exists() for link in links), [
        link for link in links if not (ROOT / link).exists()
    ]
    docs = {f"docs/{p.name}" for p in (ROOT / "docs").glob("*.md")}
    assert docs <= set(links), sorted(docs - set(links))


def _anchors(page: Path) -> set[str]:
    """The anchors GitHub gives the headings of ``page``, and its ``<a id>`` ones."""
    text = page.read_text(encoding="utf-8")
    found = set(re.findall(r'<a id="([^"]+)"', text))
    for line in text.splitlines():
        if line.startswith("#"):
            title = line.lstrip("#").strip().lower()
            found.add(re.sub(r"[^\w\- ]", "", title).replace(" ", "-"))
    return found


def test_the_docs_link_only_to_files_and_headings_that_exist() -> None:
    broken = []
    pages = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
    for page in pages:
        text = page.read_text(encoding="utf-8")
        for link, anchor in re.findall(r"\]\(([^)#\s]*)(?:#([^)\s]*))?\)", text):
            if "://" in link:
                continue
            target = (page.parent / link) if link else page
            if not target.exists():
                broken.append(f"{page.name}: {link}")
            elif anchor and target.suffix == ".md" and anchor not in _anchors(target):
                broken.append(f"{page.name}: {link}#{anchor}")
    assert broken == []
