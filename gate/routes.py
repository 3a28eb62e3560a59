"""The gate's URL space: one table read by the server (dispatch) and by the OpenAPI
builder (documentation), so that the two cannot drift apart.

A route is a path template (``/maps/{name}``: one segment per ``{param}``, as
Starlette's router reads it), the methods it takes, and the name of the operation.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["ROUTES", "Route"]


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
