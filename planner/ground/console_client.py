"""The client of a stack's console socket (:mod:`planner.stack.console_server`): what
``rover status``, ``stop``, ``clear-stop`` and ``echo`` use when a stack is up.

The standard library's ``http.client`` only: no rclpy, no DDS discovery in the command.
Every call has a timeout; a console that does not answer (the stack is gone) raises
:class:`ConsoleUnavailableError`, and the commands then use ROS 2 instead.
"""

from __future__ import annotations

import http.client
import json
import time
from collections.abc import Iterator
from typing import Any
from urllib.parse import urlencode, urlsplit

from planner.errors import ConsoleRefusedError, ConsoleUnavailableError
from planner.ground.roverstatus import RoverStatus

__all__ = [
    "CONSOLE_ENV",
    "CONSOLE_HEADER",
    "TOKEN_ENV",
    "ConsoleClient",
    "ConsoleRefusedError",
    "ConsoleUnavailableError",
    "status_of",
]

CONSOLE_ENV = "ROVER_STACK_CONSOLE"
"""The stack's console, ``http://HOST:PORT`` (``rover stack env`` exports it)."""
TOKEN_ENV = "ROVER_CONSOLE_TOKEN"
"""Its bearer token (default: the serving stack's, :func:`planner.stack.domains.console_token`)."""
CONSOLE_HEADER = "X-Rover-Console"
"""The header (value ``1``) every request carries (:mod:`planner.stack.consoleaccess`)."""
_SLACK_S = 2.0
"""How much longer than the wait it asked for a call may take to answer, s."""


def status_of(doc: dict[str, Any]) -> RoverStatus:
    """The :class:`RoverStatus` a console's ``/status`` answer describes."""
    return RoverStatus(
        {k: dict(v) for k, v in doc["values"].items()},
        {k: int(v) for k, v in doc["raw_levels"].items()},
        dict(doc["messages"]),
        float(doc.get("stamp_s", 0.0)),
    )


class ConsoleClient:
    """Calls on a stack's console at ``url`` (``http://HOST:PORT``), with ``token``."""

    def __init__(self, url: str, token: str | None = None) -> None:
        parts = urlsplit(url)
        if parts.scheme != "http" or not parts.hostname or parts.port is None:
            raise ConsoleRefusedError(0, f"not a console URL (http://HOST:PORT): {url!r}")
        self.url = url
        self._host, self._port = parts.hostname, parts.port
        self._token = token

    def _connect(self, timeout_s: float) -> http.client.HTTPConnection:
        return http.client.HTTPConnection(self._host, self._port, timeout=timeout_s)

    def _headers(self) -> dict[str, str]:
        # The marker header: what a web page's form or no-cors fetch cannot send
        # (planner.stack.consoleaccess).
        headers = {CONSOLE_HEADER: "1"}
        if self._token:
            headers["Authorization"] = f"Bearer {self._token}"
        return headers

    def _call(self, method: str, path: str, wait_s: float) -> dict[str, Any]:
        query = urlencode({"timeout": f"{wait_s:g}"})
        conn = self._connect(wait_s + _SLACK_S)
        try:
            conn.request(method, f"{path}?{query}", headers=self._headers())
            response = conn.getresponse()
            body = response.read()
        except (OSError, http.client.HTTPException) as exc:
            raise ConsoleUnavailableError(f"the stack's console at {self.url}: {exc}") from exc
        finally:
            conn.close()
        try:
            doc: dict[str, Any] = json.loads(body or b"{}")
        except ValueError as exc:
            raise ConsoleUnavailableError(f"{self.url} answered no JSON: {body[:80]!r}") from exc
        if response.status != 200:
            raise ConsoleRefusedError(response.status, str(doc.get("error", response.reason)))
        return doc

    def status(self, wait_s: float) -> tuple[RoverStatus, dict[str, Any]]:
        """The bridge's latest state (waiting at most ``wait_s`` for a first one) and
        the answer as it came (``age_s``: how old it is)."""
        doc = self._call("GET", "/status", wait_s)
        return status_of(doc), doc

    def stop(self, wait_s: float) -> bool:
        """Emergency stop until ``stopped`` (at most ``wait_s``); whether it came. Raises
        :class:`ConsoleUnavailableError` when the console did not answer (nothing was sent,
        or it is not known whether it was)."""
        try:
            return bool(self._call("POST", "/stop", wait_s).get("stopped"))
        except ConsoleRefusedError as exc:
            if exc.status == 504:
                return False
            raise

    def clear_stop(self, wait_s: float) -> dict[str, Any]:
        """Release the latch: ``outcome``, ``released``, ``why``, ``held_by``."""
        return self._call("POST", "/clear_stop", wait_s)

    def echo(self, topic: str, count: int, idle_s: float) -> Iterator[dict[str, Any]]:
        """The messages of ``topic`` as they come (the last one kept first, marked
        ``last_known``), ``count`` of them (0: until the caller stops); each is ``t``
        (wall s), ``text`` (one line, as ``rover echo`` prints it) and ``data``.

        Raises:
            ConsoleUnavailableError: no answer, or the stream broke.
            TimeoutError: no message for ``idle_s``.
        """
        query = urlencode({"topic": topic, "count": count, "timeout": f"{min(idle_s, 60):g}"})
        conn = self._connect(idle_s + _SLACK_S)
        try:
            try:
                conn.request("GET", f"/echo?{query}", headers=self._headers())
                response = conn.getresponse()
            except (OSError, http.client.HTTPException) as exc:
                raise ConsoleUnavailableError(f"the stack's console at {self.url}: {exc}") from exc
            if response.status != 200:
                doc = json.loads(response.read() or b"{}")
                raise ConsoleRefusedError(response.status, str(doc.get("error", response.reason)))
            heard = time.monotonic()
            while True:
                try:
                    raw = response.readline()
                except TimeoutError as exc:
                    raise TimeoutError(f"no message on {topic} within {idle_s:g} s") from exc
                except (OSError, http.client.HTTPException) as exc:
                    raise ConsoleUnavailableError(f"the echo stream broke: {exc}") from exc
                if not raw:
                    return  # the server ended the stream (the count was reached)
                if raw.strip() == b"":  # a keep-alive, about once a second
                    if time.monotonic() - heard >= idle_s:
                        raise TimeoutError(f"no message on {topic} within {idle_s:g} s")
                    continue
                doc = json.loads(raw)
                if not doc.get("listening"):
                    heard = time.monotonic()
                yield doc
        finally:
            conn.close()
