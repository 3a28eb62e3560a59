"""The processes below a process, from ``/proc`` (Linux): what the tests that check
children (none leaked, a node's process, the browser's) read; and a snippet of Python
run in a child of its own (signals are a process's main thread's)."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

__all__ = ["children", "descendants", "run_snippet"]

ROOT = Path(__file__).resolve().parents[1]


def children(pid: int) -> set[int]:
    """The live children of ``pid``, started by any of its threads (none if it ended)."""
    found: set[int] = set()
    try:
        tasks = list(Path(f"/proc/{pid}/task").iterdir())
    except OSError:
        return found
    for task in tasks:
        try:
            found.update(int(child) for child in (task / "children").read_text().split())
        except OSError:  # the thread ended meanwhile
            continue
    return found


def descendants(pid: int) -> set[int]:
    """Every process below ``pid``: its children, theirs, and so on."""
    found: set[int] = set()
    todo = [pid]
    while todo:
        for child in children(todo.pop()) - found:
            found.add(child)
            todo.append(child)
    return found


def run_snippet(header: str, body: str, timeout_s: float = 60.0) -> dict[str, object]:
    """Run ``header`` then ``body`` (dedented) as a Python program in a child, at the
    repository's root; the JSON object it prints last. Its exit status must be 0."""
    done = subprocess.run(
        [sys.executable, "-c", header + "\n" + textwrap.dedent(body)],
        capture_output=True, text=True, cwd=ROOT, timeout=timeout_s, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    return dict(json.loads(done.stdout.splitlines()[-1]))
