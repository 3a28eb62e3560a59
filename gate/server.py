"""The HTTP gate: ``POST /validate_plan`` and friends, served by uvicorn.

:class:`GateServer` is a Starlette application on the project's one HTTP stack
(:mod:`firmware_proto.http`: uvicorn with h11, one event loop in a thread of its own,
every connection bounded by deadlines) and application layer
(:mod:`firmware_proto.http.app`: the routes of :data:`gate.routes.ROUTES`, the shared
guard, errors worded as the gate's JSON), in front of a :mod:`worker pool <gate.pool>`.
What it promises, in full in docs/gate.md ("Capacity, keep-alive and shutdown", "Errors",
"Binding and the token"):

- admission by cost before anything is queued (:mod:`gate.admission`: 400, 429 or 503
  with ``Retry-After``); ``GET`` requests need no worker;
- a validation past ``request_timeout_s``, or whose client left, is cancelled in the
  pool and its admission released;
- validity is decided by the compiled check on the event loop; a refusal is worded on a
  thread of its own, at most :data:`MAX_VIOLATIONS`, within :data:`ERROR_ROOM_BYTES` of
  the body's size;
- connections are bounded by ``idle_timeout_s``, ``head_timeout_s``, ``body_timeout_s``
  (408) and ``max_connections`` (503); bodies by ``max_body_bytes`` (413, before any of
  it is read) and framing (411); every error body is JSON;
- with a token, every request needs ``Authorization: Bearer`` (compared in constant time;
  401); ``Host`` must name the gate (421; :mod:`firmware_proto.http.bindpolicy`);
- :meth:`GateServer.close` drains: 503 to new requests, requests under way finished
  (up to ``drain_timeout_s``).

The event loop does I/O and parsing only; playback runs in the pool. Each operation is
one ``_op_<name>`` coroutine named by :data:`gate.routes.ROUTES`.
"""

from __future__ import annotations

import asyncio
import functools
import logging
import socket
import threading
import time
from collections import Counter
from collections.abc import Awaitable, Callable
from concurrent.futures import Future, ThreadPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import replace
from typing import Any
from urllib.parse import unquote

from starlette.requests import Request
from starlette.responses import Response
from starlette.routing import Route
from starlette.types import Scope

from firmware_proto.http import (
    ClientGoneError,
    HttpService,
    RequestBodyError,
    ServeLimits,
    read_body,
)
from firmware_proto.http.app import API_HEADERS, AccessPolicy, build_app
from firmware_proto.http.bindpolicy import HostPolicy, is_wildcard
from firmware_proto.http.connection import CONNECTION_EXTENSION, ConnectionMark
from firmware_proto.http.errors import StatusError
from firmware_proto.http.limits import DEFAULT_MAX_DRAIN_BYTES
from firmware_proto.model.plan import Plan, plan_is_valid, validate_plan
from firmware_proto.model.verdict import Verdict
from gate import routes
from gate.admission import Admission, Cost, Limits, Ticket
from gate.config import GateConfig
from gate.ensemble import STEP_ERROR_DT_S, ChunkJob, chunk_sizes, run_chunk
from gate.errors import (
    BadRequestError,
    CallCancelledError,
    HttpError,
    NotFoundError,
    OptionError,
    OverloadedError,
    PayloadTooLargeError,
    PlanSchemaError,
    RequestTimeoutError,
)
from gate.openapi import build_openapi
from gate.options import ValidateOptions
from gate.pool import WorkerPool, make_pool
from gate.request import check_declared_length, check_json_media_type, parse_json
from gate.response import (
    JSON_CONTENT_TYPE,
    SERVER_NAME,
    error_json,
    json_bytes,
    render_connection_error,
)
from gate.validator import Job, Validator, gate_version

__all__ = ["ERROR_ROOM_BYTES", "MAX_VIOLATIONS", "GateServer"]

logger = logging.getLogger(__name__)

RETRY_AFTER_S = 1
"""``Retry-After`` of a 503 that does not estimate it: a validation is well under a second."""
MAX_VIOLATIONS = 20
"""Violations of a refused plan worded at most (the wording stops there)."""
MAX_VIOLATION_CHARS = 200
"""Longest pointer or message of a violation in an answer, chars (a message may quote the value)."""
ERROR_ROOM_BYTES = 2048
"""An error answer is at most this much larger than the request's body."""

_Reply = tuple[int, bytes, dict[str, str]]


class GateServer:
    """The simulation gate's HTTP server (see the module docstring); a context manager,
    or call :meth:`start` and :meth:`close`.

    Args:
        validator: default: loaded from ``config``.
        pool: default: made from ``config``; the server closes it.
    """

    def __init__(
        self,
        config: GateConfig,
        *,
        validator: Validator | None = None,
        pool: WorkerPool | None = None,
    ) -> None:
        self.config = config
        self.validator = validator if validator is not None else Validator.from_config(config)
        self._pool = pool
        self._cluster: Any = None  # gate.cluster.ClusterEngine, with --cluster
        self._service: HttpService | None = None
        self._wording: ThreadPoolExecutor | None = None
        self._draining = threading.Event()
        self.stopped_accepting = threading.Event()
        """Set once :meth:`close` has closed the listener (new connections refused)."""
        self._closed = False
        self._close_lock = threading.Lock()
        self.admission = Admission(
            Limits.for_gate(
                pool.workers if pool is not None else config.workers,
                config.queue_depth,
                config.request_timeout_s,
            )
        )
        """What is admitted now (:mod:`gate.admission`)."""
        self._count_lock = threading.Lock()
        self.rejected: Counter[str] = Counter()
        """Requests answered with an error, by code (the connection layer logs its own)."""
        self.cancelled = 0
        """Validations cancelled: past their deadline, or their client left."""
        self._started = time.monotonic()
        names = sorted(self.validator.maps)
        self._map_bodies = {n: json_bytes(self.validator.maps[n].to_dict()) for n in names}
        self._maps_body = json_bytes(self._map_list())
        self._openapi_body = json_bytes(build_openapi(config, names, self.validator.default_map))
        extra = list(config.allowed_hosts)
        if is_wildcard(config.host):
            extra.append(socket.gethostname())
        self.app = build_app(
            [  # validate_plan first: the router tries the routes in order
                Route(r.template, self._endpoint(r.operation), methods=list(r.methods))
                for r in sorted(routes.ROUTES, key=lambda r: r.operation != "validate_plan")
            ],
            policy=AccessPolicy(
                hosts=HostPolicy.for_bind(config.host, extra),
                token=config.token,
                token_required=config.token is not None,
                realm="rover-gate",
            ),
            error_body=_error_body,
            on_error=self._on_error,
            headers=API_HEADERS,
            closing=self._draining.is_set,
        )

    # -- life cycle ---------------------------------------------------------------------
    def start(self) -> GateServer:
        """Start the workers, bind, and serve in a background thread.

        Raises:
            OSError: the address cannot be bound.
            RuntimeError: already started, or the worker processes did not start.
        """
        if self._service is not None:
            raise RuntimeError("gate server already started")
        if self._pool is None:
            self._pool = make_pool(self.config, self.validator)
        if self.config.cluster and self._cluster is None:
            from gate.cluster import ClusterEngine  # noqa: PLC0415 - Dask only when asked

            try:
                self._cluster = ClusterEngine(self.config.cluster)
            except BaseException:
                self._pool.close()
                raise
        config = self.config
        limits = ServeLimits(
            idle_timeout_s=config.idle_timeout_s,
            head_timeout_s=config.head_timeout_s,
            body_timeout_s=config.body_timeout_s,
            write_timeout_s=config.idle_timeout_s,
            max_connections=config.max_connections,
            max_connections_per_address=config.max_connections_per_address,
            reserved_connections=config.reserved_connections,
            drain_timeout_s=config.drain_timeout_s,
        )
        # The wording of refused plans: off the event loop, one at a time. It starts
        # now, not with the first bad plan.
        self._wording = ThreadPoolExecutor(1, thread_name_prefix="gate-wording")
        self._wording.submit(int).result()
        service = HttpService(
            self.app,
            host=config.host,
            port=config.port,
            limits=limits,
            render_error=render_connection_error,
            server_name=SERVER_NAME,
            thread_name="gate-serve",
        )
        try:
            self._service = service.start()
        except BaseException:
            self._wording.shutdown(wait=False)
            self._pool.close()
            raise
        logger.info(
            "gate listening on %s (%s pool, %d workers, queue %d)",
            self.url,
            self._pool.kind,
            self._pool.workers,
            self.config.queue_depth,
        )
        return self

    @property
    def address(self) -> tuple[str, int]:
        """``(host, port)`` actually bound (the port is real even when 0 was asked)."""
        if self._service is None:
            raise RuntimeError("gate server not started")
        return self._service.address

    @property
    def url(self) -> str:
        """``http://host:port`` of the listener."""
        if self._service is None:
            raise RuntimeError("gate server not started")
        return self._service.url

    @property
    def draining(self) -> bool:
        """Whether shutdown has begun (new requests get 503)."""
        return self._draining.is_set()

    @property
    def pool(self) -> WorkerPool:
        """The worker pool (after :meth:`start`)."""
        if self._pool is None:
            raise RuntimeError("gate server not started")
        return self._pool

    def begin_drain(self) -> None:
        """Answer every new request with 503 from now on (the first half of
        :meth:`close`, exposed so that tests and supervisors can drain first)."""
        if not self._draining.is_set():
            logger.info("gate draining")
        self._draining.set()

    def close(self) -> None:
        """Graceful shutdown; idempotent. Stop accepting, close idle connections, wait
        for requests under way (at most ``drain_timeout_s``), stop the workers."""
        with self._close_lock:
            if self._closed:
                return
            self._closed = True
        self.begin_drain()
        if self._service is not None:
            self._service.stop_accepting()
            self.stopped_accepting.set()
            self._service.close()
        if self._wording is not None:
            self._wording.shutdown(wait=True)
        if self._cluster is not None:
            self._cluster.close()
        if self._pool is not None:
            self._pool.close(wait=True)
        logger.info("gate closed")

    def __enter__(self) -> GateServer:
        if self._service is None:
            self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- the application ----------------------------------------------------------------
    def _endpoint(self, name: str) -> Callable[[Request], Awaitable[Response]]:
        """The route's endpoint: refuses while draining, runs ``_op_<name>``."""
        operation: Callable[[Request, dict[str, Any]], Awaitable[_Reply]] = getattr(
            self, "_op_" + name
        )

        async def endpoint(request: Request) -> Response:
            if self.draining:
                raise OverloadedError(
                    "the gate is shutting down", code="shutting_down", retry_after_s=RETRY_AFTER_S
                )
            status, body, headers = await operation(request, dict(request.path_params))
            return Response(body, status, headers, media_type=JSON_CONTENT_TYPE)

        return endpoint

    def _on_error(self, scope: Scope, error: StatusError) -> None:
        with self._count_lock:
            self.rejected[error.code] += 1
        log = logger.warning if error.status >= 500 and error.status != 503 else logger.info
        log(
            "%s %s: %d %s: %s",
            scope.get("method"),
            scope.get("path"),
            error.status,
            error.code,
            error.message,
        )

    # -- operations ------------------------------------------------------------------------
    async def _op_health(self, request: Request, params: dict[str, str]) -> _Reply:
        return 200, json_bytes(self.health()), {}

    async def _op_list_maps(self, request: Request, params: dict[str, str]) -> _Reply:
        return 200, self._maps_body, {}

    async def _op_get_map(self, request: Request, params: dict[str, str]) -> _Reply:
        raw = bytes(request.scope["raw_path"]).decode("latin-1").rsplit("/", 1)[-1]
        try:
            unquote(raw, errors="strict")
        except UnicodeDecodeError:
            raise NotFoundError(f"no such path {request.url.path!r}") from None
        body = self._map_bodies.get(params["name"])
        if body is None:
            known = ", ".join(sorted(self._map_bodies))
            raise NotFoundError(f"no map {params['name']!r}; known: {known}", code="unknown_map")
        return 200, body, {}

    async def _op_openapi(self, request: Request, params: dict[str, str]) -> _Reply:
        return 200, self._openapi_body, {}

    async def _op_validate_plan(self, request: Request, params: dict[str, str]) -> _Reply:
        body = await self._read_body(request)
        document = parse_json(body)
        if not plan_is_valid(document):  # decided by the compiled check, on the loop
            raise await self._schema_error(document, len(body))
        plan = Plan.from_dict(document, checked=True)
        query = bytes(request.scope["query_string"]).decode("latin-1")
        try:
            options = ValidateOptions.from_query(query)
            job = self.validator.prepare(
                plan, options.resolve(self.validator.settings, self.validator.default_map)
            )
            cost = self._cost(job)
            self.admission.check_request(cost, self.validator.settings.dt_s)
        except OptionError as exc:
            raise BadRequestError(str(exc), code="invalid_option", parameter=exc.parameter) from exc
        peer = request.scope.get("client")
        client = peer[0] if peer else ""
        ticket = self.admission.admit(client, cost)
        return 200, await self._validate(job, ticket, request), {}

    async def _read_body(self, request: Request) -> bytes:
        """The request's body (media type, length, deadline checked)."""
        check_json_media_type(request.headers.get("content-type"))
        limit = self.config.max_body_bytes
        try:
            check_declared_length(request.headers, limit)
        except PayloadTooLargeError as exc:
            length = request.headers.get("content-length")
            if length is None or int(length) > DEFAULT_MAX_DRAIN_BYTES:
                exc.headers["Connection"] = "close"  # not worth reading and dropping
            raise
        try:
            return await read_body(
                request.receive, limit_bytes=limit, timeout_s=self.config.body_timeout_s
            )
        except RequestBodyError as exc:
            if exc.status == 408:
                raise RequestTimeoutError(exc.message) from exc
            raise PayloadTooLargeError(exc.message, headers={"Connection": "close"}) from exc

    async def _schema_error(self, document: Any, body_bytes: int) -> PlanSchemaError:
        """The error of a refused plan: its first violations, worded off the event loop,
        bounded by the request's size."""
        assert self._wording is not None
        loop = asyncio.get_running_loop()
        found = await loop.run_in_executor(
            self._wording, lambda: validate_plan(document, limit=MAX_VIOLATIONS + 1)
        )
        complete = len(found) <= MAX_VIOLATIONS
        violations = [
            (_clip(pointer), _clip(message)) for pointer, message in found[:MAX_VIOLATIONS]
        ]
        if not violations:  # pragma: no cover - the fast check and the wording agree
            violations = [("", "the plan fails the schema")]
        room = body_bytes + ERROR_ROOM_BYTES
        error = PlanSchemaError(violations, complete=complete)
        while len(violations) > 1 and len(error_json(error)) > room:
            violations = violations[: len(violations) // 2]
            error = PlanSchemaError(violations, complete=False)
        return error

    def _cost(self, job: Job) -> Cost:
        """What ``job`` will take of the workers (:mod:`gate.admission`)."""
        samples = job.options.samples
        chunks = len(chunk_sizes(samples)) if samples > 1 else 0
        fine = STEP_ERROR_DT_S if self.validator.spread.step_error_scale > 0.0 else None
        return Cost.of(
            self.validator.twin_seconds(job),
            self.validator.settings.dt_s,
            samples,
            chunks,
            fine_dt_s=fine,
        )

    # -- the pool ----------------------------------------------------------------------------
    async def _validate(self, job: Job, ticket: Ticket, request: Request) -> bytes:
        """Run an admitted ``job`` (its nominal playback and, with samples, its chunks),
        within ``request_timeout_s``; cancel what is left when the deadline passes or the
        client leaves. ``ticket`` is released once every call has ended.

        A nominal playback whose worker process died is retried once on a fresh worker
        (playback is pure, so a retry is safe); a second death is a 500.
        """
        t0 = time.perf_counter()
        deadline = time.monotonic() + self.config.request_timeout_s
        calls = _Calls(self, ticket)
        try:
            nominal = calls.submit(lambda: self.pool.submit(job, client=ticket.client))
            chunks = [
                calls.submit(functools.partial(self._submit_chunk, chunk, ticket.client))
                for chunk in (self.validator.chunk_jobs(job) if job.options.samples > 1 else [])
            ]
            try:
                verdict_bytes = await calls.wait_one(nominal, deadline, request)
            except BrokenProcessPool:
                logger.warning("a worker process died during a validation; retrying once")
                nominal = calls.submit(lambda: self.pool.submit(job, client=ticket.client))
                try:
                    verdict_bytes = await calls.wait_one(nominal, deadline, request)
                except BrokenProcessPool as exc:
                    raise HttpError(
                        "a worker process died twice on this plan", code="worker_lost"
                    ) from exc
            if not chunks:
                return bytes(verdict_bytes)
            try:
                results = [await calls.wait_one(f, deadline, request) for f in chunks]
            except BrokenProcessPool as exc:
                raise HttpError(
                    "a worker process died playing samples", code="worker_lost"
                ) from exc
        finally:
            calls.cancel_rest()
        verdict = self.validator.with_uncertainty(Verdict.from_json(verdict_bytes), job, results)
        logger.debug(
            "plan %s: %d samples, collision probability %.3f",
            verdict.replay.plan_sha256[:12],
            job.options.samples,
            verdict.uncertainty.collision_probability if verdict.uncertainty else 0.0,
        )
        wall = round(time.perf_counter() - t0, 6)
        return replace(verdict, wall_time_s=wall).to_json().encode()

    def _submit_chunk(self, chunk: ChunkJob, client: str) -> Future[Any]:
        """One chunk of samples: on the cluster with ``--cluster``, else on the pool, where
        it may be preempted for another client (:mod:`gate.pool`)."""
        if self._cluster is not None:
            future: Future[Any] = self._cluster.submit_call(run_chunk, chunk)
            return future
        return self.pool.submit_call(run_chunk, chunk, client=client, preemptible=True)

    def _cancel(self, future: Future[Any]) -> None:
        """Stop a call: in the pool (a running one interrupted), or on the cluster."""
        if self._pool is not None:
            self._pool.cancel(future)

    def health(self) -> dict[str, Any]:
        """The body of ``GET /health``."""
        return {
            "status": "draining" if self.draining else "ok",
            "version": gate_version(),
            "default_map": self.validator.default_map,
            "maps": sorted(self.validator.maps),
            "pool": self.pool.kind,
            "cluster": self.config.cluster,
            "workers": self.pool.workers,
            "queue_depth": self.config.queue_depth,
            "in_flight": self.admission.in_flight,
            "admitted_work_s": round(self.admission.work_s, 3),
            "clients": self.admission.clients,
            "dt_s": self.validator.settings.dt_s,
            "max_body_bytes": self.config.max_body_bytes,
            "uptime_s": round(time.monotonic() - self._started, 3),
        }

    def _map_list(self) -> dict[str, Any]:
        out = []
        for name in sorted(self.validator.maps):
            world = self.validator.maps[name]
            b = world.bounds
            out.append(
                {
                    "name": name,
                    "description": world.description,
                    "sha256": self.validator.map_digest(name),
                    "bounds": {
                        "min_x": b.min_x,
                        "min_y": b.min_y,
                        "max_x": b.max_x,
                        "max_y": b.max_y,
                    },
                    "start": {
                        "x": world.start.x,
                        "y": world.start.y,
                        "yaw_deg": world.start.yaw_deg,
                    },
                    "obstacles": len(world.obstacles),
                    "goals": [
                        {"name": g.name, "x": g.x, "y": g.y, "yaw_deg": g.yaw_deg, "note": g.note}
                        for g in world.goals
                    ],
                }
            )
        return {"default": self.validator.default_map, "maps": out}


class _Calls:
    """The calls of one admitted validation: submitted, waited for against its deadline
    and its client's presence, and the rest cancelled at the end; the admission ticket
    is released once the last of them has ended. On the event loop."""

    def __init__(self, server: GateServer, ticket: Ticket) -> None:
        self.server = server
        self.ticket = ticket
        self.futures: list[Future[Any]] = []
        self._open = 1  # the validation itself, until cancel_rest
        self._lock = threading.Lock()

    def submit(self, make: Callable[[], Future[Any]]) -> Future[Any]:
        """Submit one call (``make`` submits it).

        Raises:
            OverloadedError: the pool is closed (shutting down).
        """
        try:
            future = make()
        except RuntimeError as exc:  # the pool is closed
            raise OverloadedError(
                "the gate is shutting down", code="shutting_down", retry_after_s=RETRY_AFTER_S
            ) from exc
        with self._lock:
            self._open += 1
        self.futures.append(future)
        future.add_done_callback(self._ended)
        return future

    def _ended(self, _future: Future[Any] | None) -> None:
        with self._lock:
            self._open -= 1
            done = self._open == 0
        if done:
            self.server.admission.release(self.ticket)

    async def wait_one(self, future: Future[Any], deadline: float, request: Request) -> Any:
        """``future``'s result, or an error once ``deadline`` passes (503 ``timeout``)
        or the client leaves (:class:`ClientGoneError`): it has closed its connection,
        or its end of it (the connection layer's mark says so; an HTTP client that
        waits for an answer does not close its end)."""
        waiter = asyncio.wrap_future(future)
        waits: set[asyncio.Future[Any]] = {waiter}
        mark = request.scope.get("extensions", {}).get(CONNECTION_EXTENSION)
        gone = mark.when_closed() if isinstance(mark, ConnectionMark) else None
        if gone is not None:
            waits.add(gone)
        done, _ = await asyncio.wait(
            waits,
            timeout=max(0.0, deadline - time.monotonic()),
            return_when=asyncio.FIRST_COMPLETED,
        )
        if waiter in done:
            try:
                return waiter.result()
            except (asyncio.CancelledError, CallCancelledError) as exc:
                if self.server.draining:
                    raise OverloadedError(
                        "the gate is shutting down",
                        code="shutting_down",
                        retry_after_s=RETRY_AFTER_S,
                    ) from exc
                raise HttpError("the validation was cancelled", code="cancelled") from exc
            except BrokenProcessPool:
                raise  # a worker died: the caller decides (a RuntimeError too)
            except RuntimeError as exc:  # the pool closed under it, or the job's own
                if not self.server.draining:
                    raise
                raise OverloadedError(
                    "the gate is shutting down", code="shutting_down", retry_after_s=RETRY_AFTER_S
                ) from exc
        waiter.cancel()
        with self.server._count_lock:
            self.server.cancelled += 1
        if gone is not None and gone in done:
            logger.info("client left: cancelling its validation")
            raise ClientGoneError("the client left before its verdict")
        raise OverloadedError(
            f"no verdict within {self.server.config.request_timeout_s:g} s",
            code="timeout",
            retry_after_s=RETRY_AFTER_S,
        )

    def cancel_rest(self) -> None:
        """Cancel every call not ended (each ends once its worker has stopped it)."""
        for future in self.futures:
            if not future.done():
                self.server._cancel(future)
        self._ended(None)  # the validation's own share of the count


def _clip(text: str) -> str:
    return text if len(text) <= MAX_VIOLATION_CHARS else text[: MAX_VIOLATION_CHARS - 3] + "..."


def _error_body(error: StatusError) -> tuple[str, bytes]:
    """The gate's wording of every error: ``{"error": code, "status", "message", ...}``."""
    return JSON_CONTENT_TYPE, error_json(error)
