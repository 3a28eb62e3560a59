"""The OpenAPI 3.1 document served at ``/openapi.json``, built from what the server does.

Paths and methods come from :data:`gate.routes.ROUTES` (the table the server dispatches
on). The request body is the plan schema itself
(:func:`firmware_proto.model.plan.plan_schema`, the one copy of Listing 1) and ``GET
/maps/{name}`` answers with the map schema (:func:`firmware_proto.model.worldmap.map_schema`),
each hoisted into ``components.schemas`` (:func:`_hoist`). Query parameters and their
ranges come from :mod:`gate.options`, limits and defaults from this server's
configuration. The 401 responses and the bearer scheme appear only with a token.
"""

from __future__ import annotations

from typing import Any

from firmware_proto.model.plan import plan_schema
from firmware_proto.model.verdict import verdict_schemas
from firmware_proto.model.worldmap import map_schema
from gate.config import MAX_TRAJECTORY_SAMPLES, GateConfig
from gate.options import (
    DEFAULT_SAMPLES,
    DEFAULT_SEED,
    DEFAULT_SLIP_SIGMA,
    OPTION_LIMITS,
    QUERY_PARAMETERS,
)
from gate.routes import ROUTES

__all__ = ["OPENAPI_VERSION", "build_openapi"]

OPENAPI_VERSION = "3.1.0"

_NUM: dict[str, Any] = {"type": "number"}
_INT: dict[str, Any] = {"type": "integer"}
_STR: dict[str, Any] = {"type": "string"}
_BOOL: dict[str, Any] = {"type": "boolean"}
_SHA: dict[str, Any] = {"type": "string", "pattern": "^[0-9a-f]{64}$"}
_DECIMAL = r"\s*[+-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?\s*"
"""A number as ``gate.options`` reads one (blanks around it are stripped)."""


def _ref(name: str) -> dict[str, Any]:
    return {"$ref": f"#/components/schemas/{name}"}


def _obj(properties: dict[str, Any], optional: tuple[str, ...] = ()) -> dict[str, Any]:
    return {
        "type": "object",
        "required": [k for k in properties if k not in optional],
        "additionalProperties": False,
        "properties": properties,
    }


def _nullable(schema: dict[str, Any]) -> dict[str, Any]:
    return {"oneOf": [schema, {"type": "null"}]}


def _hoist(schema: dict[str, Any], name: str) -> dict[str, Any]:
    """An embedded JSON schema as component schemas: the schema itself as ``name`` and
    each of its ``$defs`` as ``name + "_" + def``, with every ``#/$defs/...`` reference
    rewritten to point there (references resolve against the OpenAPI document's root).
    ``$schema`` and ``$id`` are dropped: OpenAPI 3.1 schemas are 2020-12 already."""
    prefix = "#/$defs/"

    def rewrite(node: Any) -> Any:
        if isinstance(node, dict):
            out = {k: rewrite(v) for k, v in node.items() if k not in ("$schema", "$id", "$defs")}
            ref = out.get("$ref")
            if isinstance(ref, str) and ref.startswith(prefix):
                out["$ref"] = f"#/components/schemas/{name}_{ref[len(prefix) :]}"
            return out
        if isinstance(node, list):
            return [rewrite(v) for v in node]
        return node

    hoisted = {name: rewrite(schema)}
    for key, sub in schema.get("$defs", {}).items():
        hoisted[f"{name}_{key}"] = rewrite(sub)
    return hoisted


def _verdict_schemas() -> dict[str, Any]:
    """The verdict's schemas, from its dataclasses, with this gate's bound on trajectories."""
    schemas = verdict_schemas()
    trajectory = schemas["Trajectory"]["properties"]
    trajectory["samples"]["description"] += f" At most {MAX_TRAJECTORY_SAMPLES} fixed-rate samples."
    return schemas


def _schemas() -> dict[str, Any]:
    return {
        **_hoist(plan_schema(), "CommandPlan"),
        **_hoist(map_schema(), "Map"),
        **_verdict_schemas(),
        "Violation": _obj({"pointer": _STR, "message": _STR}),
        "Error": _obj(
            {
                "error": _STR,
                "status": _INT,
                "message": _STR,
                "violations": {"type": "array", "items": _ref("Violation")},
                "truncated": {"const": True},
                "parameter": _STR,
                "allow": {"type": "array", "items": _STR},
            },
            optional=("violations", "truncated", "parameter", "allow"),
        ),
        "Health": _obj(
            {
                "status": {"enum": ["ok", "draining"]},
                "version": _STR,
                "default_map": _STR,
                "maps": {"type": "array", "items": _STR},
                "pool": {"enum": ["process", "thread"]},
                "cluster": _nullable(_STR)
                | {"description": "The Dask scheduler that plays samples (--cluster)."},
                "workers": _INT,
                "queue_depth": _INT,
                "in_flight": _INT,
                "admitted_work_s": _NUM
                | {"description": "Estimated worker-seconds of the validations admitted."},
                "clients": _INT | {"description": "Clients with validations admitted."},
                "dt_s": _NUM,
                "max_body_bytes": _INT,
                "uptime_s": _NUM,
            }
        ),
        "MapSummary": _obj(
            {
                "name": _STR,
                "description": _STR,
                "sha256": _SHA,
                "bounds": _obj({"min_x": _NUM, "min_y": _NUM, "max_x": _NUM, "max_y": _NUM}),
                "start": _ref("Pose"),
                "obstacles": _INT,
                "goals": {
                    "type": "array",
                    "items": _obj(
                        {"name": _STR, "x": _NUM, "y": _NUM, "yaw_deg": _NUM, "note": _STR}
                    ),
                },
            }
        ),
        "MapList": _obj({"default": _STR, "maps": {"type": "array", "items": _ref("MapSummary")}}),
    }


def _error(description: str, headers: dict[str, Any] | None = None) -> dict[str, Any]:
    out: dict[str, Any] = {
        "description": description,
        "content": {"application/json": {"schema": _ref("Error")}},
    }
    if headers:
        out["headers"] = headers
    return out


def _parameters(config: GateConfig, maps: list[str], default_map: str) -> list[dict[str, Any]]:
    pb = config.playback
    limits = dict(OPTION_LIMITS)
    limits["sample_hz"] = (limits["sample_hz"][0], min(limits["sample_hz"][1], 1.0 / pb.dt_s))
    docs: dict[str, tuple[str, dict[str, Any]]] = {
        "map": (
            f"Map to play on (default {default_map!r}; see GET /maps).",
            {"type": "string", "enum": maps},
        ),
        "start": (
            "Start pose 'x,y,yaw_deg' (metres, degrees; plain decimal numbers); default "
            "the map's start pose. x and y must lie within the map's bounds (GET /maps), "
            "edges included: a start outside them is a 400 'invalid_option'; one whose "
            "footprint touches a wall is played and answered 'start_in_collision'.",
            {"type": "string", "pattern": f"^{_DECIMAL},{_DECIMAL},{_DECIMAL}$"},
        ),
        "render": (
            "1 or true: add a PNG of the top-down view (image_png_base64).",
            {"type": "string", "enum": ["0", "1", "true", "false"], "default": "0"},
        ),
        "margin_m": (
            "Safety margin: footprint inflation for collision checks, m.",
            {"default": pb.safety_margin_m},
        ),
        "pos_tol_m": (
            "Accepted distance between the final position and the goal, m.",
            {"default": pb.position_tolerance_m},
        ),
        "yaw_tol_deg": (
            "Accepted final yaw error, degrees.",
            {"default": pb.yaw_tolerance_deg},
        ),
        "sample_hz": (
            "Predicted trajectory rate, Hz (the period is rounded to whole twin steps). The "
            f"answer's size is bounded: when the plan's longest possible playback (every "
            f"step to its time limit) would give more than {MAX_TRAJECTORY_SAMPLES} samples "
            "at this rate, the gate samples at the shortest whole number of twin steps that "
            "keeps within that, and says so in trajectory.sample_period_s (replay.sample_hz "
            "stays as asked: the same request gives the same bytes).",
            {"default": pb.sample_hz},
        ),
        "samples": (
            "Twins to play the plan on. 1: the single playback. More: also that many twins "
            "drawn from the twin's parameter uncertainty (a calibrated twin's covariance, "
            "else the default spread) and a slip distribution; the verdict then carries "
            "'uncertainty' (collision probability, goal error percentiles, per-step "
            "envelope). Its judgement stays the nominal twin's.",
            {"type": "integer", "default": DEFAULT_SAMPLES},
        ),
        "seed": (
            "Seed of the twins' draws: the same request and seed give the same verdict.",
            {"type": "integer", "default": DEFAULT_SEED},
        ),
        "slip_sigma": (
            "1-sigma of each side's friction factor (log-normal) in the draws.",
            {"default": DEFAULT_SLIP_SIGMA},
        ),
        "start_sigma_m": (
            "1-sigma error of the start pose's position as measured (per axis, m), e.g. "
            "a rest's own: each twin's start is offset by it. Default: a calibrated "
            "twin's pose_sigma_m (its rests'), else 0.",
            {},
        ),
        "start_sigma_deg": (
            "1-sigma error of the start pose's heading as measured (deg). Default: a "
            "calibrated twin's heading_sigma_deg, else 0.",
            {},
        ),
    }
    out = []
    for name in QUERY_PARAMETERS:
        description, schema = docs[name]
        if name in limits:
            low, high = limits[name]
            schema = {"type": "number", "minimum": low, "maximum": high} | schema
            if schema.get("type") == "integer":
                schema = schema | {"minimum": int(low), "maximum": int(high)}
        out.append(
            {
                "name": name,
                "in": "query",
                "required": False,
                "description": description,
                "schema": schema,
            }
        )
    return out


def build_openapi(config: GateConfig, maps: list[str], default_map: str) -> dict[str, Any]:
    """The OpenAPI document of a gate with ``config`` serving ``maps`` (names), with
    ``default_map`` for requests that name none."""
    secured = config.token is not None
    overloaded = _error(
        "No capacity: every worker and queue slot is taken, the connection limit is "
        "reached, or the server is shutting down. Retry after the given seconds.",
        {"Retry-After": {"schema": {"type": "integer", "minimum": 0}}},
    )
    framing = _error("Malformed request framing (Content-Length / Transfer-Encoding).")
    common: dict[str, Any] = {"400": framing, "503": overloaded}
    if secured:
        common["401"] = _error(
            "Missing or wrong bearer token.",
            {"WWW-Authenticate": {"schema": {"type": "string"}}},
        )

    def ok(schema: dict[str, Any], description: str) -> dict[str, Any]:
        return {"description": description, "content": {"application/json": {"schema": schema}}}

    responses: dict[str, dict[str, Any]] = {
        "health": {"200": ok(_ref("Health"), "The gate is up.")},
        "list_maps": {"200": ok(_ref("MapList"), "Summaries of the served maps.")},
        "get_map": {
            "200": ok(_ref("Map"), "The map document (emulator map schema)."),
            "404": _error("No such map."),
        },
        "openapi": {"200": ok({"type": "object"}, "This document.")},
        "validate_plan": {
            "200": ok(
                _ref("Verdict"),
                "The verdict: approved, or why not, with the predicted trajectory.",
            ),
            "400": _error(
                "Not JSON, or nested deeper than 32 levels (error 'not_json'); the plan "
                "fails the schema ('plan_schema', with the JSON pointer of each violation: "
                "at most 20, and 'truncated' when there are more); "
                "a goal coordinate beyond +/-1e6 m ('goal_out_of_range', violations at "
                "/goal/x, /goal/y); a bad query option ('invalid_option', naming the "
                "parameter; also 'samples' when the request would take more of the workers than "
                "one request may, saying how many this plan may ask for); malformed framing "
                "('bad_framing', e.g. both Content-Length and "
                "Transfer-Encoding); the connection ended inside the body ('truncated_body')."
            ),
            "408": _error(
                f"The body did not arrive whole within {config.body_timeout_s:g} s "
                "('request_timeout'); the connection is closed."
            ),
            "411": _error("A body without Content-Length or chunked Transfer-Encoding."),
            "429": _error(
                "This client already holds its share of the gate: validations admitted, or "
                "their estimated work ('too_many_requests'). Retry after the given seconds.",
                {"Retry-After": {"schema": {"type": "integer", "minimum": 0}}},
            ),
            "413": _error(f"Body over {config.max_body_bytes} bytes."),
            "415": _error("Content-Type is not application/json (UTF-8)."),
        },
    }
    paths: dict[str, Any] = {}
    for route in ROUTES:
        item: dict[str, Any] = {}
        for method in route.methods:
            op: dict[str, Any] = {
                "operationId": route.operation,
                "summary": route.summary,
                "responses": common | responses[route.operation],
            }
            if route.template == "/maps/{name}":
                op["parameters"] = [
                    {"name": "name", "in": "path", "required": True, "schema": {"type": "string"}}
                ]
            if route.operation == "validate_plan":
                op["parameters"] = _parameters(config, maps, default_map)
                op["requestBody"] = {
                    "required": True,
                    "description": (
                        "Exactly a command plan of the thesis's Listing 1 (strict: no other "
                        "properties). Options go in the query string."
                    ),
                    "content": {"application/json": {"schema": _ref("CommandPlan")}},
                }
            item[method.lower()] = dict(sorted(op.items()))
        paths[route.template] = item
    doc: dict[str, Any] = {
        "openapi": OPENAPI_VERSION,
        "info": {
            "title": "Rover simulation gate",
            "version": "1",
            "description": (
                "Plays command plans on the pymunk twin of the rover and answers with a "
                "verdict and the predicted trajectory (docs/gate.md). Every error body is "
                "JSON (schema Error). Beyond the responses listed per operation, any path "
                "may answer 404 (unknown path), 405 with an Allow header (method not "
                "allowed on a known path), 421 (a Host that does not name this server), "
                "501 (unknown method), 400 (malformed request), "
                f"408 (a request's head not whole within {config.head_timeout_s:g} s of its "
                "first byte: the connection is closed), 431 (request head over 16 kB) or "
                "505 (HTTP version). HEAD is answered wherever GET is."
            ),
        },
        "paths": paths,
        "components": {"schemas": _schemas()},
    }
    if secured:
        doc["components"]["securitySchemes"] = {"bearerAuth": {"type": "http", "scheme": "bearer"}}
        doc["security"] = [{"bearerAuth": []}]
    return doc
