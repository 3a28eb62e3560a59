"""A hardware-in-the-loop rig in one process, for tests and benchmarks.

The real parts, wired as on the rover and the ground: the emulator (controller model and
twin) served on a real pty, the bridge node on it, the link relay between the rover's
topics and the ground's, and the executor on the ground side. ROS topics use the
in-process port backend (nodes in one process); the same wiring over Cyclone DDS between
processes is what ``rover demo`` runs.
"""

from __future__ import annotations

import itertools
import time
from types import TracebackType
from typing import Any

from bridge.node import BridgeNode
from bridge.params import load_params
from bridge.rosport import RosPort, open_port
from emulator.controller import ControllerConfig, ControllerModel
from emulator.engine import Emulator
from emulator.injection import parse_fault
from emulator.serial_frontend import SerialFrontEnd
from emulator.twin import Twin
from emulator.worldmap import load_map
from firmware_proto.rover import RoverDescription, load_rover
from planner.executor import ExecutorConfig, PlanExecutor
from planner.relay import DEFAULT_ROUTES, LinkProfile, LinkRelay, Route

__all__ = ["HilRig"]

_buses = itertools.count()


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
        routes: tuple[Route, ...] = DEFAULT_ROUTES,
        **executor: Any,
    ) -> None:
        self.rover = rover or load_rover()
        self.world = load_map(map_name)
        self._stack: list[Any] = []
        try:
            model = ControllerModel(
                self.rover,
                Twin(self.rover, self.world),
                ControllerConfig(timeout_scale=speed),
                seed=seed,
            )
            self.emulator = Emulator(
                model,
                SerialFrontEnd(seed=seed),
                speed_factor=speed,
                faults=[parse_fault(f) for f in faults],
            )
            self.emulator.start()
            self._stack.append(self.emulator)
            front = self.emulator.frontend
            assert isinstance(front, SerialFrontEnd)
            bus = f"rig-{next(_buses)}"
            ports: list[RosPort] = [
                open_port("inprocess", node_name="rover_bridge", bus=bus),
                open_port("inprocess", node_name="link_ground", namespace="ground", bus=bus),
                open_port("inprocess", node_name="link_rover", bus=bus),
                open_port("inprocess", node_name="executor", namespace="ground", bus=bus),
            ]
            self._stack.extend(ports)
            params = load_params({"device": front.device, "ros_backend": "inprocess"}, env={})
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
