"""HTTP client of the simulation gate (the thesis's ``HttpPlanValidator``).

:class:`GateClient` posts plans to ``POST /validate_plan`` and reads the verdict into
:class:`~firmware_proto.model.verdict.Verdict`; it also reads ``/health``, ``/maps`` and
one map. Standard library only (``http.client``), one keep-alive connection, thread-safe
(calls are serialised on it).

Each call has one time budget, ``timeout_s``, for connecting, waiting, retrying and
``Retry-After``. Connection errors are retried with doubling backoff (a keep-alive
closed while idle is reopened, uncounted: validation is pure); 503 and 429 wait
``Retry-After``; other error statuses raise at once. The table: docs/planner.md "The gate
client". Settings: :func:`resolve_gate_settings`.
"""

from __future__ import annotations

import http.client
import json
import logging
import os
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any
from urllib.parse import quote, urlsplit

from firmware_proto.errors import MapError, VerdictError
from firmware_proto.model.plan import Plan
from firmware_proto.model.pose import Pose
from firmware_proto.model.verdict import Verdict
from firmware_proto.model.worldmap import WorldMap
from planner.errors import (
    GateOverloadedError,
    GateProtocolError,
    GateStatusError,
    GateTimeoutError,
    GateUnavailableError,
)

__all__ = [
    "DEFAULT_GATE_URL",
    "ENV_TOKEN",
    "ENV_URL",
    "GateClient",
    "GateOptions",
    "resolve_gate_settings",
]

logger = logging.getLogger(__name__)

DEFAULT_GATE_URL = "http://127.0.0.1:8080"
"""Where ``rover gate`` listens by default."""
ENV_URL = "ROVER_GATE_URL"
ENV_TOKEN = "ROVER_GATE_TOKEN"

DEFAULT_TIMEOUT_S = 30.0
"""Budget of one call, s: the slowest valid plan's validation on a busy host, and 503 rounds."""
DEFAULT_RETRIES = 3
DEFAULT_BACKOFF_S = 0.1
DEFAULT_MAX_BACKOFF_S = 2.0
DEFAULT_RETRY_AFTER_S = 1.0
"""Wait after a 503 without a usable ``Retry-After``."""


def resolve_gate_settings(
    url: str | None = None,
    token: str | None = None,
    environ: Mapping[str, str] | None = None,
) -> tuple[str, str | None]:
    """The gate URL and bearer token: arguments, then ``ROVER_GATE_URL`` /
    ``ROVER_GATE_TOKEN``, then :data:`DEFAULT_GATE_URL` and no token (empty: not given)."""
    env = os.environ if environ is None else environ
    final_url = url or env.get(ENV_URL) or DEFAULT_GATE_URL
    final_token = token or env.get(ENV_TOKEN) or None
    return final_url, final_token


@dataclass(frozen=True)
class GateOptions:
    """Per-request overrides of the gate's playback defaults (``None``: the gate's).

    Attributes:
        margin_m: footprint inflation for collisions, m.
        pos_tol_m: accepted final distance to the goal, m.
        yaw_tol_deg: accepted final yaw error, degrees.
        sample_hz: predicted trajectory rate, Hz.
        render: ask for a PNG of the top-down view (``Verdict.image_png_base64``).
        samples: also play this many twins drawn from the gate's uncertainty (> 1: the
            verdict carries ``uncertainty``); ``seed`` seeds their draws.
        start_sigma_m, start_sigma_deg: the start pose's own 1-sigma error as measured
            (per position axis, m; heading, deg), which the twins' starts are drawn
            with (``None``: the gate's twin's, a calibration's rests').
    """

    margin_m: float | None = None
    pos_tol_m: float | None = None
    yaw_tol_deg: float | None = None
    sample_hz: float | None = None
    render: bool = False
    samples: int | None = None
    seed: int | None = None
    start_sigma_m: float | None = None
    start_sigma_deg: float | None = None

    def query_items(self) -> list[tuple[str, str]]:
        """The query parameters these options set."""
        items: list[tuple[str, str]] = []
        for name, value in (
            ("margin_m", self.margin_m),
            ("pos_tol_m", self.pos_tol_m),
            ("yaw_tol_deg", self.yaw_tol_deg),
            ("sample_hz", self.sample_hz),
        ):
            if value is not None:
                items.append((name, repr(float(value))))
        if self.render:
            items.append(("render", "1"))
        for name, count in (("samples", self.samples), ("seed", self.seed)):
            if count is not None:
                items.append((name, str(int(count))))
        for name, value in (
            ("start_sigma_m", self.start_sigma_m),
            ("start_sigma_deg", self.start_sigma_deg),
        ):
            if value is not None:
                items.append((name, repr(float(value))))
        return items


def _retry_after_s(value: str | None) -> float:
    if value is None:
        return DEFAULT_RETRY_AFTER_S
    try:
        seconds = float(value.strip())
    except ValueError:
        return DEFAULT_RETRY_AFTER_S  # an HTTP date: not worth parsing for a local gate
    return seconds if seconds >= 0 else DEFAULT_RETRY_AFTER_S


def _describe(exc: BaseException) -> str:
    text = str(exc) or type(exc).__name__
    return f"{type(exc).__name__}: {text}" if type(exc).__name__ not in text else text


class _StaleConnectionError(Exception):
    """A reused keep-alive connection was closed by the gate before answering."""


class GateClient:
    """A client of one gate; a context manager (:meth:`close` is idempotent).

    Args:
        url: the gate's base URL, ``http://host:port``; see :func:`resolve_gate_settings`.
        token: bearer token sent with every request.
        timeout_s: time budget of each call, s.
        retries: retries after a connection error (so ``retries + 1`` attempts).
        backoff_s, max_backoff_s: first retry delay and its cap, s (doubling).
        environ: environment for the settings (default ``os.environ``).
        sleep, clock: waits between retries and the time budget's clock, s.

    Raises:
        ValueError: the URL is not ``http://host[:port][/path]``, or a number is out of
            range.
    """

    def __init__(
        self,
        url: str | None = None,
        *,
        token: str | None = None,
        timeout_s: float = DEFAULT_TIMEOUT_S,
        retries: int = DEFAULT_RETRIES,
        backoff_s: float = DEFAULT_BACKOFF_S,
        max_backoff_s: float = DEFAULT_MAX_BACKOFF_S,
        environ: Mapping[str, str] | None = None,
        sleep: Callable[[float], None] = time.sleep,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        base, self._token = resolve_gate_settings(url, token, environ)
        parts = urlsplit(base)
        if parts.scheme != "http" or not parts.hostname:
            raise ValueError(f"gate URL must be http://host[:port], got {base!r}")
        if parts.query or parts.fragment:
            raise ValueError(f"gate URL must not carry a query or fragment: {base!r}")
        if not timeout_s > 0 or retries < 0 or backoff_s < 0 or max_backoff_s < 0:
            raise ValueError("timeout_s must be > 0; retries and backoffs must be >= 0")
        self._host = parts.hostname
        self._port = parts.port or 80
        self._prefix = parts.path.rstrip("/")
        self.url = base.rstrip("/")
        self.timeout_s = timeout_s
        self.retries = retries
        self.backoff_s = backoff_s
        self.max_backoff_s = max_backoff_s
        self._sleep = sleep
        self._clock = clock
        self._conn: http.client.HTTPConnection | None = None
        self._conn_used = False
        self._lock = threading.Lock()
        self._closed = False
        self.requests = 0
        """Requests answered so far (any status)."""

    # -- life cycle ---------------------------------------------------------------------
    def close(self) -> None:
        """Close the connection. Idempotent; the client cannot be used afterwards."""
        with self._lock:
            self._closed = True
            self._drop()

    def __enter__(self) -> GateClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"GateClient({self.url!r})"

    # -- API ----------------------------------------------------------------------------
    def validate(
        self,
        plan: Plan | Mapping[str, Any],
        *,
        map_name: str | None = None,
        start: Pose | None = None,
        options: GateOptions | None = None,
    ) -> Verdict:
        """Validate a plan on the twin.

        Args:
            plan: a plan, or plan JSON data sent as is (the gate checks it).
            map_name: the map; ``None`` for the gate's default.
            start: the start pose; ``None`` for the map's.
            options: overrides of the gate's tolerances and margin.

        Raises:
            GateStatusError: the gate refused the request (a plan failing the schema, an
                unknown map, a start outside it, 401...).
            GateOverloadedError: 503 or 429 past the time budget.
            GateUnavailableError: no answer after the retries (GateTimeoutError: none
                within the budget).
            GateProtocolError: the answer is not a verdict.
        """
        if isinstance(plan, Plan):
            body = plan.to_json().encode()
        else:
            body = json.dumps(plan, separators=(",", ":")).encode()
        query: list[tuple[str, str]] = []
        if map_name is not None:
            query.append(("map", map_name))
        if start is not None:
            if not start.is_finite():
                raise ValueError(f"start pose must be finite, got {start}")
            query.append(
                ("start", ",".join(repr(float(v)) for v in (start.x, start.y, start.yaw_deg)))
            )
        query += (options or GateOptions()).query_items()
        path = "/validate_plan"
        if query:
            path += "?" + "&".join(f"{k}={quote(v, safe=',')}" for k, v in query)
        data = self._call("POST", path, body)
        try:
            verdict = Verdict.from_dict(self._json(data))
        except VerdictError as exc:
            raise GateProtocolError(str(exc), exc.pointers) from exc
        logger.debug("verdict for %s: %s", path, verdict.summary())
        return verdict

    def health(self) -> dict[str, Any]:
        """``GET /health``: status, version, default map, maps, load."""
        obj = self._json(self._call("GET", "/health", None))
        if not isinstance(obj, dict):
            raise GateProtocolError("/health: not a JSON object")
        return obj

    def list_maps(self) -> tuple[str, list[dict[str, Any]]]:
        """``GET /maps``: the default map's name and one summary per map."""
        obj = self._json(self._call("GET", "/maps", None))
        if not isinstance(obj, dict) or not isinstance(obj.get("maps"), list):
            raise GateProtocolError("/maps: not the documented map list", ["/maps"])
        return str(obj.get("default", "")), list(obj["maps"])

    def get_map(self, name: str | None = None) -> WorldMap:
        """``GET /maps/{name}`` as a :class:`WorldMap`; ``None`` for the default map.

        Raises:
            GateStatusError: 404 for an unknown map.
            GateProtocolError: the document is not a valid map (``pointers`` says
                where).
        """
        if name is None:
            name = self.list_maps()[0]
        obj = self._json(self._call("GET", "/maps/" + quote(name, safe=""), None))
        try:
            return WorldMap.from_dict(obj, f"/maps/{name}")
        except MapError as exc:
            raise GateProtocolError(str(exc), [ptr for ptr, _ in exc.violations]) from exc

    # -- transport ----------------------------------------------------------------------
    def _json(self, data: bytes) -> Any:
        try:
            return json.loads(data)
        except ValueError as exc:
            raise GateProtocolError(
                f"the gate at {self.url} answered with non-JSON: {exc}"
            ) from exc

    def _call(self, method: str, path: str, body: bytes | None) -> bytes:
        with self._lock:
            if self._closed:
                raise RuntimeError("GateClient is closed")
            return self._call_locked(method, path, body)

    def _call_locked(self, method: str, path: str, body: bytes | None) -> bytes:
        deadline = self._clock() + self.timeout_s
        failures = 0
        reopened = False
        while True:
            remaining = deadline - self._clock()
            if remaining <= 0:
                raise GateTimeoutError(self.url, failures + 1, self.timeout_s)
            try:
                status, headers, data = self._exchange(method, path, body, remaining)
            except _StaleConnectionError:
                if reopened:
                    failures += 1
                    if self._give_up(failures, deadline):
                        raise GateUnavailableError(
                            self.url, failures, "connection closed before an answer"
                        ) from None
                reopened = True
                logger.debug("keep-alive connection to %s was closed; reopening", self.url)
                continue
            except TimeoutError as exc:
                self._drop()
                raise GateTimeoutError(self.url, failures + 1, self.timeout_s) from exc
            except (OSError, http.client.HTTPException) as exc:
                self._drop()
                failures += 1
                if self._give_up(failures, deadline):
                    raise GateUnavailableError(self.url, failures, _describe(exc)) from exc
                continue
            self.requests += 1
            if status in (429, 503):  # this client's share taken, or the gate full
                wait_s = _retry_after_s(headers.get("retry-after"))
                text = data.decode("utf-8", "replace")
                if self._clock() + wait_s >= deadline:
                    raise GateOverloadedError(
                        status, text, url=self.url + path, retry_after_s=wait_s
                    )
                logger.info("gate busy (%d); retrying in %.1f s", status, wait_s)
                self._sleep(wait_s)
                continue
            if status >= 400:
                raise GateStatusError(status, data.decode("utf-8", "replace"), url=self.url + path)
            if not 200 <= status < 300:
                raise GateProtocolError(f"the gate at {self.url} answered {status} to {path}")
            return data

    def _give_up(self, failures: int, deadline: float) -> bool:
        """After a connection error: whether to stop; else wait the backoff."""
        if failures > self.retries:
            return True
        delay = min(self.max_backoff_s, self.backoff_s * 2 ** (failures - 1))
        if self._clock() + delay >= deadline:
            return True
        logger.debug(
            "gate %s unreachable (attempt %d); retrying in %.2f s", self.url, failures, delay
        )
        self._sleep(delay)
        return False

    def _exchange(
        self, method: str, path: str, body: bytes | None, timeout_s: float
    ) -> tuple[int, dict[str, str], bytes]:
        reused = self._conn is not None and self._conn_used
        if self._conn is None:
            self._conn = http.client.HTTPConnection(self._host, self._port, timeout=timeout_s)
            self._conn_used = False
        conn = self._conn
        if conn.sock is not None:
            conn.sock.settimeout(timeout_s)
        else:
            conn.timeout = timeout_s
        headers = {"Accept": "application/json"}
        if body is not None:
            headers["Content-Type"] = "application/json"
        if self._token:
            headers["Authorization"] = f"Bearer {self._token}"
        try:
            conn.request(method, self._prefix + path, body=body, headers=headers)
            response = conn.getresponse()
            data = response.read()
        except (ConnectionResetError, BrokenPipeError, http.client.RemoteDisconnected):
            if reused:
                self._drop()
                raise _StaleConnectionError() from None
            raise
        self._conn_used = True
        if response.will_close:
            self._drop()
        return response.status, {k.lower(): v for k, v in response.getheaders()}, data

    def _drop(self) -> None:
        if self._conn is not None:
            self._conn.close()
            self._conn = None
            self._conn_used = False
