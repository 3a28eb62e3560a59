"""Replay a recorded session's controller side into a fresh bridge link and compare the
bridge's requests (docs/traffic-logs.md).

The counterpart of :mod:`emulator.emulator_replay`: a regression test of the host side.
:func:`replay_into_bridge` plays the controller on a new pty or a python-can bus to a
fresh :class:`~bridge.link.controllerlink.ControllerLink`, gives it the operator's inputs
recovered from the recorded host frames, and compares the link's requests with the
recorded ones; the timing and causality rules are docs/traffic-logs.md, "Into the
bridge". The log should come from a bridge (``rover bridge --record``).
"""

from __future__ import annotations

import logging
import threading
import time
from collections import Counter
from dataclasses import dataclass

from bridge.link.controllerlink import ControllerLink, LinkConfig, StepRequest
from bridge.link.transport import Transport, open_transport
from firmware_proto.linkio.can_endpoint import CanEndpoint
from firmware_proto.linkio.endpoint import CONTROLLER, Endpoint
from firmware_proto.linkio.replay_peer import ReplayPeer
from firmware_proto.linkio.serial_endpoint import PtyPort, SerialEndpoint
from firmware_proto.linkio.trafficio import LogFile
from firmware_proto.linkio.trafficlog import (
    CONTROLLER_TO_HOST,
    HOST_TO_CONTROLLER,
    Difference,
    counts_before,
    decode_records,
    diff_texts,
    log_node,
)
from firmware_proto.wire.message import Message
from firmware_proto.wire.messages import BROADCAST_NODE, DEFAULT_NODE, ClearStop, Motion, Stop

__all__ = ["BridgeReplayOptions", "BridgeReplayResult", "replay_into_bridge"]

logger = logging.getLogger(__name__)

_TAIL_S = 0.3
"""Wait after the last frame for the link's last requests, s."""


@dataclass(frozen=True)
class BridgeReplayOptions:
    """How to replay.

    Attributes:
        node: CAN node id (``None``: the node the log's host addressed).
        can_interface, can_channel: the python-can bus for a CAN log.
        gate_s: longest wait past a controller frame's recorded time for the requests
            that preceded it, s.
    """

    node: int | None = None
    can_interface: str = "virtual"
    can_channel: str = "rover-bridge-replay"
    gate_s: float = 0.1


@dataclass(frozen=True)
class BridgeReplayResult:
    """What a bridge replay found.

    Attributes:
        medium: ``"serial"`` or ``"can"``.
        inputs: operator inputs replayed (steps, stops, clears).
        played: controller frames played back.
        recorded_requests, replayed_requests: requests compared on each side.
        statuses: what the link reported on ``/command_status``, in order.
        differences: every difference; empty when the bridge asked alike.
        duration_s: wall time of the replay.
    """

    medium: str
    inputs: int
    played: int
    recorded_requests: int
    replayed_requests: int
    statuses: tuple[str, ...]
    differences: tuple[Difference, ...]
    duration_s: float

    @property
    def ok(self) -> bool:
        """The bridge sent the recorded requests."""
        return not self.differences

    def report(self) -> str:
        """A few lines for a terminal."""
        lines = [
            f"replayed {self.played} controller frames and {self.inputs} operator inputs "
            f"into a fresh bridge link over {self.medium} in {self.duration_s:.1f} s",
            f"requests compared: {self.recorded_requests} recorded, "
            f"{self.replayed_requests} replayed",
            f"/command_status: {', '.join(self.statuses) or 'nothing'}",
        ]
        if self.ok:
            lines.append("same requests")
        else:
            lines.append(f"{len(self.differences)} difference(s):")
            lines += [f"  {d}" for d in self.differences]
        return "\n".join(lines)


def _requests(messages: list[Message]) -> list[str]:
    """Host requests (no heartbeats), consecutive repeats counted once."""
    out: list[str] = []
    for message in messages:
        if message.DIRECTION != "host_to_controller" or message.PRIORITY == "telemetry":
            continue
        text = message.describe()
        if not out or out[-1] != text:
            out.append(text)
    return out


def _controller_peer(kind: str, opts: BridgeReplayOptions, node: int) -> ReplayPeer:
    """The controller's end for a ``kind`` log: a new pty, or node ``node`` on the bus;
    it counts the link's requests (everything but telemetry)."""
    endpoint: Endpoint = (
        SerialEndpoint(CONTROLLER, PtyPort)
        if kind == "serial"
        else CanEndpoint(CONTROLLER, opts.can_interface, opts.can_channel, node=node)
    )
    return ReplayPeer(endpoint, counted=lambda m: m.PRIORITY != "telemetry")


def _link_url(peer: ReplayPeer) -> str:
    """The URL a bridge link opens to reach ``peer`` (started)."""
    endpoint = peer.endpoint
    if isinstance(endpoint, CanEndpoint):
        return f"can://{endpoint.interface}/{endpoint.channel}?node={endpoint.node}"
    return endpoint.name


class _Processed:
    """Counts, by type, the controller answers the link has processed (its
    ``on_telemetry`` callback runs after each message is handled)."""

    def __init__(self) -> None:
        self._counts: Counter[str] = Counter()
        self._cond = threading.Condition()

    def __call__(self, message: Message, arrived: float) -> None:
        if message.PRIORITY == "telemetry":
            return
        with self._cond:
            self._counts[message.NAME] += 1
            self._cond.notify_all()

    def wait(self, need: Counter[str], deadline: float) -> bool:
        def reached() -> bool:
            return all(self._counts[name] >= n for name, n in need.items())

        with self._cond:
            return self._cond.wait_for(reached, max(0.0, deadline - time.monotonic()))


def _own_time(message: Message) -> bool:
    """Periodic controller telemetry, played on its recorded time alone (PROGRESS is not:
    it must not overtake the STATUS frames it sums up)."""
    return message.PRIORITY == "telemetry" and message.NAME != "PROGRESS"


def replay_into_bridge(
    log: LogFile, options: BridgeReplayOptions | None = None
) -> BridgeReplayResult:
    """Replay ``log``'s controller side into a fresh bridge link (module docstring).

    Raises:
        ValueError: the log holds no controller frame or no host request.
        OSError: the pty or bus cannot be opened.
    """
    opts = options or BridgeReplayOptions()
    decoded = decode_records(log.records)
    node = (opts.node or log_node(decoded)) if log.kind == "can" else None
    pairs = [
        (rec, d)
        for rec, d in zip(log.records, decoded, strict=False)
        if d.message is not None and (node is None or d.node in (node, BROADCAST_NODE))
    ]
    host = [(rec, d) for rec, d in pairs if d.direction == HOST_TO_CONTROLLER]
    ctrl = [(rec, d) for rec, d in pairs if d.direction == CONTROLLER_TO_HOST]
    recorded_requests = _requests([d.message for _, d in host if d.message is not None])
    if not ctrl or not recorded_requests:
        raise ValueError(f"{log.path}: needs controller frames and host requests to replay")
    t_first = min(host[0][0].time_s, ctrl[0][0].time_s)
    t_last = max(host[-1][0].time_s, ctrl[-1][0].time_s)

    # Operator inputs: the first appearance of each step, stop and clear.
    inputs: list[tuple[float, Message]] = []
    seen: set[tuple[str, int]] = set()
    for rec, d in host:
        m = d.message
        key = (
            ("MOTION", m.seq)
            if isinstance(m, Motion)
            else ("STOP", m.stop_id)
            if isinstance(m, Stop)
            else ("CLEAR", m.stop_id)
            if isinstance(m, ClearStop)
            else None
        )
        if key is not None and key not in seen:
            seen.add(key)
            inputs.append((rec.time_s, m))  # type: ignore[arg-type]

    # What the operator had seen before each input: answers by type.
    input_needs = counts_before(
        (
            (rec.time_s, d.message.NAME)
            for rec, d in ctrl
            if d.message is not None and d.message.PRIORITY != "telemetry"
        ),
        (t for t, _ in inputs),
    )

    # What the controller waited for before each of its frames: requests by type.
    # PROGRESS sums up the STATUS frames before it: it goes in their lane, in order.
    answers = [(rec, d) for rec, d in ctrl if d.message and not _own_time(d.message)]
    telemetry = [rec for rec, d in ctrl if d.message and _own_time(d.message)]
    needs = counts_before(
        (
            (rec.time_s, d.message.NAME)
            for rec, d in host
            if d.message is not None and d.message.PRIORITY != "telemetry"
        ),
        (rec.time_s for rec, _ in answers),
    )

    started = time.monotonic()
    statuses: list[str] = []
    controller = _controller_peer(log.kind, opts, node or DEFAULT_NODE)
    sent: list[Message] = []
    with controller:
        controller.start()
        t0 = time.monotonic()

        def factory(url: str) -> Transport:
            return open_transport(url)

        processed = _Processed()
        link = ControllerLink(
            LinkConfig(_link_url(controller), reconnect_min_s=0.01),
            on_status=statuses.append,
            on_telemetry=processed,
            transport_factory=factory,
            first_request_id=_first_request_id([d.message for _, d in host if d.message]),
        )
        beats = threading.Thread(
            target=controller.play_on_time,
            args=(telemetry, t0 - t_first),
            name="bridge-replay-telemetry",
            daemon=True,
        )
        operator = threading.Thread(
            target=_operate,
            args=(link,),
            kwargs={
                "inputs": inputs,
                "needs": input_needs,
                "processed": processed,
                "offset": t0 - t_first,
                "gate_s": opts.gate_s,
            },
            name="bridge-replay-operator",
        )
        with link:
            beats.start()
            operator.start()
            try:
                for (rec, _), need in zip(answers, needs, strict=True):
                    due = t0 + rec.time_s - t_first
                    delay = due - time.monotonic()
                    if delay > 0:
                        time.sleep(delay)  # replaying the recorded timing is the point
                    if need:
                        controller.wait_counts(need, due + opts.gate_s)
                    controller.play(rec)
            finally:
                operator.join()
                beats.join()
            end = t0 + (t_last - t_first) + _TAIL_S
            while (left := end - time.monotonic()) > 0:
                time.sleep(min(left, 0.05))
        sent = [m for _, m in controller.snapshot()]
    replayed_requests = _requests(sent)
    return BridgeReplayResult(
        medium=log.kind,
        inputs=len(inputs),
        played=len(answers) + len(telemetry),
        recorded_requests=len(recorded_requests),
        replayed_requests=len(replayed_requests),
        statuses=tuple(statuses),
        differences=tuple(diff_texts(recorded_requests, replayed_requests)),
        duration_s=time.monotonic() - started,
    )


def _first_request_id(requests: list[Message]) -> int | None:
    """The id the recorded bridge gave its first STOP or CLEAR_STOP (``None`` if it sent
    none): the fresh link starts its count there, so its requests match the recording."""
    for message in requests:
        if isinstance(message, (Stop, ClearStop)):
            return message.stop_id
    return None


def _operate(
    link: ControllerLink,
    *,
    inputs: list[tuple[float, Message]],
    needs: list[Counter[str]],
    processed: _Processed,
    offset: float,
    gate_s: float,
) -> None:
    """Give the link the operator's inputs at their recorded times, each once the link
    has handled the answers that came before it in the recording."""
    for (t, message), need in zip(inputs, needs, strict=True):
        due = t + offset
        delay = due - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        if need:
            processed.wait(need, due + gate_s)
        if isinstance(message, Motion):
            link.submit_step(StepRequest(message.command, message.speed, message.distance))
        elif isinstance(message, Stop):
            link.emergency_stop(message.source)
        elif isinstance(message, ClearStop):
            link.clear_stop()
