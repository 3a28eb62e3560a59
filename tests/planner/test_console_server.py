"""The stack's console socket on a real HTTP server on 127.0.0.1, its client the one the
commands use: the bind and token policy, bad requests answered and the server going on,
bounded waits when no bridge answers, and ``echo`` streaming a topic with its last value
first. The topics travel on the ``inprocess`` ROS port (what the test publishes is a
message on the bus, as a bridge's would be); the same server against a real bridge over
DDS is tests/planner/test_console.py's (``rover stack up`` and the commands)."""

from __future__ import annotations

import http.client
import json
import socket
import threading
import uuid
from collections.abc import Iterator
from typing import Any

import pytest

from bridge.ros.rosport import open_port, qos
from bridge.ros.rosport.msgs import Odometry, String
from planner.errors import ConsoleRefusedError, ConsoleUnavailableError
from planner.ground.console import RoverConsole
from planner.ground.console_client import ConsoleClient
from planner.stack.console_server import ConsoleConfig, ConsoleServer

TOKEN = "s3cret"


HEARD = threading.Event()
"""Set when the console hears a ``command_status``."""


@pytest.fixture
def served() -> Iterator[tuple[ConsoleServer, Any]]:
    """A console on an in-process port, with a token; and a port on the same bus (the
    rover's side) to publish on."""
    bus = f"console-{uuid.uuid4().hex}"
    HEARD.clear()
    with (
        open_port("inprocess", bus=bus, node_name="rover_stack_console") as port,
        open_port("inprocess", bus=bus, node_name="rover_bridge") as rover,
        RoverConsole(port, on_status=lambda text: HEARD.set()) as console,
        ConsoleServer(console, ConsoleConfig(token=TOKEN)) as server,
    ):
        yield server, rover


def _raw(server: ConsoleServer, method: str, path: str, token: str | None = TOKEN) -> Any:
    host, port = server.url.rsplit("//", 1)[1].split(":")
    conn = http.client.HTTPConnection(host, int(port), timeout=10)
    try:
        headers = {"Authorization": f"Bearer {token}"} if token else {}
        conn.request(method, path, headers=headers)
        response = conn.getresponse()
        return response.status, json.loads(response.read() or b"{}")
    finally:
        conn.close()


def test_the_bind_policy_is_the_gates() -> None:
    with pytest.raises(ValueError, match=r"refusing to listen on '0\.0\.0\.0' without a token"):
        ConsoleConfig("0.0.0.0")
    assert ConsoleConfig("0.0.0.0", token="t").host == "0.0.0.0"
    with pytest.raises(ValueError, match="console port"):
        ConsoleConfig(port=70000)


def test_a_token_is_needed_and_bad_requests_get_an_answer(
    served: tuple[ConsoleServer, Any],
) -> None:
    server, _ = served
    for token, why in ((None, "needs 'Authorization: Bearer <token>'"), ("no", "wrong token")):
        with pytest.raises(ConsoleRefusedError, match=why) as refused:
            ConsoleClient(server.url, token).status(0.2)
        assert refused.value.status == 401
    assert _raw(server, "GET", "/stop")[0] == 405
    assert _raw(server, "GET", "/nothing")[0] == 404
    assert _raw(server, "GET", "/status?timeout=abc")[0] == 400
    assert _raw(server, "GET", "/status?timeout=1e9")[0] == 400
    code, doc = _raw(server, "GET", "/echo?topic=nonsense")
    assert code == 400 and "topic must be one of" in doc["error"]
    assert _raw(server, "GET", "/echo?topic=odom&count=x")[0] == 400
    # Still serving, and every wait bounded: no bridge here, so no state and no 'stopped'.
    client = ConsoleClient(server.url, TOKEN)
    with pytest.raises(ConsoleRefusedError, match="no /diagnostics from the bridge") as late:
        client.status(0.3)
    assert late.value.status == 504
    assert client.stop(0.3) is False


def test_echo_streams_a_topic_with_its_last_value_first(
    served: tuple[ConsoleServer, Any],
) -> None:
    server, rover = served
    client = ConsoleClient(server.url, TOKEN)
    statuses = rover.publisher("command_status", String, qos.STATUS)
    statuses.wait_for_subscribers(1, 5.0)
    statuses.publish(String(data="completed"))  # said while nobody echoed
    assert HEARD.wait(5.0) and server.console.heard == ("completed",)
    lines = list(client.echo("command_status", 1, 5.0))
    assert lines[0] == {"listening": True}
    assert lines[1]["text"] == "completed" and lines[1]["last_known"] is True
    # A live topic: each message as it comes, its line as `rover echo` prints it.
    odom = rover.publisher("odom_ground", Odometry, qos.TELEMETRY)
    got: list[dict[str, Any]] = []

    def read() -> None:
        got.extend(client.echo("odom_ground", 2, 10.0))

    reader = threading.Thread(target=read)
    reader.start()
    msg = Odometry()
    msg.header.frame_id = "map"
    msg.pose.pose.position.x = 1.25
    msg.pose.pose.orientation.w = 1.0
    for _ in range(100):  # until the reader has joined and taken two
        if not reader.is_alive():
            break
        odom.publish(msg)
        reader.join(0.05)
    reader.join(10)
    texts = [line["text"] for line in got if "text" in line]
    assert len(texts) == 2 and texts[-1].startswith("x=1.250 y=0.000 yaw=0.0 deg"), got
    assert "frame=map" in texts[-1]


def test_a_console_that_is_not_there_is_unavailable() -> None:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        url = f"http://127.0.0.1:{probe.getsockname()[1]}"
    with pytest.raises(ConsoleUnavailableError, match="the stack's console at"):
        ConsoleClient(url).stop(1.0)
    with pytest.raises(ConsoleRefusedError, match="not a console URL"):
        ConsoleClient("ftp://x")
