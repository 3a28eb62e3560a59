"""The gate's URL space: one table read by the server (dispatch) and by the OpenAPI
builder (documentation), so that the two cannot drift apart.

A route is a path template (``/maps/{name}``: one segment per ``{param}``), the methods
it takes, and the name of the operation. :func:`match` finds the route of a path or
says which methods it would take.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from urllib.parse import unquote

__all__ = ["ROUTES", "Route", "match"]


@dataclass(frozen=True)
class Route:
    """One path template and its operations.

    Attributes:
        template: OpenAPI-style path, ``{name}`` matching one non-empty segment.
        methods: the methods it takes, upper case (``HEAD`` is implied by ``GET``).
        operation: operation id, also the server's handler name (``_op_<operation>``).
        summary: one line for the OpenAPI document.
    """

    template: str
    methods: tuple[str, ...]
    operation: str
    summary: str

    @property
    def pattern(self) -> re.Pattern[str]:
        """The template as an anchored regular expression."""
        parts = re.split(r"(\{[a-z_]+\})", self.template)
        regex = "".join(
            f"(?P<{p[1:-1]}>[^/]+)" if p.startswith("{") else re.escape(p) for p in parts
        )
        return re.compile(f"^{regex}$")

    @property
    def allowed(self) -> tuple[str, ...]:
        """Methods answered on this path, sorted (``GET`` brings ``HEAD``)."""
        extra = ("HEAD",) if "GET" in self.methods else ()
        return tuple(sorted(set(self.methods) | set(extra)))


ROUTES: tuple[Route, ...] = (
    Route("/health", ("GET",), "health", "Liveness, version, load and the served maps"),
    Route("/maps", ("GET",), "list_maps", "The maps this gate validates on"),
    Route("/maps/{name}", ("GET",), "get_map", "One map, as its JSON document"),
    Route("/openapi.json", ("GET",), "openapi", "This OpenAPI document"),
    Route("/validate_plan", ("POST",), "validate_plan", "Play a plan on the twin; a verdict"),
)
"""Every route the gate serves."""

_COMPILED = tuple((route, route.pattern) for route in ROUTES)


def match(path: str) -> tuple[Route, dict[str, str]] | None:
    """The route of ``path`` (no query string) and its decoded parameters, or ``None``."""
    for route, pattern in _COMPILED:
        m = pattern.match(path)
        if m is not None:
            return route, {k: unquote(v, errors="strict") for k, v in m.groupdict().items()}
    return None
