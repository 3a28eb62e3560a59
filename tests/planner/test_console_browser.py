"""The stack's console against web pages, in headless Chromium: a page of another port
of 127.0.0.1 posting a form and a ``no-cors`` fetch to ``/stop`` and ``/clear_stop``,
and a page whose name a DNS rebinding points at the console, reading ``/status`` and
posting STOP as its own origin. The browser sends every one of them; the console refuses
each, and the rover hears no STOP and no clear. The commands' own client, the control,
does STOP it. A real console on 127.0.0.1; the rover's side of the bus is the
``inprocess`` ROS port (what the console publishes is seen there as the bridge would
see it)."""

from __future__ import annotations

import threading
import uuid
from collections.abc import Iterator
from typing import Any

import pytest

from bridge.ros.rosport import STOP_LANE, open_port, qos
from bridge.ros.rosport.msgs import Bool, Empty
from planner.ground.console import RoverConsole
from planner.ground.console_client import ConsoleClient
from planner.stack.console_server import ConsoleConfig, ConsoleServer

pytestmark = [pytest.mark.browser, pytest.mark.slow]

WAIT_S = 30.0


def _attacks(console: str) -> dict[str, str]:
    """Pages of another origin that try STOP and clear-STOP on ``console``."""
    fetches = "".join(
        f'fetch("{console}{path}", {{method: "POST", mode: "no-cors", body: "{{}}",'
        ' headers: {"Content-Type": "text/plain"}})'
        ".then(() => done.push(1), () => done.push(0));"
        for path in ("/stop?timeout=1", "/clear_stop?timeout=1")
    )

    def form(path: str) -> str:
        return (
            f'<form method="POST" action="{console}{path}" enctype="text/plain">'
            '<input name="x" value="1"></form><script>document.forms[0].submit()</script>'
        )

    return {
        "/stop_form.html": form("/stop?timeout=1"),
        "/clear_form.html": form("/clear_stop?timeout=1"),
        "/fetch.html": f"<script>window.done = []; {fetches}</script>",
    }


class _Rover:
    """What the bridge would hear from the console."""

    def __init__(self, port: Any) -> None:
        self.stops = 0
        self.clears = 0
        self.stopped = threading.Event()
        port.subscribe("emergency_stop", Bool, self._on_stop, qos.STOP, lane=STOP_LANE)
        port.subscribe("clear_emergency_stop", Empty, self._on_clear, qos.STOP, lane=STOP_LANE)

    def _on_stop(self, msg: Bool) -> None:
        self.stops += 1
        self.stopped.set()

    def _on_clear(self, msg: Empty) -> None:
        self.clears += 1


@pytest.fixture
def served() -> Iterator[tuple[ConsoleServer, _Rover]]:
    bus = f"console-browser-{uuid.uuid4().hex}"
    with (
        open_port("inprocess", bus=bus, node_name="rover_stack_console") as port,
        open_port("inprocess", bus=bus, node_name="rover_bridge") as rover_port,
        RoverConsole(port) as console,
        ConsoleServer(console, ConsoleConfig()) as server,
    ):
        yield server, _Rover(rover_port)


def test_pages_of_another_origin_cannot_stop_clear_or_read_the_console(
    served: tuple[ConsoleServer, _Rover],
) -> None:
    from tests.browser import REBIND, WITHOUT_PRIVATE_NETWORK_ACCESS, OtherSite, chromium

    server, rover = served
    console = server.url
    port = console.rsplit(":", 1)[1]
    other = OtherSite(_attacks(console), WAIT_S)
    try:
        resolve = f"--host-resolver-rules=MAP {REBIND} 127.0.0.1"
        with chromium((resolve, WITHOUT_PRIVATE_NETWORK_ACCESS)) as browser:
            page = browser.new_page()
            # A form posted from another port: the browser sends it, the console refuses.
            for form in ("/stop_form.html", "/clear_form.html"):
                with page.expect_response(lambda r: r.request.method == "POST") as posted:
                    page.goto(other.origin + form)
                assert posted.value.status == 403, form
                assert "a request from a web page" in posted.value.text()
            assert server.refused["403 POST /stop"] == 1
            assert server.refused["403 POST /clear_stop"] == 1
            # A no-cors fetch: sent (the console counts it), refused.
            page.goto(other.origin + "/fetch.html")
            page.wait_for_function("() => window.done && window.done.length === 2")
            assert server.refused["403 POST /stop"] == 2
            assert server.refused["403 POST /clear_stop"] == 2
            # A rebinding page: its own origin is the console's port, so the browser lets
            # it read and post there, with any header. Its name is not the console's.
            rebound = f"http://{REBIND}:{port}"
            page.route(
                rebound + "/attack.html",
                lambda route: route.fulfill(body="<p>attack</p>", content_type="text/html"),
            )
            page.goto(rebound + "/attack.html")
            page.unroute(rebound + "/attack.html")
            statuses = page.evaluate(
                """async () => {
                    const out = [];
                    const asks = [["GET", "/status?timeout=1"], ["POST", "/stop?timeout=1"],
                                  ["POST", "/clear_stop?timeout=1"],
                                  ["GET", "/echo?topic=command_status&count=1&timeout=1"]];
                    for (const [method, path] of asks) {
                        const r = await fetch(path, {method,
                                                     headers: {"X-Rover-Console": "1"}});
                        out.push(r.status);
                    }
                    return out;
                }"""
            )
            assert statuses == [421, 421, 421, 421]
            assert server.refused["421 GET /status"] >= 1  # Chromium retries a 421 once
    finally:
        other.close()
    assert rover.stops == 0 and rover.clears == 0 and server.stops_published == 0
    # The control: the commands' own client, with the stack's token, does STOP.
    assert ConsoleClient(console, server.config.token).stop(0.5) is False  # nobody answers
    assert rover.stopped.wait(WAIT_S) and server.stops_published >= 1
