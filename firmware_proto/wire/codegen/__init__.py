"""Code generators: the protocol spec rendered into every artefact that speaks it.

:data:`TARGETS` maps each generated file (relative to the repository root) to the
function that renders it from the spec model. :func:`generate` writes them all;
:func:`stale` lists the files whose content differs from what the spec renders, which
the test suite asserts is empty. Generated files are never edited by hand.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from firmware_proto.wire.codegen.c import render_c_header, render_c_source
from firmware_proto.wire.codegen.dbc import render_dbc
from firmware_proto.wire.codegen.markdown import render_markdown
from firmware_proto.wire.codegen.python import render_python
from firmware_proto.wire.codegen.vectors import VECTOR_TARGETS
from firmware_proto.wire.spec import ProtocolSpec, load_spec

__all__ = ["REPO_ROOT", "TARGETS", "generate", "render_all", "stale"]

REPO_ROOT = Path(__file__).resolve().parents[3]

TARGETS: dict[str, Callable[[ProtocolSpec], str]] = {
    "firmware_proto/wire/messages.py": render_python,
    "firmware_proto/wire/rover.dbc": render_dbc,
    "docs/protocol.md": render_markdown,
    "firmware_proto/wire/c/rover_msgs.h": render_c_header,
    "firmware_proto/wire/c/rover_msgs.c": render_c_source,
    **VECTOR_TARGETS,
}


def render_all(spec: ProtocolSpec | None = None) -> dict[Path, str]:
    """Every generated file's path (under :data:`REPO_ROOT`) and its expected text."""
    spec = spec or load_spec()
    return {REPO_ROOT / rel: render(spec) for rel, render in TARGETS.items()}


def generate(spec: ProtocolSpec | None = None) -> list[Path]:
    """Write every generated file; returns the paths whose content changed."""
    changed = []
    for path, text in render_all(spec).items():
        if not path.exists() or path.read_text(encoding="utf-8") != text:
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(text, encoding="utf-8")
            changed.append(path)
    return changed


def stale(spec: ProtocolSpec | None = None) -> list[Path]:
    """Generated files that are missing or differ from what the spec renders."""
    return [
        path
        for path, text in render_all(spec).items()
        if not path.exists() or path.read_text(encoding="utf-8") != text
    ]
