"""One JSON codec for frozen model dataclasses: the JSON-ready data of a value, the value
back from parsed JSON, and the JSON Schema (2020-12) of both, all from the class's fields.

A field's type says its JSON: ``float`` a number (an integer is read as one), ``int``,
``bool``, ``str``; ``tuple[X, ...]`` an array; ``X | None`` the value or ``null`` (``None``
when absent too); a nested dataclass or named tuple an object (a ``$ref``). :func:`spec`
in a field's metadata adds:

- ``doc``: the field's meaning, the schema's ``description``;
- ``schema``: further keywords of its schema (``minimum``, ``enum``, ``pattern``...);
- ``inline``: the nested object's fields stand in the outer object, each key may add
  schema keywords;
- ``omit_none``: the key is left out when ``None`` (optional in the schema).

A field with a default may be absent when read. Keys keep the fields' order; reading
ignores unknown keys and raises ``error(message, (pointer,))`` at the first missing or
mistyped field. Encoders are compiled once per class into one dict expression. Pure:
standard library only.
"""

from __future__ import annotations

import dataclasses
import types
import typing
from collections.abc import Callable, Mapping
from typing import Any

__all__ = ["JsonCodec", "spec"]

_SCALARS: dict[type, tuple[str, str]] = {
    bool: ("boolean", "a boolean"),
    int: ("integer", "an integer"),
    float: ("number", "a number"),
    str: ("string", "a string"),
}


def spec(
    doc: str = "",
    *,
    schema: Mapping[str, Any] | None = None,
    inline: bool | Mapping[str, Mapping[str, Any]] = False,
    omit_none: bool = False,
) -> dict[str, Any]:
    """Field metadata for :class:`JsonCodec`: ``field(metadata=spec(...))`` (module docstring)."""
    return {"json": {"doc": doc, "schema": dict(schema or {}), "inline": inline, "omit": omit_none}}


def _meta(f: dataclasses.Field[Any] | None) -> dict[str, Any]:
    if f is None:
        return {"doc": "", "schema": {}, "inline": False, "omit": False}
    meta = f.metadata.get("json")
    return dict(meta) if meta else _meta(None)


def _fields(cls: type) -> list[tuple[str, Any, dict[str, Any], Any]]:
    """(name, resolved type, metadata, default or MISSING) of each field of ``cls``."""
    hints = typing.get_type_hints(cls)
    if dataclasses.is_dataclass(cls):
        return [(f.name, hints[f.name], _meta(f), f.default) for f in dataclasses.fields(cls)]
    defaults = getattr(cls, "_field_defaults", {})
    return [
        (n, hints[n], _meta(None), defaults.get(n, dataclasses.MISSING))
        for n in cls._fields  # type: ignore[attr-defined]
    ]


def _is_model(tp: Any) -> bool:
    return isinstance(tp, type) and (dataclasses.is_dataclass(tp) or hasattr(tp, "_fields"))


def _optional(tp: Any) -> Any | None:
    """``X`` of ``X | None``, else ``None``."""
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if len(args) == 1 and len(typing.get_args(tp)) == 2:
            return args[0]
    return None


def _items(tp: Any) -> Any | None:
    """``X`` of ``tuple[X, ...]``, else ``None``."""
    args = typing.get_args(tp)
    if typing.get_origin(tp) is tuple and len(args) == 2 and args[1] is Ellipsis:
        return args[0]
    return None


class JsonCodec:
    """The codec of one family of model classes: encoders, decoders and schemas, built on
    first use and cached (thread-safe: a race builds the same function twice). Bad input
    raises ``error(message, pointers)``, each message starting with ``what`` (``"verdict"``)."""

    def __init__(self, error: Callable[[str, tuple[str, ...]], Exception], what: str) -> None:
        self._error = error
        self._what = what
        self._encoders: dict[type, Callable[[Any], dict[str, Any]]] = {}
        self._decoders: dict[type, Callable[[Any, str], Any]] = {}

    # -- encoding ---------------------------------------------------------------------

    def encode(self, value: Any) -> dict[str, Any]:
        """``value`` (an instance of a model class) as JSON-ready data."""
        cls = type(value)
        enc = self._encoders.get(cls)
        if enc is None:
            enc = self._encoders[cls] = self._compile(cls)
        return enc(value)

    def _compile(self, cls: type) -> Callable[[Any], dict[str, Any]]:
        names: dict[str, Any] = {}
        counter = iter(range(1_000_000))

        def expr(tp: Any, src: str) -> str:
            if tp in _SCALARS:
                return src
            inner = _optional(tp)
            if inner is not None:
                sub = expr(inner, src)
                return src if sub == src else f"(None if {src} is None else {sub})"
            item = _items(tp)
            if item is not None:
                var = f"v{next(counter)}"
                sub = expr(item, var)
                return f"list({src})" if sub == var else f"[{sub} for {var} in {src}]"
            if _is_model(tp):
                return "{" + ", ".join(f"{k!r}: {v}" for k, v in entries(tp, src)) + "}"
            raise TypeError(f"{cls.__name__}: no JSON form for {tp!r}")

        def entries(tp: type, src: str) -> list[tuple[str, str]]:
            out: list[tuple[str, str]] = []
            for name, ftp, meta, _ in _fields(tp):
                if meta["inline"]:
                    out += entries(ftp, f"{src}.{name}")
                else:
                    out.append((name, expr(ftp, f"{src}.{name}")))
            return out

        # A dict literal up to the first key that may be left out, then one statement a key.
        head: list[tuple[str, str]] = []
        tail: list[str] = []
        for name, ftp, meta, _ in _fields(cls):
            if meta["omit"]:
                sub = expr(_optional(ftp), f"o.{name}")
                tail.append(f"if o.{name} is not None: out[{name!r}] = {sub}")
                continue
            src = f"o.{name}"
            found = entries(ftp, src) if meta["inline"] else [(name, expr(ftp, src))]
            if tail:
                tail += [f"out[{key!r}] = {value}" for key, value in found]
            else:
                head += found
        literal = ", ".join(f"{key!r}: {value}" for key, value in head)
        body = "\n".join(
            ["def encode(o):", f"    out = {{{literal}}}"]
            + [f"    {line}" for line in tail]
            + ["    return out"]
        )
        exec(compile(body, f"<json encoder of {cls.__qualname__}>", "exec"), names)
        encode: Callable[[Any], dict[str, Any]] = names["encode"]
        return encode

    # -- decoding ---------------------------------------------------------------------

    def decode(self, cls: type[Any], obj: Any, pointer: str = "") -> Any:
        """An instance of ``cls`` read from parsed JSON ``obj`` found at ``pointer``; the
        codec's ``error`` when a field is missing or of the wrong type."""
        return self._object_reader(cls)(obj, pointer)

    def _fail(self, message: str, pointer: str) -> Exception:
        return self._error(f"{self._what}: {message}", (pointer,))

    def _object_reader(self, cls: type) -> Callable[[Any, str], Any]:
        reader = self._decoders.get(cls)
        if reader is not None:
            return reader
        plan: list[tuple[str, Callable[[Any, str], Any], bool, Any, bool]] = []
        for name, tp, meta, default in _fields(cls):
            optional = _optional(tp) is not None
            plan.append((name, self._value_reader(tp), optional, default, bool(meta["inline"])))

        def read(obj: Any, pointer: str) -> Any:
            if not isinstance(obj, Mapping):
                raise self._fail(f"{pointer or '/'} is not an object", pointer)
            values = {}
            for name, value_reader, optional, default, inline in plan:
                if inline:
                    values[name] = value_reader(obj, pointer)
                    continue
                where = f"{pointer}/{name}"
                if optional and obj.get(name) is None:
                    values[name] = None
                elif name in obj:
                    values[name] = value_reader(obj[name], where)
                elif default is not dataclasses.MISSING:
                    values[name] = default
                else:
                    raise self._fail(f"missing field {where}", where)
            return cls(**values)

        self._decoders[cls] = read
        return read

    def _value_reader(self, tp: Any) -> Callable[[Any, str], Any]:
        inner = _optional(tp)
        if inner is not None:
            return self._value_reader(inner)
        if tp in _SCALARS:
            return self._scalar_reader(tp)
        item = _items(tp)
        if item is not None:
            return self._array_reader(item)
        if _is_model(tp):
            return self._object_reader(tp)
        raise TypeError(f"no JSON form for {tp!r}")

    def _scalar_reader(self, tp: type) -> Callable[[Any, str], Any]:
        accepted: tuple[type, ...] = (int, float) if tp is float else (tp,)
        noun = _SCALARS[tp][1]

        def read(value: Any, pointer: str) -> Any:
            ok = isinstance(value, accepted) and (tp is bool or not isinstance(value, bool))
            if not ok:
                raise self._fail(f"{pointer} is not {noun}", pointer)
            return float(value) if tp is float else value

        return read

    def _array_reader(self, item: Any) -> Callable[[Any, str], Any]:
        if item in _SCALARS:
            scalar = self._scalar_reader(item)
            noun = f"a list of {_SCALARS[item][1].split()[-1]}s"

            def read_scalars(value: Any, pointer: str) -> Any:
                if not isinstance(value, list):
                    raise self._fail(f"{pointer} is not {noun}", pointer)
                try:
                    return tuple(scalar(v, pointer) for v in value)
                except Exception:
                    raise self._fail(f"{pointer} is not {noun}", pointer) from None

            return read_scalars
        element = self._value_reader(item)

        def read_items(value: Any, pointer: str) -> Any:
            if not isinstance(value, list):
                raise self._fail(f"{pointer} is not a list", pointer)
            return tuple(element(v, f"{pointer}/{i}") for i, v in enumerate(value))

        return read_items

    # -- schemas ----------------------------------------------------------------------

    def schemas(self, *roots: type, ref: str = "#/components/schemas/") -> dict[str, Any]:
        """The JSON Schema of each class reachable from ``roots``, by class name; nested
        classes are referenced as ``ref + name``. Objects are closed
        (``additionalProperties: false``) and require every key but the ``omit_none``
        ones."""
        out: dict[str, Any] = {}

        def value(tp: Any, meta: Mapping[str, Any]) -> dict[str, Any]:
            inner = _optional(tp)
            if inner is not None and not meta["omit"]:
                return {"oneOf": [value(inner, _meta(None)), {"type": "null"}]}
            if inner is not None:
                tp = inner
            if tp in _SCALARS:
                return {"type": _SCALARS[tp][0]}
            item = _items(tp)
            if item is not None:
                return {"type": "array", "items": value(item, _meta(None))}
            if _is_model(tp):
                visit(tp)
                return {"$ref": ref + tp.__name__}
            raise TypeError(f"no JSON form for {tp!r}")

        def properties(cls: type) -> tuple[dict[str, Any], list[str]]:
            props: dict[str, Any] = {}
            required: list[str] = []
            for name, tp, meta, _ in _fields(cls):
                if meta["inline"]:
                    extra = meta["inline"] if isinstance(meta["inline"], Mapping) else {}
                    sub, sub_required = properties(tp)
                    props |= {k: v | dict(extra.get(k, {})) for k, v in sub.items()}
                    required += sub_required
                    continue
                schema = value(tp, meta)
                if _optional(tp) is not None and not meta["omit"] and meta["schema"]:
                    schema["oneOf"][0] |= meta["schema"]
                else:
                    schema |= meta["schema"]
                if meta["doc"]:
                    schema["description"] = meta["doc"]
                props[name] = schema
                if not meta["omit"]:
                    required.append(name)
            return props, required

        def visit(cls: type) -> None:
            if cls.__name__ in out:
                return
            out[cls.__name__] = {}
            props, required = properties(cls)
            out[cls.__name__] = {
                "type": "object",
                "required": required,
                "additionalProperties": False,
                "properties": props,
            }

        for root in roots:
            visit(root)
        return out
