"""A whole mission in one process, in virtual time: :class:`World` (docs/sim.md,
"Whole missions in virtual time").

The parts are the product's own, each given one
:class:`~firmware_proto.linkio.clock.LockstepClock` instead of the wall clock, so none
of them starts a thread: the controller model or C core over a twin of the map (served
by :class:`~emulator.lockstep.LockstepController`), an in-memory serial line or a
python-can ``virtual`` bus, the bridge node and its link, four in-process ROS port nodes
on a bus of their own, the link relay, the ground's executor and mission runner. The
gate is a real HTTP server (one worker thread) on 127.0.0.1: a validation takes no
virtual time, as nothing on the clock runs while the executor waits for it.

One thread runs everything: the caller's. A wait of the executor advances the clock tick
by tick, and each tick runs, in this fixed order, the controller, the bridge's link, the
ROS ports (the rover's side first) with the relay between them, and the bridge's
diagnostics. Every random draw comes from generators seeded by :attr:`WorldConfig.seed`,
so a seed plays the same way on every run and machine (:meth:`World.digest`).
:attr:`WorldConfig.reproducer` is the one command line that plays a configuration again.
"""

from __future__ import annotations

import functools
import hashlib
import itertools
import logging
from dataclasses import dataclass, field, replace
from types import TracebackType
from typing import Any

from bridge.link.transport import Transport
from bridge.ros.node import BridgeNode
from bridge.ros.params import load_params
from bridge.ros.rosport import TAP_SENT, RosPort, open_port
from bridge.ros.rosport.copying import message_values
from emulator.controller import ControllerConfig, ControllerModel
from emulator.firmware import make_controller
from emulator.lockstep import MEDIA, LockstepController, lockstep_pair
from emulator.twin import GATE_DT_S, Twin
from firmware_proto.linkio.clock import LockstepClock
from firmware_proto.linkio.endpoint import Endpoint
from firmware_proto.model.rover import RoverDescription, load_rover
from firmware_proto.model.worldmap import WorldMap, load_map
from planner.ground.executor import ExecutorConfig, PlanExecutor
from planner.ground.relay import DEFAULT_ROUTES, LinkProfile, LinkRelay

__all__ = ["CONTROLLERS", "MEDIA", "Truth", "World", "WorldConfig"]

logger = logging.getLogger(__name__)

CONTROLLERS = ("python", "c")
"""The controllers a world can hold: the Python model or the C firmware core."""

_buses = itertools.count()

TELEMETRY_SETTLE_S = 0.5
"""Virtual s after the handshake and a round trip before a world is ready (POSE heard)."""


@dataclass(frozen=True)
class WorldConfig:
    """What a world is made of; every field is part of the reproducer.

    Attributes:
        map_name: the map the twin drives on (its start is the rover's).
        controller: ``python`` or ``c``.
        medium: ``serial`` (an in-memory line) or ``can`` (a python-can ``virtual`` bus).
        seed: seeds the controller's sensor noise and boot nonce and the relay.
        rtt_s: the link's round trip, s (3 s Earth-Moon).
        jitter_s: added to each one-way delay, uniform in ``[0, jitter_s]``, s.
        loss: the relay's loss ratio on every topic, in ``[0, 1)``.
        tick_s: the clock's tick and the controller's control period, s.
        executor: overrides of :class:`~planner.ground.executor.ExecutorConfig` (its
            ``link_rtt_s`` is ``rtt_s``), as ``(name, value)`` pairs.
        faults: controller faults from the start (``slip:both=0.1``; with a trigger,
            ``stall:left@d=1.2``, they wait for it), as ``rover emulate --fault``.
        unrelayed: topics the relay does not carry (``odom``, ``odom_ground``...): a link
            that loses them all.
        mission: the named mission of :mod:`sim.worldmissions` this world plays (for the
            reproducer; ``""`` when none).

    Raises:
        ValueError: an unknown controller or medium, or a value out of range.
    """

    map_name: str = "lab"
    controller: str = "python"
    medium: str = "serial"
    seed: int = 0
    rtt_s: float = 3.0
    jitter_s: float = 0.0
    loss: float = 0.0
    tick_s: float = GATE_DT_S
    executor: tuple[tuple[str, Any], ...] = ()
    faults: tuple[str, ...] = ()
    unrelayed: tuple[str, ...] = ()
    mission: str = ""

    def __post_init__(self) -> None:
        if self.controller not in CONTROLLERS:
            raise ValueError(
                f"unknown controller {self.controller!r}; known: {', '.join(CONTROLLERS)}"
            )
        if self.medium not in MEDIA:
            raise ValueError(f"unknown medium {self.medium!r}; known: {', '.join(MEDIA)}")
        if not 0.0 <= self.loss < 1.0:
            raise ValueError(f"loss must be in [0, 1), got {self.loss}")
        if not (self.rtt_s >= 0.0 and self.jitter_s >= 0.0 and self.tick_s > 0.0):
            raise ValueError("rtt_s and jitter_s must be >= 0 and tick_s > 0")

    @property
    def reproducer(self) -> str:
        """The command line that plays this world's mission again."""
        words = ["rover sim", f"--world {self.mission or '?'}", f"--seed {self.seed}"]
        words += [f"--controller {self.controller}", f"--medium {self.medium}"]
        if self.map_name != "lab":
            words.append(f"--map {self.map_name}")
        if self.rtt_s != 3.0:
            words.append(f"--rtt {self.rtt_s:g}")
        if self.jitter_s:
            words.append(f"--jitter {self.jitter_s:g}")
        if self.loss:
            words.append(f"--loss {self.loss:g}")
        if self.tick_s != GATE_DT_S:
            words.append(f"--tick-ms {self.tick_s * 1000:g}")
        words += [f"--fault {fault}" for fault in self.faults]
        words += [f"--unrelayed {topic}" for topic in self.unrelayed]
        words += [f"--executor {name}={value}" for name, value in self.executor]
        return " ".join(words)

    def with_(self, **changes: Any) -> WorldConfig:
        """A copy with ``changes``."""
        return replace(self, **changes)


@functools.cache
def _rover() -> RoverDescription:
    """The packaged rover description, read once per process (it is immutable)."""
    return load_rover()


@functools.cache
def _map(name: str) -> WorldMap:
    """A shipped map, read and validated once per process (it is immutable)."""
    return load_map(name)


@dataclass(frozen=True)
class Truth:
    """The controller's side of the world: where the twin is, how fast its wheels turn,
    whether its motion is latched (what an emulator's ``status`` reports)."""

    x_m: float
    y_m: float
    yaw_deg: float
    wheel_mps: tuple[float, float]
    stop_latched: bool
    latch: tuple[str, ...]


REST_MPS = 1e-3
"""Both wheels slower than this: at rest."""


@dataclass
class _Ledger:
    """What crossed the relay, in order, hashed with the virtual time it crossed at."""

    clock: LockstepClock
    hash: Any = field(default_factory=lambda: hashlib.blake2b(digest_size=12))
    count: int = 0

    def __call__(self, side: str, direction: str, topic: str, msg: Any) -> None:
        if direction != TAP_SENT:
            return  # what the relay forwards, once: as it is published on the far side
        self.count += 1
        self.hash.update(f"{self.clock.ticks}|{side}|{topic}|{message_values(msg)!r}\n".encode())


class World:
    """The parts of a mission on one lockstep clock (module docstring); closing it (or
    ``with``) closes every part."""

    def __init__(self, config: WorldConfig | None = None) -> None:
        """Build every part and connect the bridge to the controller in virtual time.

        Raises:
            ValueError: a bad configuration.
            FirmwareBuildError: the C core is asked for and cannot be built here.
            TimeoutError: the bridge did not reach the controller within 5 virtual s.
        """
        self.config = cfg = config or WorldConfig()
        self.rover: RoverDescription = _rover()
        self.map: WorldMap = _map(cfg.map_name)
        self.clock = LockstepClock(cfg.tick_s)
        self.gate: Any = None
        """The gate a mission plays against, when it owns one (:mod:`sim.worldmissions`)."""
        self._stack: list[Any] = []
        try:
            self._build(cfg)
        except BaseException:
            self.close()
            raise

    def _build(self, cfg: WorldConfig) -> None:
        clock = self.clock
        model = make_controller(
            cfg.controller,
            self.rover,
            Twin(self.rover, self.map, dt_s=cfg.tick_s),
            ControllerConfig(),
            seed=cfg.seed,
        )
        self.model: ControllerModel = model
        controller, host_end, _ = lockstep_pair(model, cfg.medium, clock=clock)
        self.controller: LockstepController = controller
        self._host_end: Endpoint = host_end
        controller.open()
        self._stack.append(controller)
        for fault in cfg.faults:
            controller.inject(fault)
        bus = f"world-{next(_buses)}"
        ports: dict[str, RosPort] = {}
        for name, namespace in (
            ("rover_bridge", ""),
            ("link_rover", ""),
            ("link_ground", "ground"),
            ("executor", "ground"),
        ):
            port = open_port("inprocess", node_name=name, namespace=namespace, bus=bus, clock=clock)
            ports[name] = port
            self._stack.append(port)
        self.ports = ports
        self.ledger = _Ledger(clock)
        ports["link_rover"].add_tap(lambda d, t, m: self.ledger("up", d, t, m))
        ports["link_ground"].add_tap(lambda d, t, m: self.ledger("down", d, t, m))
        # The link's URL names the world, not the medium's channel (a counter of the
        # process): it shows in /diagnostics, and a seed must play the same in any process.
        overrides: dict[str, Any] = {"ros_backend": "inprocess"}
        if cfg.medium == "can":
            overrides |= {"can_interface": "virtual", "can_channel": "world"}
        else:
            overrides["device"] = "memory://world"
        params = load_params(overrides, env={})
        self.bridge = BridgeNode(
            params,
            ports["rover_bridge"],
            rover=self.rover,
            clock=clock,
            transport_factory=self._transport,
        ).start()
        self._stack.append(self.bridge)
        self.relay = LinkRelay(
            ports["link_ground"],
            ports["link_rover"],
            LinkProfile(
                one_way_delay_s=cfg.rtt_s / 2.0,
                jitter_s=cfg.jitter_s,
                loss=cfg.loss,
                seed=cfg.seed,
            ),
            tuple(r for r in DEFAULT_ROUTES if r.topic not in cfg.unrelayed),
            clock=clock,
        )
        self._stack.append(self.relay)
        executor_config = ExecutorConfig(link_rtt_s=cfg.rtt_s, **dict(cfg.executor))
        self.executor = PlanExecutor(ports["executor"], self.rover, executor_config, clock=clock)
        self._stack.append(self.executor)
        if not self.run_until(lambda: self.bridge.link.ready, 5.0):
            raise TimeoutError("the bridge did not reach the controller in 5 virtual s")
        # The ground hears the rover's telemetry before it plans (else it takes the
        # silence for a lost POSE and falls back to odom).
        self.run_for(cfg.rtt_s + TELEMETRY_SETTLE_S)

    def _transport(self, url: str) -> Transport:
        """The bridge's transport: the host's end of the lockstep medium."""
        return Transport(url, self._host_end)

    # -- running -------------------------------------------------------------------------
    def run_until(self, ready: Any, timeout_s: float) -> bool:
        """Advance the clock until ``ready()`` or ``timeout_s`` virtual s; whether it came true."""
        deadline = self.clock.ticks + round(timeout_s / self.clock.dt_s)
        while not ready():
            if self.clock.ticks >= deadline:
                return False
            self.clock.advance()
        return True

    def run_for(self, seconds: float) -> None:
        """Advance the clock ``seconds`` of virtual time."""
        self.clock.sleep(seconds)

    @property
    def now_s(self) -> float:
        """Virtual seconds since the world was made."""
        return self.clock.now()

    def digest(self) -> str:
        """A hash of every message that crossed the relay, in order, with its tick: two
        runs of one configuration and mission give the same digest."""
        return f"{self.ledger.hash.hexdigest()}/{self.ledger.count}"

    def truth(self) -> Truth:
        """The controller's side now."""
        m = self.model
        pose = m.twin.pose
        return Truth(
            pose.x_m,
            pose.y_m,
            pose.yaw_deg,
            m.twin.wheel_surface_speeds_mps,
            m.stop_latched,
            tuple(sorted(str(c) for c in m.latch_causes)),
        )

    def at_rest(self) -> bool:
        """Both wheels stopped (:data:`REST_MPS`)."""
        return all(abs(v) < REST_MPS for v in self.model.twin.wheel_surface_speeds_mps)

    def inject(self, fault: str) -> dict[str, Any]:
        """Inject a controller fault now (``slip:both=0.1``, ``clear:slip``, ``reboot``...;
        docs/emulator.md), as a control port would; its answer.

        Raises:
            InjectionError: malformed or inapplicable (a link fault: cut the relay or
                close the controller instead).
        """
        return self.controller.inject(fault)

    def callback_errors(self) -> int:
        """Callbacks that raised on any port (each logged): a healthy world has none."""
        return sum(port.stats().callback_errors for port in self.ports.values())

    # -- lifecycle -----------------------------------------------------------------------
    def close(self) -> None:
        """Close every part, last built first (idempotent)."""
        while self._stack:
            part = self._stack.pop()
            try:
                part.close()
            except Exception:
                logger.exception("closing %r failed", part)

    def __enter__(self) -> World:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
