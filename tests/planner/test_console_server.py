"""The stack's console socket on a real HTTP server on 127.0.0.1, its client the one the
commands use: STOP published at once whatever else waits, one clear-STOP at a time, who
it answers (its own Host, no web page, the token always, a marked POST), bad requests
answered and the server going on, bounded waits when no bridge answers, ``echo``
streaming a topic with its last value first and never losing a slot. The topics travel
on the ``inprocess`` ROS port (what the test publishes is a message on the bus, as a
bridge's would be, and what the console publishes is seen there as the bridge would
see it); the same server against a real bridge over DDS is tests/planner/test_console.py's
(``rover stack up`` and the commands), in a browser tests/planner/test_console_browser.py's.

No assertion here is about time: the waits are generous bounds on events, and what is
checked is order (the STOP reached the rover while the clear-STOP still waited)."""

from __future__ import annotations

import dataclasses
import http.client
import json
import socket
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import pytest

from bridge.link.controllerlink import LinkDiagnostics
from bridge.ros.diagnostics import diagnostic_array
from bridge.ros.rosport import STOP_LANE, RosPort, open_port, qos
from bridge.ros.rosport.msgs import Bool, DiagnosticArray, Empty, Odometry, String, stamp
from planner.errors import ConsoleRefusedError, ConsoleUnavailableError
from planner.ground.console import RoverConsole
from planner.ground.console_client import CONSOLE_HEADER, ConsoleClient
from planner.stack.console_server import ConsoleConfig, ConsoleServer

TOKEN = "s3cret-console-token"
WAIT_S = 30.0
"""The bound of every wait on an event here (generous: the machine is shared)."""


class Rover:
    """The rover's side of the bus: what the bridge would hear from the console, and
    what it would say."""

    def __init__(self, port: RosPort, console: RoverConsole) -> None:
        self.port = port
        self.console = console
        self.stops: list[bool] = []
        self.clears = 0
        self.stopped = threading.Event()
        self.cleared = threading.Event()
        port.subscribe("emergency_stop", Bool, self._on_stop, qos.STOP, lane=STOP_LANE)
        port.subscribe("clear_emergency_stop", Empty, self._on_clear, qos.STOP, lane=STOP_LANE)
        self.statuses = port.publisher("command_status", String, qos.STATUS)
        self.diagnostics = port.publisher("diagnostics", DiagnosticArray, qos.DIAGNOSTICS)
        assert self.statuses.wait_for_subscribers(1, WAIT_S)

    def _on_stop(self, msg: Bool) -> None:
        self.stops.append(bool(msg.data))
        self.stopped.set()

    def _on_clear(self, msg: Empty) -> None:
        self.clears += 1
        self.cleared.set()

    def say(self, text: str) -> None:
        self.statuses.publish(String(data=text))

    def bridge_reports(self) -> None:
        """The bridge's ``/diagnostics`` (ready), as it publishes them every second;
        returns once the console has it."""
        self.diagnostics.publish(_ready_diagnostics())
        _until(lambda: self.console.latest() is not None)


HEARD = threading.Event()
"""Set when the console hears a ``command_status``."""


@pytest.fixture
def served() -> Iterator[tuple[ConsoleServer, Rover]]:
    """A console on an in-process port, with a token; and the rover's side of the bus."""
    bus = f"console-{uuid.uuid4().hex}"
    HEARD.clear()
    with (
        open_port("inprocess", bus=bus, node_name="rover_stack_console") as port,
        open_port("inprocess", bus=bus, node_name="rover_bridge") as rover,
        RoverConsole(port, on_status=lambda text: HEARD.set()) as console,
        ConsoleServer(console, ConsoleConfig(token=TOKEN)) as server,
    ):
        yield server, Rover(rover, console)


def _address(server: ConsoleServer) -> tuple[str, int]:
    host, port = server.url.rsplit("//", 1)[1].split(":")
    return host, int(port)


def _raw(
    server: ConsoleServer,
    method: str,
    path: str,
    token: str | None = TOKEN,
    headers: dict[str, str] | None = None,
    body: bytes | None = None,
) -> tuple[int, dict[str, Any]]:
    """One request as the commands make it (token, marker header), ``headers`` on top
    (a value ``""`` leaves that header out)."""
    host, port = _address(server)
    conn = http.client.HTTPConnection(host, port, timeout=WAIT_S + 70)
    try:
        sent = {CONSOLE_HEADER: "1"}
        if token:
            sent["Authorization"] = f"Bearer {token}"
        sent.update(headers or {})
        conn.putrequest(method, path, skip_host="Host" in sent)
        for name, value in sent.items():
            if value:
                conn.putheader(name, value)
        conn.putheader("Content-Length", str(len(body or b"")))
        conn.endheaders(body)
        response = conn.getresponse()
        return response.status, json.loads(response.read() or b"{}")
    finally:
        conn.close()


def _until(condition: Callable[[], bool]) -> None:
    """Wait until ``condition()`` (checked every 20 ms), at most :data:`WAIT_S`."""
    deadline = time.monotonic() + WAIT_S
    while not condition():
        assert time.monotonic() < deadline, "the condition never came"
        time.sleep(0.02)


def _ready_diagnostics() -> DiagnosticArray:
    diag = LinkDiagnostics(
        state="ready", url="/dev/x", connected=True, missed_beats=0, lost_after_beats=None,
        heartbeat_losses=0, reconnects=0, reboots=0, rtt_ms=0.2, rtt_median_ms=0.2,
        heartbeat_age_s=0.01, rx_frames=10, tx_frames=10, crc_errors=0, resyncs=0,
        rx_dropped=0, rx_overflow=0, lost_frames=0, retries=0, no_ack_faults=0,
        stop_repeats=0, watchdog_trips=0, last_stop_latency_ms=None,
        last_stopping_distance_mm=None, controller_state="IDLE", stop_latched=False,
        estop_requested=False, faults=(), controller_queue=0, boot_nonce=1,
        firmware="1.0.0", schema_hash="", host_schema_hash="", steps_sent=0,
        steps_completed=0, steps_rejected=0, steps_aborted=0, rejected=(), last_error="",
    )  # fmt: skip
    return diagnostic_array(dataclasses.replace(diag), stamp(), statuses=["ready"])


def test_the_bind_policy_is_the_gates_and_a_token_is_always_made() -> None:
    with pytest.raises(ValueError, match=r"refusing to listen on '0\.0\.0\.0' without a token"):
        ConsoleConfig("0.0.0.0")
    with pytest.raises(ValueError, match="too weak"):  # the gate's policy (#43)
        ConsoleConfig("0.0.0.0", token="t")
    assert ConsoleConfig("0.0.0.0", token="k3Jf9-xQ2mPz8vLw").host == "0.0.0.0"
    with pytest.raises(ValueError, match="console port"):
        ConsoleConfig(port=70000)
    one, two = ConsoleConfig(), ConsoleConfig()
    assert len(one.token) >= 32 and one.token != two.token  # random, one per stack
    assert one.token not in repr(one)


# -- B1: STOP never waits ---------------------------------------------------------------------
def test_a_stop_is_published_and_answered_while_a_clear_stop_waits(
    served: tuple[ConsoleServer, Rover],
) -> None:
    """Four slow clear-STOPs (the controller silent: nobody answers them), then a STOP:
    the rover hears it and the STOP is answered while the one clear admitted still
    waits; the other three were refused at once (one clear-STOP at a time). Before, the
    four held the four threads that served STOP too, and the STOP went out when the
    first of them gave up (19.5 s after its request at timeout=20)."""
    server, rover = served
    rover.bridge_reports()
    with ThreadPoolExecutor(5) as pool:
        clears = [pool.submit(_raw, server, "POST", "/clear_stop?timeout=60") for _ in range(4)]
        # Each clear has reached the rover or been answered: the four are all in.
        _until(lambda: rover.clears + sum(c.done() for c in clears) >= 4)
        stop = pool.submit(_raw, server, "POST", "/stop?timeout=60")
        assert rover.stopped.wait(WAIT_S), "the STOP waited behind the clear-STOPs"
        waiting = [c for c in clears if not c.done()]
        assert len(waiting) == 1, "more than one clear-STOP admitted at a time"
        rover.say("stopped")
        assert stop.result(WAIT_S) == (200, {"stopped": True})
        assert not waiting[0].done()  # answered ahead of the clear that came first
        rover.say("cleared")  # the controller answers the clear at last
        code, doc = waiting[0].result(WAIT_S)
    assert code == 200 and doc["outcome"] in ("released", "not_latched"), doc
    refused = [c.result() for c in clears if c is not waiting[0]]
    assert [code for code, _ in refused] == [409, 409, 409], refused
    assert "one at a time" in refused[0][1]["error"]
    assert rover.clears == 1 and rover.stops[0] is True


def test_stops_waiting_for_their_answer_hold_nothing_back(
    served: tuple[ConsoleServer, Rover],
) -> None:
    """Eight STOPs pressed while the controller is silent each wait for ``stopped``;
    the status, a clear-STOP and one more STOP still go through at once, and every
    STOP is answered when ``stopped`` comes."""
    server, rover = served
    with ThreadPoolExecutor(12) as pool:
        stops = [pool.submit(_raw, server, "POST", "/stop?timeout=60") for _ in range(8)]
        assert rover.stopped.wait(WAIT_S)
        rover.bridge_reports()
        code, doc = _raw(server, "GET", "/status?timeout=30")
        assert code == 200 and doc["link_state"] == "ready", doc
        clear = pool.submit(_raw, server, "POST", "/clear_stop?timeout=60")
        assert rover.cleared.wait(WAIT_S), "the clear-STOP waited behind the STOPs"
        assert not any(s.done() for s in stops)
        rover.say("cleared")
        assert clear.result(WAIT_S)[0] == 200
        rover.say("stopped")
        answers = [s.result(WAIT_S) for s in stops]
    assert answers == [(200, {"stopped": True})] * 8
    assert all(rover.stops)


def test_closing_ends_every_wait(served: tuple[ConsoleServer, Rover]) -> None:
    """A STOP and a clear-STOP waiting on a silent controller end when the server
    closes (answered, not left hanging), and the clear's thread is joined."""
    server, rover = served
    rover.bridge_reports()
    with ThreadPoolExecutor(2) as pool:
        stop = pool.submit(_raw, server, "POST", "/stop?timeout=60")
        clear = pool.submit(_raw, server, "POST", "/clear_stop?timeout=60")
        assert rover.stopped.wait(WAIT_S) and rover.cleared.wait(WAIT_S)
        server.close()
        assert stop.result(WAIT_S)[0] == 503
        assert clear.result(WAIT_S)[0] == 200  # its outcome: no answer
    assert not any(t.name.startswith("console-clear") for t in threading.enumerate())


# -- B2: who the console answers ------------------------------------------------------------
def test_a_token_is_needed_and_bad_requests_get_an_answer(
    served: tuple[ConsoleServer, Rover],
) -> None:
    server, _ = served
    for token, why in ((None, "needs its stack's token"), ("no", "wrong token")):
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
    assert _raw(server, "POST", "/stop", body=b"x" * 2000)[0] == 413
    # Still serving, and every wait bounded: no bridge here, so no state and no 'stopped'.
    client = ConsoleClient(server.url, TOKEN)
    with pytest.raises(ConsoleRefusedError, match="no /diagnostics from the bridge") as late:
        client.status(0.3)
    assert late.value.status == 504
    assert client.stop(0.3) is False


def test_requests_a_web_page_could_make_are_refused_before_anything_is_done(
    served: tuple[ConsoleServer, Rover],
) -> None:
    """With the right token even: another Host (a DNS rebinding), an Origin, a
    cross-site Sec-Fetch-Site, a POST without the marker header (a form, a no-cors
    fetch); nothing is published. The commands' own requests pass, by either name of
    the loopback address, and a POST marked by its JSON content type instead."""
    server, rover = served
    _, port = _address(server)
    refused = [
        ("GET", "/status?timeout=1", {"Host": f"rebind.evil.example:{port}"}, 421),
        ("GET", "/echo?topic=command_status&count=1", {"Host": f"rebind.test:{port}"}, 421),
        ("POST", "/stop?timeout=1", {"Host": f"127.0.0.1:{port + 1}"}, 421),
        ("POST", "/stop?timeout=1", {"Host": "127.0.0.1"}, 421),
        ("POST", "/stop?timeout=1", {"Origin": "http://evil.example"}, 403),
        ("POST", "/clear_stop?timeout=1", {"Origin": "null"}, 403),
        ("POST", "/stop?timeout=1", {"Origin": f"http://127.0.0.1:{port}"}, 403),
        ("POST", "/stop?timeout=1", {"Sec-Fetch-Site": "cross-site"}, 403),
        ("GET", "/status?timeout=1", {"Sec-Fetch-Site": "same-site"}, 403),
        ("POST", "/stop?timeout=1", {CONSOLE_HEADER: "", "Content-Type": "text/plain"}, 403),
        ("POST", "/clear_stop?timeout=1", {CONSOLE_HEADER: ""}, 403),
        (
            "POST",
            "/clear_stop?timeout=1",
            {CONSOLE_HEADER: "", "Content-Type": "application/x-www-form-urlencoded"},
            403,
        ),
    ]
    for method, path, headers, status in refused:
        code, doc = _raw(server, method, path, headers=headers)
        assert code == status, (method, path, headers, code, doc)
    assert rover.stops == [] and rover.clears == 0 and server.stops_published == 0
    # The commands' own: by name, and marked by a JSON body instead of the header.
    rover.bridge_reports()
    assert _raw(server, "GET", "/status?timeout=30", headers={"Host": f"localhost:{port}"})[0] == (
        200
    )
    json_post = {CONSOLE_HEADER: "", "Content-Type": "application/json"}
    assert _raw(server, "POST", "/stop?timeout=0.3", headers=json_post, body=b"{}")[0] == 504
    assert rover.stopped.wait(WAIT_S) and server.stops_published >= 1


# -- B4: echo -------------------------------------------------------------------------------
def test_echo_streams_a_topic_with_its_last_value_first(
    served: tuple[ConsoleServer, Rover],
) -> None:
    server, rover = served
    client = ConsoleClient(server.url, TOKEN)
    rover.say("completed")  # said while nobody echoed
    assert HEARD.wait(5.0) and server.console.heard == ("completed",)
    lines = list(client.echo("command_status", 1, 5.0))
    assert lines[0] == {"listening": True}
    assert lines[1]["text"] == "completed" and lines[1]["last_known"] is True
    # A live topic: each message as it comes, its line as `rover echo` prints it.
    odom = rover.port.publisher("odom_ground", Odometry, qos.TELEMETRY)
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
    _until(lambda: server.echo_streams == 0)  # both streams ended, their slots back


def test_echo_slots_are_given_back_when_a_stream_fails(
    served: tuple[ConsoleServer, Rover],
) -> None:
    """A stream that fails before it starts (here: the console's port closed under
    it, so the topic cannot be subscribed) gives its slot back: the twelfth is refused
    for the same reason as the first, never 503 'already 8 echo streams'."""
    server, _ = served
    server.console.port.close()
    answers = [_raw(server, "GET", "/echo?topic=odom&count=1&timeout=1") for _ in range(12)]
    assert {code for code, _ in answers} == {500}, answers
    assert server.echo_streams == 0


def test_echo_slots_are_given_back_when_the_client_leaves(
    served: tuple[ConsoleServer, Rover],
) -> None:
    """Clients that leave at once, before or after their stream started, and clients
    that read to the end, leave no slot taken: eight streams open afterwards."""
    server, _ = served
    host, port = _address(server)
    request = (
        f"GET /echo?topic=odom&count=0&timeout=60 HTTP/1.1\r\nHost: {host}:{port}\r\n"
        f"Authorization: Bearer {TOKEN}\r\n\r\n"
    ).encode()
    for i in range(24):
        with socket.create_connection((host, port), timeout=WAIT_S) as sock:
            sock.sendall(request)
            if i % 2:
                assert sock.recv(1)  # the stream started
            sock.shutdown(socket.SHUT_RDWR)
    _until(lambda: server.echo_streams == 0)  # the server notices each departure
    opened: list[http.client.HTTPConnection] = []
    try:
        for _ in range(8):
            conn = http.client.HTTPConnection(host, port, timeout=WAIT_S)
            conn.request(
                "GET", "/echo?topic=odom&count=0", headers={"Authorization": f"Bearer {TOKEN}"}
            )
            response = conn.getresponse()
            assert response.status == 200 and response.readline() == b'{"listening":true}\n'
            opened.append(conn)
        assert server.echo_streams == 8
        assert _raw(server, "GET", "/echo?topic=odom&count=1")[0] == 503
    finally:
        for conn in opened:
            conn.close()


def test_a_console_that_is_not_there_is_unavailable() -> None:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        url = f"http://127.0.0.1:{probe.getsockname()[1]}"
    with pytest.raises(ConsoleUnavailableError, match="the stack's console at"):
        ConsoleClient(url).stop(1.0)
    with pytest.raises(ConsoleRefusedError, match="not a console URL"):
        ConsoleClient("ftp://x")


def test_clear_stop_says_when_an_armed_plan_starts_with_the_release(
    served: tuple[ConsoleServer, Rover],
) -> None:
    """Review A1: releasing the latch starts a plan that waits armed on board (after its
    guard's STOP, the ground re-planned); the answer says so."""
    from firmware_proto.model.downlink import OnboardReport

    server, side = served
    rover = side.port
    statuses = side.statuses
    reports = rover.publisher("onboard_report", String, qos.STATUS)
    armed = OnboardReport(7, "armed", 1.0, 42, "a" * 64, "armed", 0, 3, boot="b" * 32)
    reports.wait_for_subscribers(1, 5.0)
    statuses.wait_for_subscribers(1, 5.0)
    for _ in range(100):  # until the console has heard it
        reports.publish(String(data=armed.to_json()))
        if server.console.onboard is not None:
            break
        HEARD.wait(0.05)
    rover.subscribe(
        "clear_emergency_stop",
        Empty,
        lambda _msg: statuses.publish(String(data="cleared")),
        qos.STOP,
    )
    doc = ConsoleClient(server.url, TOKEN).clear_stop(5.0)
    assert doc["released"] and "plan 42 was armed on board" in doc["armed"]
