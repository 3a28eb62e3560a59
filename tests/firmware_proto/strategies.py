"""Hypothesis strategies for protocol messages, built from the spec model."""

from __future__ import annotations

from hypothesis import strategies as st

from firmware_proto.wire.message import Message
from firmware_proto.wire.messages import BY_NAME
from firmware_proto.wire.spec import MessageSpec, load_spec

SPEC = load_spec()


def message_of(spec: MessageSpec, *, within_limits: bool = True) -> st.SearchStrategy[Message]:
    """Any valid instance of one message type (inside semantic limits by default)."""
    cls = BY_NAME[spec.name]
    fields = {}
    for f in spec.public_fields:
        lo, hi = f.limit if (within_limits and f.limit) else (f.min, f.max)
        fields[f.name] = st.integers(lo, hi)
    return st.builds(cls, **fields)


def any_message(*, within_limits: bool = True) -> st.SearchStrategy[Message]:
    """An instance of any message type."""
    return st.one_of([message_of(m, within_limits=within_limits) for m in SPEC.messages])
