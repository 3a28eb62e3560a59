"""The processes below a process, from ``/proc`` (Linux): what the tests that check
children (none leaked, a node's process, the browser's) read."""

from __future__ import annotations

from pathlib import Path

__all__ = ["children", "descendants"]


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
