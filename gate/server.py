"""The HTTP gate: ``POST /validate_plan`` and friends, served by uvicorn.

:class:`GateServer` is an ASGI application (Starlette's request and response types) on
the project's one HTTP stack (:mod:`firmware_proto.http`: uvicorn with h11, one
event loop in a thread of its own, every connection bounded by deadlines), in front of
a bounded :mod:`worker pool <gate.pool>`:

- *Admission*: at most ``workers + queue_depth`` validations are admitted at once; the
  next one gets 503 with ``Retry-After`` at once instead of waiting in a queue that
  grows without bound. ``GET`` requests need no worker.
- *Clients*: a connection waits ``idle_timeout_s`` for a request, whose head must then
  arrive within ``head_timeout_s`` (408 otherwise: slowloris) and its body within
  ``body_timeout_s`` (408); slow clients cost no thread, so they cannot lock others out.
  Beyond ``max_connections`` open at once, a new one is answered 503.
- *Bodies*: a declared length over ``max_body_bytes`` is refused (413) before a byte of
  it is read (and before ``100 Continue``); chunked bodies are counted as they come; a
  body without framing gets 411; every error body is JSON, those the connection layer
  answers itself too (:func:`gate.response.render_connection_error`).
- *Auth and binding* (:mod:`firmware_proto.http.bindpolicy`): with a token, every request
  needs ``Authorization: Bearer <token>`` (constant-time comparison; 401 otherwise). The
  configuration refuses a non-loopback address without a token.
- *Shutdown* (:meth:`GateServer.close`, idempotent): new requests get 503; the listener
  closes; idle connections are closed; requests under way finish (up to
  ``drain_timeout_s``) with ``Connection: close``; then the workers stop.

The event loop does I/O and parsing only; playback runs in the pool. Each operation is
one ``_op_<name>`` coroutine named by :data:`gate.routes.ROUTES`.
"""

from __future__ import annotations

import asyncio
import logging
import threading
import time
from collections import Counter
from collections.abc import Awaitable, Callable, MutableMapping
from concurrent.futures import Future, ThreadPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import replace
from typing import Any

from starlette.requests import Request
from starlette.responses import Response

from firmware_proto.errors import PlanError
from firmware_proto.http import (
    ClientGoneError,
    HttpService,
    RequestBodyError,
    ServeLimits,
    read_body,
)
from firmware_proto.http.bindpolicy import bearer_token, token_matches
from firmware_proto.http.limits import DEFAULT_MAX_DRAIN_BYTES
from firmware_proto.model.plan import Plan
from firmware_proto.model.verdict import Verdict
from gate import routes
from gate.config import GateConfig
from gate.ensemble import run_chunk
from gate.errors import (
    BadRequestError,
    HttpError,
    MethodNotAllowedError,
    MethodNotImplementedError,
    NotFoundError,
    OptionError,
    OverloadedError,
    PayloadTooLargeError,
    PlanSchemaError,
    RequestTimeoutError,
    UnauthorizedError,
)
from gate.openapi import build_openapi
from gate.options import ValidateOptions
from gate.pool import WorkerPool, make_pool
from gate.request import check_declared_length, check_json_media_type, parse_json
from gate.response import (
    JSON_CONTENT_TYPE,
    SERVER_NAME,
    error_body,
    json_bytes,
    render_connection_error,
)
from gate.validator import Job, Validator, gate_version

__all__ = ["GateServer"]

logger = logging.getLogger(__name__)

RETRY_AFTER_S = 1
"""``Retry-After`` of a 503: one typical validation is well under a second."""
METHODS = ("DELETE", "GET", "HEAD", "OPTIONS", "PATCH", "POST", "PUT")
"""Methods the gate understands (405 where a path does not take one); others are 501."""

_Reply = tuple[int, bytes, dict[str, str]]
_Scope = MutableMapping[str, Any]
_Send = Callable[[MutableMapping[str, Any]], Awaitable[None]]
_Receive = Callable[[], Awaitable[MutableMapping[str, Any]]]


class GateServer:
    """The simulation gate's HTTP server. See the module docstring.

    Use as a context manager, or call :meth:`start` and :meth:`close`::

        with GateServer(GateConfig(port=0)) as gate:
            print(gate.url)

    Args:
        config: the settings.
        validator: the validator (default: loaded from ``config``).
        pool: the worker pool (default: made from ``config``); the server closes it.
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
        self._submitter: ThreadPoolExecutor | None = None
        self._draining = threading.Event()
        self.stopped_accepting = threading.Event()
        """Set once :meth:`close` has closed the listener (new connections refused)."""
        self._closed = False
        self._close_lock = threading.Lock()
        self._slots = threading.BoundedSemaphore(config.capacity)
        self._in_flight = 0
        self._count_lock = threading.Lock()
        self.rejected: Counter[str] = Counter()
        """Requests answered with an error, by error code (bad input is counted here
        and logged; the connection layer logs what it refuses itself)."""
        self._started = time.monotonic()
        names = sorted(self.validator.maps)
        self._map_bodies = {n: json_bytes(self.validator.maps[n].to_dict()) for n in names}
        self._maps_body = json_bytes(self._map_list())
        self._openapi_body = json_bytes(build_openapi(config, names, self.validator.default_map))

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
            drain_timeout_s=config.drain_timeout_s,
        )
        # The retry after a worker died goes through this thread: replacing the worker
        # takes a second, during which other requests go on being served. It starts
        # now, not with the first retry.
        self._submitter = ThreadPoolExecutor(1, thread_name_prefix="gate-submit")
        self._submitter.submit(int).result()
        service = HttpService(
            self._asgi,
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
            self._submitter.shutdown(wait=False)
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
        if self._submitter is not None:
            self._submitter.shutdown(wait=True)
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

    # -- the ASGI application -------------------------------------------------------------
    async def _asgi(self, scope: _Scope, receive: _Receive, send: _Send) -> None:
        if scope["type"] != "http":  # lifespan is off and websockets are not served
            return
        request = Request(scope, receive)
        close = self.draining
        try:
            status, body, headers = await self._dispatch(request)
        except ClientGoneError:
            return  # nobody to answer
        except HttpError as exc:
            status, body, headers = exc.status, error_body(exc), dict(exc.headers)
            close = close or self._close_after(exc, request)
            with self._count_lock:
                self.rejected[exc.code] += 1
            log = logger.warning if exc.status >= 500 and exc.status != 503 else logger.info
            log("%s %s: %d %s: %s", scope["method"], scope["path"], status, exc.code, exc.message)
        except Exception:
            logger.exception("internal error serving %s %s", scope["method"], scope["path"])
            error = HttpError("internal error; see the gate's log")
            status, body, headers, close = error.status, error_body(error), {}, True
        headers["Cache-Control"] = "no-store"
        if close or self.draining:
            headers["Connection"] = "close"
        await Response(body, status, headers, media_type=JSON_CONTENT_TYPE)(scope, receive, send)

    def _close_after(self, error: HttpError, request: Request) -> bool:
        """Whether an error ends the connection: a server fault, a body that stalled
        (408), or a declared body too large to be worth reading and dropping."""
        if error.status == 408 or (error.status >= 500 and error.status != 503):
            return True
        if isinstance(error, PayloadTooLargeError):
            length = request.headers.get("content-length")
            return length is None or int(length) > DEFAULT_MAX_DRAIN_BYTES
        return False

    async def _dispatch(self, request: Request) -> _Reply:
        method = request.method
        if method not in METHODS:
            raise MethodNotImplementedError(f"method {method} is not implemented here")
        self._authorise(request.headers.get("authorization"))
        if self.draining:
            raise OverloadedError(
                "the gate is shutting down", code="shutting_down", retry_after_s=RETRY_AFTER_S
            )
        path = bytes(request.scope["raw_path"]).decode("latin-1")
        try:
            found = routes.match(path)
        except UnicodeDecodeError:
            found = None
        if found is None:
            raise NotFoundError(f"no such path {path!r}")
        route, params = found
        if method not in route.allowed:
            raise MethodNotAllowedError(
                f"{method} is not allowed on {route.template}", list(route.allowed)
            )
        operation: Callable[[Request, dict[str, str]], Awaitable[_Reply]] = getattr(
            self, "_op_" + route.operation
        )
        return await operation(request, params)

    def _authorise(self, header: str | None) -> None:
        token = self.config.token
        if token is None:
            return
        challenge = 'Bearer realm="rover-gate"'
        if not header:
            raise UnauthorizedError(
                "this gate needs 'Authorization: Bearer <token>'",
                headers={"WWW-Authenticate": challenge},
            )
        if not token_matches(bearer_token(header), token):
            raise UnauthorizedError(
                "wrong bearer token",
                code="invalid_token",
                headers={"WWW-Authenticate": challenge + ', error="invalid_token"'},
            )

    # -- operations ------------------------------------------------------------------------
    async def _op_health(self, request: Request, params: dict[str, str]) -> _Reply:
        return 200, json_bytes(self.health()), {}

    async def _op_list_maps(self, request: Request, params: dict[str, str]) -> _Reply:
        return 200, self._maps_body, {}

    async def _op_get_map(self, request: Request, params: dict[str, str]) -> _Reply:
        body = self._map_bodies.get(params["name"])
        if body is None:
            known = ", ".join(sorted(self._map_bodies))
            raise NotFoundError(f"no map {params['name']!r}; known: {known}", code="unknown_map")
        return 200, body, {}

    async def _op_openapi(self, request: Request, params: dict[str, str]) -> _Reply:
        return 200, self._openapi_body, {}

    async def _op_validate_plan(self, request: Request, params: dict[str, str]) -> _Reply:
        document = await self._read_json(request)
        try:
            plan = Plan.from_dict(document)
        except PlanError as exc:
            raise PlanSchemaError(exc.violations) from exc
        query = bytes(request.scope["query_string"]).decode("latin-1")
        try:
            options = ValidateOptions.from_query(query)
            job = self.validator.prepare(
                plan, options.resolve(self.validator.settings, self.validator.default_map)
            )
        except OptionError as exc:
            raise BadRequestError(str(exc), code="invalid_option", parameter=exc.parameter) from exc
        if job.options.samples > 1:
            return 200, await self._run_uncertain(job), {}
        return 200, await self._run(job), {}

    async def _read_json(self, request: Request) -> Any:
        """The request's body as strict JSON (media type, length, deadline checked)."""
        check_json_media_type(request.headers.get("content-type"))
        limit = self.config.max_body_bytes
        check_declared_length(request.headers, limit)
        try:
            body = await read_body(
                request.receive, limit_bytes=limit, timeout_s=self.config.body_timeout_s
            )
        except RequestBodyError as exc:
            if exc.status == 408:
                raise RequestTimeoutError(exc.message) from exc
            raise PayloadTooLargeError(exc.message) from exc
        return parse_json(body)

    # -- the pool ----------------------------------------------------------------------------
    async def _run(self, job: Job) -> bytes:
        """Admit ``job`` (or 503), run it in the pool, wait for its verdict bytes.

        The admission slot is held until the job has finished in its worker, even when
        the wait times out, so no more than ``capacity`` validations ever run or wait. A
        job whose worker process died is retried once on a fresh worker (playback is
        pure, so a retry is safe); a second death is a 500. The first hand-off is made
        on the event loop (a write to an idle worker's pipe, or a place in the pool's
        queue); the process pool replaces a dead worker from its own thread, and the
        job waits for it (the retry after a death during a job is handed off from the
        ``gate-submit`` thread).
        """
        if not self._slots.acquire(blocking=False):
            raise OverloadedError(
                f"all {self.pool.workers} workers busy and {self.config.queue_depth} "
                "validations queued",
                retry_after_s=RETRY_AFTER_S,
            )
        with self._count_lock:
            self._in_flight += 1
        release_now = True
        loop = asyncio.get_running_loop()
        try:
            for attempt in (1, 2):
                try:
                    if attempt == 1:  # on the loop: a hand-off to a thread costs a wake-up
                        future: Future[bytes] = self.pool.submit(job)
                    else:  # after a worker died: off the loop
                        future = await loop.run_in_executor(self._submitter, self.pool.submit, job)
                    waiter = asyncio.wrap_future(future)
                    done, _ = await asyncio.wait({waiter}, timeout=self.config.request_timeout_s)
                    if not done:
                        release_now = False
                        future.add_done_callback(lambda _f: self._release())
                        waiter.cancel()  # a job still queued is dropped; a running one ends
                        raise OverloadedError(
                            f"no verdict within {self.config.request_timeout_s:g} s",
                            code="timeout",
                            retry_after_s=RETRY_AFTER_S,
                        )
                    if waiter.cancelled():
                        raise RuntimeError("the pool cancelled the job")
                    return waiter.result()
                except BrokenProcessPool as exc:
                    if attempt == 2:
                        raise HttpError(
                            "a worker process died twice on this plan", code="worker_lost"
                        ) from exc
                    logger.warning("a worker process died during a validation; retrying once")
                except RuntimeError as exc:  # the pool is closed or cancelled the job
                    if not self.draining:
                        raise
                    raise OverloadedError(
                        "the gate is shutting down",
                        code="shutting_down",
                        retry_after_s=RETRY_AFTER_S,
                    ) from exc
            raise AssertionError("unreachable")  # pragma: no cover
        finally:
            if release_now:
                self._release()

    async def _run_uncertain(self, job: Job) -> bytes:
        """A verdict with its uncertainty: the nominal playback (:meth:`_run`, which
        admits the request) and, meanwhile, the chunks of its twins on the cluster or
        the local pool; then the summary (:mod:`gate.ensemble`). A chunk that fails or
        a wait past ``request_timeout_s`` fails the request (its chunks are cancelled)."""
        t0 = time.perf_counter()
        engine = self._cluster if self._cluster is not None else self.pool
        futures = [engine.submit_call(run_chunk, c) for c in self.validator.chunk_jobs(job)]
        waiters = [asyncio.wrap_future(f) for f in futures]
        try:
            nominal = await self._run(job)
            done, _ = await asyncio.wait(waiters, timeout=self.config.request_timeout_s)
            if len(done) < len(waiters):
                raise OverloadedError(
                    f"no verdict for {job.options.samples} samples within "
                    f"{self.config.request_timeout_s:g} s",
                    code="timeout",
                    retry_after_s=RETRY_AFTER_S,
                )
            results = [w.result() for w in waiters]
        except BrokenProcessPool as exc:
            raise HttpError("a worker process died playing samples", code="worker_lost") from exc
        finally:
            for w in waiters:
                w.cancel()
        verdict = self.validator.with_uncertainty(Verdict.from_json(nominal), job, results)
        logger.debug(
            "plan %s: %d samples, collision probability %.3f",
            verdict.replay.plan_sha256[:12],
            job.options.samples,
            verdict.uncertainty.collision_probability if verdict.uncertainty else 0.0,
        )
        wall = round(time.perf_counter() - t0, 6)
        return replace(verdict, wall_time_s=wall).to_json().encode()

    def _release(self) -> None:
        with self._count_lock:
            self._in_flight -= 1
        self._slots.release()

    def health(self) -> dict[str, Any]:
        """The body of ``GET /health``."""
        with self._count_lock:
            in_flight = self._in_flight
        return {
            "status": "draining" if self.draining else "ok",
            "version": gate_version(),
            "default_map": self.validator.default_map,
            "maps": sorted(self.validator.maps),
            "pool": self.pool.kind,
            "cluster": self.config.cluster,
            "workers": self.pool.workers,
            "queue_depth": self.config.queue_depth,
            "in_flight": in_flight,
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
