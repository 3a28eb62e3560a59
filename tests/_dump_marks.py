"""A pytest plugin for tests/test_lanes.py and ``.ci/test`` (which reads from it the
modules its serial and VM parts need): after collection (the lanes' marks applied by
tests/conftest.py), write each selected test's node id and the names of its marks, one
test per line (``nodeid<TAB>mark,mark``), to the file that ``ROVER_DUMP_MARKS`` names."""

from __future__ import annotations

import os
from pathlib import Path

import pytest


def pytest_collection_finish(session: pytest.Session) -> None:
    """Write the dump (once collection and every ``modifyitems`` hook are done)."""
    out = os.environ.get("ROVER_DUMP_MARKS")
    if not out:
        return
    lines = [
        item.nodeid + "\t" + ",".join(sorted({m.name for m in item.iter_markers()}))
        for item in session.items
    ]
    Path(out).write_text("\n".join(lines) + "\n")
