"""A hardware-in-the-loop rig in one process, for tests and benchmarks.

The real parts, wired as on the rover and the ground: the emulator (controller model and
twin) served on a real pty, the bridge node on it, the link relay between the rover's
topics and the ground's, and the executor on the ground side. ROS topics go over real
ROS 2 (``backend="rclpy"``, one node per part, as between processes) or the in-process
port; the same wiring with each part in its own process is what ``rover demo`` runs.
"""

from __future__ import annotations

import itertools
import time
from types import TracebackType
from typing import Any

from bridge.ros.node import BridgeNode
from bridge.ros.params import load_params
from bridge.ros.rosport import RosPort, open_port
from emulator.controller import ControllerConfig, ControllerModel
from emulator.engine import Emulator
from emulator.injection import parse_fault
from emulator.serial_frontend import SerialFrontEnd
from emulator.twin import Twin, served_dt_s
from firmware_proto.model.rover import RoverDescription, load_rover
from firmware_proto.model.worldmap import load_map
from firmware_proto.runtime.realtime import BRIDGE_PRIORITY, EMULATOR_PRIORITY
from planner.ground.executor import ExecutorConfig, PlanExecutor
from planner.ground.relay import DEFAULT_ROUTES, LinkProfile, LinkRelay, RelayedTopic
from tests.scheduling import threads_at

__all__ = ["HilRig"]

_buses = itertools.count()

RIG_MAX_BACKLOG_S = 1.0
"""How far behind the wall clock the rig's emulator may fall and still run every tick it
owes (``rover emulate``: :data:`emulator.engine.MAX_BACKLOG_S`), s."""


class HilRig:
    """Emulator + bridge + relay + executor; close it (or use ``with``) to stop them all.

    Args:
        map_name: the emulator's map (its start pose is the rover's).
        speed: twin seconds per wall second; the link delay and the executor's timeouts
            scale with it.
        rtt_s: the link's round trip in mission seconds (wall: ``rtt_s / speed``).
        seed: seeds sensor noise, boot nonce and the link.
        faults: emulator faults (``slip:left=0.05``, ``...@t=3``) from the start.
        routes: the topics the link relays (default all: the rover's and the ground's).
        backend: the ROS port backend, ``rclpy`` (real ROS 2) or ``inprocess``.
        executor: overrides of the executor's settings.
    """

    def __init__(
        self,
        map_name: str = "lab",
        *,
        speed: float = 4.0,
        rtt_s: float = 0.4,
        seed: int = 5,
        faults: tuple[str, ...] = (),
        rover: RoverDescription | None = None,
        routes: tuple[RelayedTopic, ...] = DEFAULT_ROUTES,
        backend: str = "rclpy",
        **executor: Any,
    ) -> None:
        self.rover = rover or load_rover()
        self.world = load_map(map_name)
        self._stack: list[Any] = []
        try:
            model = ControllerModel(
                self.rover,
                Twin(self.rover, self.world, dt_s=served_dt_s(speed)),  # as `rover emulate`
                ControllerConfig(timeout_scale=speed),
                seed=seed,
            )
            # Its threads share this process's interpreter with the rig's ROS nodes, relay
            # and executor, which the machine may keep off the CPU while they hold it: the
            # loop then fell 107 ms behind and let twin time slip, and drift control,
            # which aligns the prediction on the wall clock, saw 0.28 m of false drift. Here
            # it catches up in a burst instead, up to a second behind.
            self.emulator = Emulator(
                model,
                SerialFrontEnd(seed=seed),
                speed_factor=speed,
                faults=[parse_fault(f) for f in faults],
                max_backlog_s=RIG_MAX_BACKLOG_S,
            )
            with threads_at(EMULATOR_PRIORITY):
                self.emulator.start()
            self._stack.append(self.emulator)
            front = self.emulator.frontend
            assert isinstance(front, SerialFrontEnd)
            options = {"bus": f"rig-{next(_buses)}"} if backend == "inprocess" else {}
            ports: list[RosPort] = []
            for name, namespace in (
                ("rover_bridge", ""),
                ("link_ground", "ground"),
                ("link_rover", ""),
                ("executor", "ground"),
            ):
                ports.append(open_port(backend, node_name=name, namespace=namespace, **options))
                self._stack.append(ports[-1])
            params = load_params({"device": front.device, "ros_backend": backend}, env={})
            with threads_at(BRIDGE_PRIORITY):
                self.bridge = BridgeNode(params, ports[0]).start()
            self._stack.append(self.bridge)
            self.relay = LinkRelay(
                ports[1],
                ports[2],
                LinkProfile(one_way_delay_s=rtt_s / speed / 2, seed=seed),
                routes,
            )
            self._stack.append(self.relay)
            config = ExecutorConfig(link_rtt_s=rtt_s / speed, time_scale=speed, **executor)
            self.executor = PlanExecutor(ports[3], self.rover, config)
            self._stack.append(self.executor)
            # Over DDS the parts discover each other first: wait until every hop matched.
            needed = {"wheel_instructions", "emergency_stop", "clear_emergency_stop"}
            needed.add("command_status")  # poses are periodic: a first one lost is harmless
            if not (self.executor.wait_for_rover() and self.relay.wait_until_matched(10.0, needed)):
                raise TimeoutError("the rig's ROS nodes did not discover each other in 10 s")
            deadline = time.monotonic() + 10.0
            while not self.bridge.link.ready:
                if time.monotonic() > deadline:
                    raise TimeoutError("the bridge did not reach the emulator")
                time.sleep(0.01)
        except BaseException:
            self.close()
            raise

    def close(self) -> None:
        """Stop everything, last started first (idempotent)."""
        while self._stack:
            self._stack.pop().close()

    def __enter__(self) -> HilRig:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
