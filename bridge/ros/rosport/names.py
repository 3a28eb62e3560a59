"""ROS 2 names: validation and expansion against a namespace and node; interface names.

The rules are those of rcl and rmw (``rcl_expand_topic_name`` and the ``*_validate_*``
functions), so a name accepted here is accepted by a ROS 2 node and resolves to the same
fully qualified name:

- ``"odom"`` in namespace ``"/rover1"`` -> ``"/rover1/odom"`` (relative names get the namespace);
- ``"/odom"`` -> ``"/odom"`` (absolute names do not);
- ``"~/status"`` of node ``bridge`` in ``"/rover1"`` -> ``"/rover1/bridge/status"`` (private);
- ``"{node}/status"`` -> ``"/rover1/bridge/status"`` (``{node}``, ``{ns}``, ``{namespace}``).

Names use ``A-Z a-z 0-9 _`` and ``/`` separators; no token starts with a digit; no ``//``;
no trailing ``/``; a fully qualified topic name has at most 247 characters (255 minus the
room rmw keeps for prefixes such as ``rt``). Every violation raises :class:`RosNameError`
saying which rule it broke.
"""

from __future__ import annotations

import re
from typing import Any, Final

from bridge.ros.rosport.errors import RosNameError

__all__ = [
    "NODE_NAME_MAX_LENGTH",
    "TOPIC_NAME_MAX_LENGTH",
    "is_message_type",
    "normalize_namespace",
    "resolve_topic",
    "ros_type_name",
    "validate_full_topic_name",
    "validate_node_name",
]

#: rmw: RMW_TOPIC_MAX_NAME_LENGTH (255 - 8, room for DDS prefixes and suffixes).
TOPIC_NAME_MAX_LENGTH: Final = 255 - 8
#: rmw: RMW_NAMESPACE_MAX_LENGTH.
NAMESPACE_MAX_LENGTH: Final = TOPIC_NAME_MAX_LENGTH - 2
#: rmw: RMW_NODE_NAME_MAX_NAME_LENGTH.
NODE_NAME_MAX_LENGTH: Final = 255

_NODE_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")
_NAME_CHARS = re.compile(r"[A-Za-z0-9_/]*\Z")
_INPUT_CHARS = re.compile(r"[A-Za-z0-9_/~{}]*\Z")
_SUBSTITUTION = re.compile(r"\{([^{}]*)\}")


def validate_node_name(name: str) -> str:
    """Return ``name`` if it is a valid ROS 2 node name.

    Raises:
        RosNameError: empty, longer than 255, a character outside ``A-Za-z0-9_``, or
            starting with a digit.
    """
    if not name:
        raise RosNameError("node name must not be empty", name=name, kind="node")
    if len(name) > NODE_NAME_MAX_LENGTH:
        raise RosNameError(
            f"node name {name!r} is longer than {NODE_NAME_MAX_LENGTH} characters",
            name=name,
            kind="node",
        )
    if not _NODE_NAME.match(name):
        why = "must not start with a digit" if name[0].isdigit() else "may use only A-Z a-z 0-9 _"
        raise RosNameError(f"node name {name!r} is invalid: it {why}", name=name, kind="node")
    return name


def normalize_namespace(namespace: str) -> str:
    """Return the absolute form of a node namespace (``""`` -> ``"/"``, ``"r1"`` -> ``"/r1"``).

    Raises:
        RosNameError: the namespace breaks a naming rule (see the module docstring).
    """
    given = namespace
    if not namespace or namespace == "/":
        return "/"
    if not namespace.startswith("/"):
        namespace = "/" + namespace
    _check_absolute(namespace, given, kind="namespace", max_length=NAMESPACE_MAX_LENGTH)
    return namespace


def validate_full_topic_name(name: str) -> str:
    """Return ``name`` if it is a valid fully qualified ROS 2 topic name (e.g. ``/a/b``).

    Raises:
        RosNameError: not absolute, or breaks a naming rule.
    """
    if not name.startswith("/"):
        raise RosNameError(
            f"topic name {name!r} is not fully qualified (must start with '/')",
            name=name,
            kind="topic",
        )
    _check_absolute(name, name, kind="topic", max_length=TOPIC_NAME_MAX_LENGTH)
    return name


def resolve_topic(name: str, *, namespace: str = "/", node_name: str) -> str:
    """Expand a topic name as a node ``node_name`` in ``namespace`` would.

    Args:
        name: absolute (``/odom``), relative (``odom``), private (``~/odom``) or with
            substitutions (``{node}``, ``{ns}``, ``{namespace}``).
        namespace: the node's namespace (absolute or relative; ``""`` is the root).
        node_name: the node's name, for ``~`` and ``{node}``.

    Returns:
        The fully qualified name, e.g. ``"/rover1/odom"``.

    Raises:
        RosNameError: the name, namespace or node name breaks a naming rule.
    """
    namespace = normalize_namespace(namespace)
    validate_node_name(node_name)
    if not name:
        raise RosNameError("topic name must not be empty", name=name, kind="topic")
    if not _INPUT_CHARS.match(name):
        bad = sorted({c for c in name if not _INPUT_CHARS.match(c)})
        raise RosNameError(
            f"topic name {name!r} contains characters not allowed in ROS names: {bad}",
            name=name,
            kind="topic",
        )
    if "~" in name[1:] or (name.startswith("~") and name not in ("~",) and name[1] != "/"):
        raise RosNameError(
            f"topic name {name!r}: '~' may only start a name, followed by '/' or nothing",
            name=name,
            kind="topic",
        )
    if name.endswith("/"):
        raise RosNameError(f"topic name {name!r} must not end with '/'", name=name, kind="topic")
    prefix = namespace.rstrip("/")
    expanded = name
    if expanded.startswith("~"):
        expanded = f"{prefix}/{node_name}{expanded[1:]}"
    expanded = _substitute(expanded, given=name, namespace=namespace, node_name=node_name)
    if not expanded.startswith("/"):
        expanded = f"{prefix}/{expanded}"
    try:
        return validate_full_topic_name(expanded)
    except RosNameError as exc:
        if expanded == name:
            raise
        raise RosNameError(
            f"topic name {name!r} expands to an invalid name: {exc}", name=name, kind="topic"
        ) from exc


def _substitute(name: str, *, given: str, namespace: str, node_name: str) -> str:
    values = {"node": node_name, "ns": namespace, "namespace": namespace}

    def replace(match: re.Match[str]) -> str:
        key = match.group(1)
        if key not in values:
            raise RosNameError(
                f"topic name {given!r}: unknown substitution {{{key}}} "
                "(known: {node}, {ns}, {namespace})",
                name=given,
                kind="topic",
            )
        return values[key]

    out = _SUBSTITUTION.sub(replace, name)
    if "{" in out or "}" in out:
        raise RosNameError(f"topic name {given!r} has unbalanced braces", name=given, kind="topic")
    # A substitution may put a namespace's leading '/' after another '/': fold it.
    return re.sub(r"/{2,}", "/", out) if out != name else out


def _check_absolute(name: str, given: str, *, kind: str, max_length: int) -> None:
    if len(name) > max_length:
        raise RosNameError(
            f"{kind} {given!r} is longer than {max_length} characters", name=given, kind=kind
        )
    if not _NAME_CHARS.match(name):
        bad = sorted({c for c in name if not _NAME_CHARS.match(c)})
        raise RosNameError(
            f"{kind} {given!r} contains characters not allowed in ROS names: {bad}",
            name=given,
            kind=kind,
        )
    if name.endswith("/"):
        raise RosNameError(f"{kind} {given!r} must not end with '/'", name=given, kind=kind)
    if "//" in name:
        raise RosNameError(f"{kind} {given!r} contains '//'", name=given, kind=kind)
    for token in name.split("/")[1:]:
        if token[:1].isdigit():
            raise RosNameError(
                f"{kind} {given!r}: the token {token!r} starts with a digit",
                name=given,
                kind=kind,
            )


def is_message_type(obj: object) -> bool:
    """True for a generated ROS 2 message class (what rclpy can publish)."""
    return isinstance(obj, type) and hasattr(obj, "_TYPE_SUPPORT") and hasattr(obj, "SLOT_TYPES")


def ros_type_name(msg_type: type[Any]) -> str:
    """The interface name of a generated message class, e.g. ``"nav_msgs/msg/Odometry"``."""
    package = msg_type.__module__.split(".", 1)[0]
    return f"{package}/msg/{msg_type.__name__}"
