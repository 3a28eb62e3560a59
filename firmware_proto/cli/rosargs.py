"""The ROS 2 part of a command line, for programs that ``ros2 run`` and launch files start.

launch_ros starts every node as ``EXE [arguments...] --ros-args -r __node:=NAME [-r
__ns:=/NS] [--params-file FILE]... [-p name:=value]...``. The programs that are not ROS
nodes themselves (emulator, gate, link relay) take their own long options; these pure
helpers turn the ROS arguments into those options, so that one parameters YAML
configures the whole HIL set (docs/ros2.md). The YAML loader is passed in; the
command-line edge is :mod:`firmware_proto.cli.rosparams`.

Mapping: ``speed_factor: 4.0`` becomes ``--speed-factor 4.0``; ``true`` the bare flag;
``false`` and empty values are left out; a list repeats the option. Options given on the
command line come after, so they win.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

__all__ = [
    "RosArgs",
    "argv_from_ros_args",
    "node_parameters",
    "parameters_to_argv",
    "parse_ros_args",
    "ros_node_parameters",
    "split_ros_args",
]

_FLAGS_WITH_VALUE = {"--log-level", "-e", "--enclave", "--log-config-file", "--log-file-name"}
"""ROS arguments that take a value we ignore (logging, security enclaves)."""


def split_ros_args(argv: Sequence[str]) -> tuple[list[str], list[str]]:
    """Split a command line into the program's own arguments and the ROS arguments.

    Every ``--ros-args`` block runs to the next ``--`` or to the end, as in rcl; blocks
    may repeat. The markers themselves are dropped.
    """
    own: list[str] = []
    ros: list[str] = []
    in_ros = False
    for arg in argv:
        if arg == "--ros-args":
            in_ros = True
        elif in_ros and arg == "--":
            in_ros = False
        elif in_ros:
            ros.append(arg)
        else:
            own.append(arg)
    return own, ros


@dataclass(frozen=True)
class RosArgs:
    """What the ROS arguments say about a node.

    Attributes:
        node_name, namespace: from ``-r __node:=NAME`` and ``-r __ns:=/NS`` (``None``: not set).
        params_files: every ``--params-file``, in order.
        params: every ``-p name:=value``, later ones winning, typed as ROS types them
            (``true``/``false``, integers, floats, else text).
        sources: the parameter sources in command-line order: ``("file", path)`` or
            ``("param", section, name, value)`` (section ``/**``, or the node named).
    """

    node_name: str | None = None
    namespace: str | None = None
    params_files: tuple[str, ...] = ()
    params: dict[str, Any] = field(default_factory=dict)
    sources: tuple[tuple[Any, ...], ...] = ()


def _scalar(text: str) -> Any:
    """A ``-p`` value as ROS types it: YAML booleans, integers, floats, else text."""
    lowered = text.strip().lower()
    if lowered in ("true", "false"):
        return lowered == "true"
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    if len(text) >= 2 and text[0] == text[-1] and text[0] in "'\"":
        return text[1:-1]
    return text


def parse_ros_args(ros_args: Sequence[str]) -> RosArgs:
    """Parse the ROS arguments (without the ``--ros-args`` marker).

    Remaps other than the node name and namespace, and logging and enclave options, are
    accepted and ignored. A ``-p`` or ``-r`` prefixed with another node's name
    (``other:name:=value``) is ignored too.

    Raises:
        ValueError: an option lacks its value, or a ``-p``/``-r`` is not ``name:=value``.
    """
    node_name: str | None = None
    namespace: str | None = None
    files: list[str] = []
    params: dict[str, Any] = {}
    remaps: list[str] = []
    sources: list[tuple[Any, ...]] = []
    it = iter(ros_args)
    for arg in it:
        if arg in ("-p", "--param", "-r", "--remap", "--params-file", *_FLAGS_WITH_VALUE):
            value = next(it, None)
            if value is None:
                raise ValueError(f"ROS argument {arg} needs a value")
            if arg in ("-p", "--param"):
                name, sep, text = value.partition(":=")
                if not sep or not name:
                    raise ValueError(f"ROS parameter must be name:=value, got {value!r}")
                section, colon, own = name.rpartition(":")
                if not colon:
                    params[name] = _scalar(text)
                    sources.append(("param", "/**", name, _scalar(text)))
                elif section and own:
                    sources.append(("param", section, own, _scalar(text)))
            elif arg in ("-r", "--remap"):
                if ":=" not in value:
                    raise ValueError(f"ROS remap must be from:=to, got {value!r}")
                remaps.append(value)
            elif arg == "--params-file":
                files.append(value)
                sources.append(("file", value))
        # anything else (--enable-rosout-logs, ...) takes no value and is ignored
    for remap in remaps:
        source, _, target = remap.partition(":=")
        if source == "__node":
            node_name = target
        elif source == "__ns":
            namespace = target
    return RosArgs(node_name, namespace, tuple(files), params, tuple(sources))


def _flatten(prefix: str, values: Mapping[str, Any], out: dict[str, Any]) -> None:
    for key, value in values.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            _flatten(name + ".", value, out)
        else:
            out[name] = value


def _section_keys(node_name: str, namespace: str) -> set[str]:
    """The section names of a parameters document that apply to one node."""
    ns = "/" + namespace.strip("/") if namespace.strip("/") else ""
    fqn = f"{ns}/{node_name}"
    return {"/**", "**", f"/**/{node_name}", node_name, fqn.lstrip("/"), fqn}


def _check_document(doc: Any) -> Mapping[str, Any]:
    if doc is None:
        return {}
    if not isinstance(doc, Mapping):
        raise ValueError("a parameters file must be a mapping of node names to sections")
    return doc


def _merge_sections(sections: dict[str, dict[str, Any]], doc: Mapping[str, Any]) -> None:
    for key, section in doc.items():
        if isinstance(section, Mapping) and isinstance(section.get("ros__parameters"), Mapping):
            _flatten("", section["ros__parameters"], sections.setdefault(str(key), {}))


def _apply_sections(
    sections: Mapping[str, Mapping[str, Any]], node_name: str, namespace: str
) -> dict[str, Any]:
    keys = _section_keys(node_name, namespace)
    out: dict[str, Any] = {}
    for key, values in sections.items():
        if key in keys:
            out.update(values)
    return out


def node_parameters(doc: Any, node_name: str, namespace: str = "") -> dict[str, Any]:
    """The parameters a ROS 2 parameters document gives one node.

    rcl's order: every section that names the node (``/**``, ``**``, ``/**/NAME``,
    ``NAME``, ``/NS/NAME``) applies in the order the sections first appear, later ones
    winning. Nested mappings under ``ros__parameters`` become dotted names, as ROS does.

    Raises:
        ValueError: the document is not a mapping of sections.
    """
    sections: dict[str, dict[str, Any]] = {}
    _merge_sections(sections, _check_document(doc))
    return _apply_sections(sections, node_name, namespace)


def parameters_to_argv(params: Mapping[str, Any]) -> list[str]:
    """Long options for parameters, ``name_x: v`` -> ``--name-x v`` (module docstring)."""
    argv: list[str] = []
    for name, value in params.items():
        option = "--" + name.replace("_", "-").replace(".", "-")
        values: Iterable[Any] = value if isinstance(value, (list, tuple)) else [value]
        for item in values:
            if item is None or item is False or item == "":
                continue
            if item is True:
                argv.append(option)
            else:
                argv += [option, str(item)]
    return argv


def argv_from_ros_args(
    ros_args: Sequence[str],
    default_node: str,
    load: Callable[[str], Any],
) -> list[str]:
    """The long options that the ROS arguments (:func:`split_ros_args`) stand for;
    ``default_node`` and ``load`` (e.g. ``yaml.safe_load`` of a file's text) as for
    :func:`ros_node_parameters`. ValueError for malformed arguments or parameters files."""
    return parameters_to_argv(ros_node_parameters(parse_ros_args(ros_args), default_node, load))


def ros_node_parameters(
    parsed: RosArgs, default_node: str, load: Callable[[str], Any]
) -> dict[str, Any]:
    """One node's parameters from parsed ROS arguments (:func:`parse_ros_args`), merged as
    rcl merges them; the node is ``default_node`` unless ``__node`` is remapped, and
    ``load`` reads one parameters file into a document (once per file; ValueError when one
    is malformed).

    Each ``--params-file`` and each ``-p`` (section ``/**`` unless the name carries a node)
    updates one table of sections in command-line order; the node's parameters are its
    sections applied in the order they first appeared. So a ``-p`` wins over an earlier
    file's ``/**`` section but not over its ``/**/NAME`` section, as for any ROS 2 node.
    """
    node = parsed.node_name or default_node
    sections: dict[str, dict[str, Any]] = {}
    sources = parsed.sources or (
        *(("file", path) for path in parsed.params_files),
        *(("param", "/**", name, value) for name, value in parsed.params.items()),
    )
    for source in sources:
        if source[0] == "file":
            _merge_sections(sections, _check_document(load(source[1])))
        else:
            _kind, section, name, value = source
            sections.setdefault(section, {})[name] = value
    return _apply_sections(sections, node, parsed.namespace or "")
