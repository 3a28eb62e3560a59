"""Copies of generated ROS 2 messages, as a trip through DDS would give each receiver,
cheaply: :func:`copy_message`; and their values, flat (:func:`message_values`), for a
digest of what crossed a link.

The in-process port copies every message once per subscription, and ``copy.deepcopy``
is slow for messages with numpy arrays. A generated message keeps its fields in
``__slots__``, each holding one kind of value (the generated setters check it): a plain
value, a nested message, or a container. The first message of a class seen gives those
kinds, and a small function is compiled for the class that copies (or walks) exactly
those slots: nested messages by their own function, containers copied, plain values
shared. A slot that later holds another kind of value is copied the generic way; the
copy never runs the field checks again.
"""

from __future__ import annotations

import array
import copy
from collections.abc import Callable
from typing import Any, TypeVar

from bridge.ros.rosport.names import is_message_type

__all__ = ["copy_message", "message_values"]

M = TypeVar("M")

_IMMUTABLE = (int, float, str, bool, bytes, type(None))

_Copier = Callable[[Any], Any]
_Walker = Callable[[Any, list[Any]], None]
_COPIERS: dict[type[Any], _Copier | None] = {}
_WALKERS: dict[type[Any], _Walker | None] = {}


def copy_message(msg: M) -> M:
    """An independent copy of ``msg``: a generated message through its class's compiled
    copier, anything else with ``copy.deepcopy``."""
    cls = type(msg)
    try:
        copier = _COPIERS[cls]
    except KeyError:
        copier = _COPIERS[cls] = _compile_copier(cls, msg)
    if copier is None:
        return copy.deepcopy(msg)
    copied: M = copier(msg)
    return copied


def message_values(msg: Any) -> tuple[Any, ...]:
    """Every field value of ``msg``, depth first, as plain values (arrays as bytes): equal
    for equal messages, and cheap to hash."""
    out: list[Any] = []
    _walk(msg, out)
    return tuple(out)


def _slots(cls: type[Any]) -> tuple[str, ...] | None:
    """The value slots of a generated message class; ``None`` for anything else."""
    slots = getattr(cls, "__slots__", None)
    if not is_message_type(cls) or not isinstance(slots, (list, tuple)):
        return None
    return tuple(s for s in slots if s != "_check_fields")


def _is_message(value: Any) -> bool:
    return is_message_type(type(value)) and _slots(type(value)) is not None


def _compile_copier(cls: type[Any], sample: Any) -> _Copier | None:
    slots = _slots(cls)
    if slots is None:
        return None
    lines = ["def copier(m):", "    n = new(cls)", "    n._check_fields = m._check_fields"]
    for slot in slots:
        value = getattr(sample, slot)
        if isinstance(value, _IMMUTABLE):
            lines.append(f"    v = m.{slot}")
            lines.append(f"    n.{slot} = v if v.__class__ in immutable else generic(v)")
        elif _is_message(value):
            lines.append(f"    n.{slot} = message(m.{slot})")
        else:
            lines.append(f"    n.{slot} = generic(m.{slot})")
    lines.append("    return n")
    scope: dict[str, Any] = {
        "new": cls.__new__,
        "cls": cls,
        "message": copy_message,
        "generic": _copy,
        "immutable": frozenset(_IMMUTABLE),
    }
    exec("\n".join(lines), scope)  # the class's own slot names
    copier: _Copier = scope["copier"]
    return copier


def _copy(value: Any) -> Any:
    if isinstance(value, _IMMUTABLE):
        return value
    if _is_message(value):
        return copy_message(value)
    if isinstance(value, array.array):
        return array.array(value.typecode, value)
    if isinstance(value, list):
        return [_copy(v) for v in value]
    if isinstance(value, tuple):
        return tuple(_copy(v) for v in value)
    if type(value).__name__ == "ndarray":
        return value.copy()
    return copy.deepcopy(value)


def _walk(value: Any, out: list[Any]) -> None:
    if isinstance(value, _IMMUTABLE):
        out.append(value)
        return
    cls = type(value)
    try:
        walker = _WALKERS[cls]
    except KeyError:
        walker = _WALKERS[cls] = _compile_walker(cls, value)
    if walker is not None:
        walker(value, out)
        return
    if isinstance(value, (list, tuple)):
        out.append(len(value))
        for v in value:
            _walk(v, out)
        return
    tobytes = getattr(value, "tobytes", None)
    out.append(tobytes() if callable(tobytes) else repr(value))


def _compile_walker(cls: type[Any], sample: Any) -> _Walker | None:
    slots = _slots(cls)
    if slots is None:
        return None
    lines = ["def walker(m, out):"]
    plain = [s for s in slots if isinstance(getattr(sample, s), _IMMUTABLE)]
    for slot in slots:
        if slot in plain:
            lines.append(f"    v = m.{slot}")
            lines.append("    if v.__class__ in immutable: out.append(v)")
            lines.append("    else: walk(v, out)")
        else:
            lines.append(f"    walk(m.{slot}, out)")
    if len(lines) == 1:
        lines.append("    pass")
    scope: dict[str, Any] = {"walk": _walk, "immutable": frozenset(_IMMUTABLE)}
    exec("\n".join(lines), scope)  # the class's own slot names
    walker: _Walker = scope["walker"]
    return walker
