"""Parallel clients on a process-pool gate; verdicts identical in any worker, thread or
process (bytes, apart from wall_time_s)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from firmware_proto.model.plan import Plan
from firmware_proto.model.rover import RoverDescription
from gate.options import ValidateOptions
from gate.server import GateServer
from gate.validator import Validator

from .client import Client, Reply, post_plan
from .conftest import thread_config
from .plans import fwd, heuristic, plan, step

CLIENTS = 16
WAIT_S = 60.0


@pytest.fixture(scope="module")
def process_gate() -> Iterator[GateServer]:
    """A gate with two worker processes (the default kind), shared by this module."""
    with GateServer(thread_config(pool="process", workers=2)) as gate:
        yield gate


def _plans(rover: RoverDescription) -> list[tuple[dict[str, Any], str]]:
    return [
        (heuristic(rover, (1.2, 3.0, 0.0), (2.5, 4.5, 90.0)), "map=lab"),
        (heuristic(rover, (1.2, 3.0, 0.0), (6.2, 3.0, 0.0)), "map=lab"),  # table
        (heuristic(rover, (1.0, 4.0, 0.0), (3.0, 2.0, -45.0)), "map=scn01"),
        (heuristic(rover, (1.0, 4.0, 0.0), (7.0, 4.2, 0.0)), "map=scn02"),
        (heuristic(rover, (1.0, 4.0, 0.0), (8.0, 4.2, 0.0)), "map=scn03&margin_m=0"),
        (plan((3.0, 3.0, 0.0), fwd(1.0)), "map=lab&render=1"),
        (plan((1.2, 3.0, 45.0), step("LEFT", 60, 30000)), "map=lab&sample_hz=50"),
        (plan((2.0, 2.0, 0.0), step("REV", 10, 5000)), "map=lab&start=3,2,0"),
    ]


def test_parallel_clients_get_the_serial_answers(
    process_gate: GateServer, rover: RoverDescription
) -> None:
    cases = _plans(rover)
    serial = []
    with Client(process_gate.address) as client:
        for body, query in cases:
            reply = client.post_plan(body, query)
            assert reply.status == 200
            serial.append(reply.without_wall_time())
    start = threading.Barrier(CLIENTS, timeout=WAIT_S)
    results: dict[int, Reply] = {}

    def client_thread(i: int) -> None:
        body, query = cases[i % len(cases)]
        with Client(process_gate.address) as client:
            start.wait()
            results[i] = client.post_plan(body, query)

    threads = [threading.Thread(target=client_thread, args=(i,)) for i in range(CLIENTS)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(WAIT_S)
    assert sorted(results) == list(range(CLIENTS))
    for i, reply in results.items():
        assert reply.status == 200, reply.body
        assert reply.without_wall_time() == serial[i % len(cases)], i
    # Every case twice, spread over both worker processes: same bytes each time.
    outcomes = [json.loads(s + b"}")["failure_type"] for s in serial]
    assert "collision" in outcomes and None in outcomes


def test_same_bytes_in_a_worker_process_a_thread_and_another_interpreter(
    process_gate: GateServer,
    validator: Validator,
    rover: RoverDescription,
    tmp_path: Path,
) -> None:
    body, query = heuristic(rover, (1.0, 4.0, 0.0), (8.0, 4.2, 0.0)), "map=scn03&margin_m=0"
    over_http = post_plan(process_gate.address, body, query)
    assert over_http.status == 200
    # In this process, through the same code path as a thread worker.
    options = ValidateOptions.from_query(query).resolve(validator.settings, "lab")
    in_thread = validator.validate(Plan.from_dict(body), options).to_json().encode()
    assert in_thread.rpartition(b',"wall_time_s":')[0] == over_http.without_wall_time()
    # A fresh interpreter with another hash seed: `rover gate check --json`.
    plan_file = tmp_path / "plan.json"
    plan_file.write_text(json.dumps(body))
    rover_exe = Path(sys.executable).with_name("rover")
    env = dict(os.environ, PYTHONHASHSEED="12345")
    done = subprocess.run(
        [
            str(rover_exe),
            "gate",
            "check",
            str(plan_file),
            "--map",
            "scn03",
            "--margin",
            "0",
            "--json",
        ],
        capture_output=True,
        timeout=WAIT_S,
        env=env,
        check=False,
    )
    assert done.returncode in (0, 1), done.stderr
    printed = done.stdout.strip()
    assert printed.rpartition(b',"wall_time_s":')[0] == over_http.without_wall_time()
