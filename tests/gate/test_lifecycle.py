"""Capacity and life cycle: overload gets 503, draining, graceful shutdown, connection
limit, a dead worker process replaced. Synchronised on events, never on sleeps."""

from __future__ import annotations

import os
import signal
import socket
import threading
from collections.abc import Callable, Iterator

import pytest

from gate.server import GateServer
from gate.validator import Validator

from .client import Client, Reply, call, post_plan
from .held import WAIT_S, HeldPool
from .plans import STOP_AT_LAB_START


@pytest.fixture
def held(validator: Validator) -> Iterator[HeldPool]:
    pool = HeldPool(validator)
    yield pool
    pool.release.set()
    pool.close()


def _post_in_thread(address: tuple[str, int]) -> tuple[threading.Thread, list[Reply]]:
    out: list[Reply] = []
    thread = threading.Thread(target=lambda: out.append(post_plan(address, STOP_AT_LAB_START)))
    thread.start()
    return thread, out


def test_overload_is_503_with_retry_after(
    make_gate: Callable[..., GateServer], held: HeldPool
) -> None:
    gate = make_gate(worker_pool=held, workers=1, queue_depth=0)
    thread, first = _post_in_thread(gate.address)
    assert held.entered.wait(WAIT_S)
    busy = post_plan(gate.address, STOP_AT_LAB_START)
    assert busy.status == 503
    assert busy.headers["retry-after"] == "1"
    assert busy.json()["error"] == "overloaded"
    health = call(gate.address, "GET", "/health").json()
    assert health["in_flight"] == 1
    # GETs do not need a worker: still served.
    assert call(gate.address, "GET", "/maps").status == 200
    held.release.set()
    thread.join(WAIT_S)
    assert first[0].status == 200
    assert post_plan(gate.address, STOP_AT_LAB_START).status == 200  # the slot is back


def test_queue_admits_up_to_its_depth(make_gate: Callable[..., GateServer], held: HeldPool) -> None:
    gate = make_gate(worker_pool=held, workers=1, queue_depth=2)
    threads = []
    results: list[list[Reply]] = []
    for _ in range(3):  # one running (held) + two queued
        t, out = _post_in_thread(gate.address)
        threads.append(t)
        results.append(out)
    assert held.wait_submitted(3)
    assert call(gate.address, "GET", "/health").json()["in_flight"] == 3
    assert post_plan(gate.address, STOP_AT_LAB_START).status == 503
    held.release.set()
    for t in threads:
        t.join(WAIT_S)
    assert [r[0].status for r in results] == [200, 200, 200]


def test_draining_answers_503_then_close_refuses_new_connections(
    make_gate: Callable[..., GateServer], held: HeldPool
) -> None:
    gate = make_gate(worker_pool=held, workers=1)
    address = gate.address
    thread, in_flight = _post_in_thread(address)
    assert held.entered.wait(WAIT_S)
    with Client(address) as idle:
        assert idle.request("GET", "/health").status == 200  # an idle keep-alive connection
        gate.begin_drain()
        draining = call(address, "GET", "/health")
        assert draining.status == 503
        assert draining.json()["error"] == "shutting_down"
        assert draining.headers["connection"] == "close"
        closer = threading.Thread(target=gate.close)
        closer.start()
        assert gate.stopped_accepting.wait(WAIT_S)
        with pytest.raises(ConnectionRefusedError):
            socket.create_connection(address, timeout=WAIT_S).close()
        # The idle connection was closed by the server.
        idle.conn.sock.settimeout(WAIT_S)
        assert idle.conn.sock.recv(1) == b""
        # The in-flight request still finishes, then the server stops.
        held.release.set()
        thread.join(WAIT_S)
        closer.join(WAIT_S)
    assert not closer.is_alive()
    assert in_flight[0].status == 200
    assert in_flight[0].headers["connection"] == "close"
    gate.close()  # idempotent


def test_connection_limit(make_gate: Callable[..., GateServer], held: HeldPool) -> None:
    """At the limit, a new connection takes the place of an idle one; with none idle
    (the one open is waiting for its verdict), it is answered 503."""
    gate = make_gate(max_connections=1, worker_pool=held, workers=1)
    with Client(gate.address) as first:
        assert first.request("GET", "/health").status == 200  # then idle
        assert call(gate.address, "GET", "/health").status == 200  # in its place
        assert first.conn.sock is not None
        first.conn.sock.settimeout(WAIT_S)
        assert first.conn.sock.recv(1) == b""  # closed by the server
    thread, busy = _post_in_thread(gate.address)
    assert held.entered.wait(WAIT_S)
    second = call(gate.address, "GET", "/health")
    assert second.status == 503
    assert second.json()["error"] == "too_many_connections"
    held.release.set()
    thread.join(WAIT_S)
    assert busy[0].status == 200


def test_a_dead_worker_process_is_replaced(make_gate: Callable[..., GateServer]) -> None:
    gate = make_gate(pool="process", workers=1)
    assert post_plan(gate.address, STOP_AT_LAB_START).status == 200
    (pid,) = gate.pool.pids  # type: ignore[attr-defined]
    os.kill(pid, signal.SIGKILL)
    reply = post_plan(gate.address, STOP_AT_LAB_START)
    assert reply.status == 200
    assert gate.pool.pids != [pid]  # type: ignore[attr-defined]
