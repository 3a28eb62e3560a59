"""The ``inprocess`` backend: publish/subscribe between ports of one Python process.

Ports opened with the same ``bus`` name (default ``"default"``) see each other's topics,
as nodes of one ROS domain would: a publisher reaches the subscriptions on its bus with
the same fully qualified topic, the same message type and compatible QoS
(:func:`~bridge.ros.rosport.qos.compatible`). ``publish`` only queues: each subscription
keeps the last ``qos.depth`` messages (older ones dropped and counted in
``stats().dropped``), and each lane of a port delivers on its own thread.

**In lockstep** (``clock=`` a :class:`~firmware_proto.linkio.clock.LockstepClock`,
docs/sim.md) a port has no thread: on each tick of the clock it delivers what is queued,
the STOP lane's first, then the default lane's, in the order published, and what those
callbacks publish in turn, until nothing is left: within the tick, never inside
``publish``. Every subscription receives its own copy of the message, as after DDS.
"""

from __future__ import annotations

import importlib
import threading
from collections import deque
from typing import Any, Final

from bridge.ros.rosport.copying import copy_message
from bridge.ros.rosport.errors import RosPortError
from bridge.ros.rosport.port import (
    DEFAULT_NODE_NAME,
    LANES,
    STOP_LANE,
    Message,
    RosPort,
    Subscription,
)
from bridge.ros.rosport.qos import Qos, compatible
from firmware_proto.linkio.clock import WALL, Clock, LockstepClock

__all__ = ["DEFAULT_BUS", "LOCKSTEP_BURST", "InProcessPort"]

#: Bus used when ``open_port("inprocess")`` is given none.
DEFAULT_BUS: Final = "default"

#: In lockstep, more deliveries than this in one tick of one port: callbacks that publish
#: to each other for ever (an error, raised on the clock's thread).
LOCKSTEP_BURST: Final = 100_000


class _Slot:
    """One subscription's queue on the bus."""

    __slots__ = ("port", "queue", "sub")

    def __init__(self, port: InProcessPort, sub: Subscription[Message]) -> None:
        self.port = port
        self.sub = sub
        self.queue: deque[Message] = deque()


class _Bus:
    """Subscriptions and publishers by topic; shared by every port on one bus name."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.slots: dict[str, list[_Slot]] = {}
        self.writers: dict[str, list[_Writer]] = {}

    def add_writer(self, writer: _Writer) -> None:
        with self.lock:
            self.writers.setdefault(writer.topic, []).append(writer)

    def remove_writer(self, writer: _Writer) -> None:
        with self.lock:
            writers = self.writers.get(writer.topic, [])
            if writer in writers:
                writers.remove(writer)
            if not writers:
                self.writers.pop(writer.topic, None)

    def publishers_of(self, sub: Subscription[Message]) -> int:
        with self.lock:
            return sum(
                1
                for w in self.writers.get(sub.topic, ())
                if w.msg_type is sub.msg_type and compatible(w.qos, sub.qos)
            )

    def add(self, slot: _Slot) -> None:
        with self.lock:
            self.slots.setdefault(slot.sub.topic, []).append(slot)

    def remove(self, slot: _Slot) -> None:
        with self.lock:
            slots = self.slots.get(slot.sub.topic, [])
            if slot in slots:
                slots.remove(slot)
            if not slots:
                self.slots.pop(slot.sub.topic, None)

    def matching(self, topic: str, msg_type: type[Any], qos: Qos) -> list[_Slot]:
        with self.lock:
            return [
                s
                for s in self.slots.get(topic, ())
                if s.sub.msg_type is msg_type and compatible(qos, s.sub.qos)
            ]


_BUSES: dict[str, _Bus] = {}
_BUSES_LOCK = threading.Lock()


def _bus(name: str) -> _Bus:
    with _BUSES_LOCK:
        return _BUSES.setdefault(name, _Bus())


class _Writer:
    def __init__(self, port: InProcessPort, topic: str, msg_type: type[Any], qos: Qos) -> None:
        self._port = port
        self.topic = topic
        self.msg_type = msg_type
        self.qos = qos
        port._bus.add_writer(self)

    def write(self, msg: Message) -> None:
        cdr = None
        for slot in self._port._bus.matching(self.topic, self.msg_type, self.qos):
            if slot.sub.serialized:  # what DDS would hand it (serialized once per message)
                if cdr is None:
                    cdr = importlib.import_module("rclpy.serialization").serialize_message(msg)
                slot.port._enqueue(slot, cdr)
            else:
                slot.port._enqueue(slot, copy_message(msg))

    def matched_count(self) -> int:
        return len(self._port._bus.matching(self.topic, self.msg_type, self.qos))

    def close(self) -> None:
        self._port._bus.remove_writer(self)


class _Reader:
    def __init__(self, port: InProcessPort, slot: _Slot) -> None:
        self._port = port
        self._slot = slot

    def matched_count(self) -> int:
        return self._port._bus.publishers_of(self._slot.sub)

    def close(self) -> None:
        self._port._bus.remove(self._slot)
        with self._port._cond:
            self._slot.queue.clear()


class InProcessPort(RosPort):
    """A port on an in-process bus (``open_port("inprocess", bus=...)``).

    Args:
        namespace, node_name: see :class:`RosPort`.
        bus: name of the in-process bus to join; ports on one bus see each other.
        clock: the wall clock (lane threads), or a lockstep clock whose ticks deliver
            (see the module docstring).
    """

    backend = "inprocess"

    def __init__(
        self,
        *,
        namespace: str = "",
        node_name: str = DEFAULT_NODE_NAME,
        bus: str = DEFAULT_BUS,
        clock: Clock = WALL,
    ) -> None:
        super().__init__(namespace=namespace, node_name=node_name)
        self.bus_name = bus
        self._bus = _bus(bus)
        self._cond = threading.Condition()
        self._ready: dict[str, deque[_Slot]] = {lane: deque() for lane in LANES}
        self.clock = clock
        self._stepping: LockstepClock | None = None
        if isinstance(clock, LockstepClock):
            self._stepping = clock
            clock.add(self._deliver_ready)
        self._start()

    def _deliver_ready(self) -> None:
        """Lockstep: one tick's deliveries (see the module docstring)."""
        order = [STOP_LANE, *(lane for lane in LANES if lane != STOP_LANE)]
        for _ in range(LOCKSTEP_BURST):
            if self._stopping.is_set():
                return
            with self._cond:
                lane = next((name for name in order if self._ready[name]), None)
                if lane is None:
                    return
                slot = self._ready[lane].popleft()
                if not slot.queue:
                    continue
                msg = slot.queue.popleft()
            self._deliver(slot.sub, msg)
        raise RosPortError(
            f"{self!r}: more than {LOCKSTEP_BURST} deliveries in one tick (callbacks "
            "publishing to each other for ever?)"
        )

    def _release(self) -> None:
        if self._stepping is not None:
            self._stepping.remove(self._deliver_ready)

    def _open_writer(self, topic: str, msg_type: type[Any], qos: Qos) -> _Writer:
        return _Writer(self, topic, msg_type, qos)

    def _open_reader(self, sub: Subscription[Message]) -> _Reader:
        slot = _Slot(self, sub)
        self._bus.add(slot)
        return _Reader(self, slot)

    def _enqueue(self, slot: _Slot, msg: Message) -> None:
        """Queue ``msg`` for ``slot`` (called on the publisher's thread)."""
        dropped = False
        with self._cond:
            if self._stopping.is_set():
                return
            if len(slot.queue) >= slot.sub.qos.depth:
                # Keep-last: the oldest goes, and its ready mark now stands for this one,
                # so the ready queue never holds more marks than messages.
                slot.queue.popleft()
                dropped = True
            else:
                self._ready[slot.sub.lane].append(slot)
            slot.queue.append(msg)
            self._cond.notify_all()
        if dropped:
            self._count_dropped()

    def _run(self, lane: str) -> None:
        ready = self._ready[lane]
        while True:
            with self._cond:
                while not ready and not self._stopping.is_set():
                    self._cond.wait()
                if self._stopping.is_set():
                    return
                slot = ready.popleft()
                if not slot.queue:
                    # The subscription closed and its queue was cleared.
                    continue
                msg = slot.queue.popleft()
            self._deliver(slot.sub, msg)

    def _wake(self) -> None:
        with self._cond:
            self._cond.notify_all()
