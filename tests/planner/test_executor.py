"""The executor on the real rig (emulator on a pty, bridge node, link relay): plans that
end early for any reason leave the rover stopped and latched; progress during a step;
drift control that falls back to ``odom`` when POSE goes silent, and stops the rover when
it hears no pose at all."""

from __future__ import annotations

import _thread
import math
import signal
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

import pytest

from firmware_proto.model.plan import Plan
from firmware_proto.model.verdict import Verdict
from gate.server import GateServer
from planner.ground.executor import ExecutionProgress, ExecutorConfig
from planner.ground.relay import DEFAULT_ROUTES
from planner.plan.gate_client import GateClient
from tests.rig import HilRig

# Missions in real time on an in-process rig (emulator, bridge and relay threads in this
# worker): run after the rest, as the whole-mission tests are (marker serial: two at a
# time, never beside the host part's tests). Its emulator and bridge threads are
# real-time, but they share this process's interpreter lock with threads that are not:
# beside the host part's tests the bridge's heartbeats came 255 ms late (watchdog trips
# in 5 tests of one run).
pytestmark = pytest.mark.serial

SPEED = 4.0
RTT_S = 0.4  # mission seconds: 0.1 s wall
START = (1.2, 3.0)  # the lab map's start, facing +x

# 1.3 m straight ahead at half speed: about 9 s of mission time, 2.2 s wall.
LONG_STEP = {
    "goal": {"x": START[0] + 1.3, "y": START[1], "yaw_deg": 0.0},
    "commands": [{"command": "FWD", "speed": 30, "distance": 30000}],
}
TWO_STEPS = {
    "goal": {"x": START[0] + 1.5, "y": START[1], "yaw_deg": 0.0},
    "commands": [
        {"command": "FWD", "speed": 60, "distance": 23000},
        {"command": "FWD", "speed": 60, "distance": 11500},
    ],
}


@pytest.fixture
def hil() -> Iterator[Callable[..., HilRig]]:
    """Factory of rigs on the lab map; all closed after the test."""
    rigs: list[HilRig] = []

    def make(**kwargs: Any) -> HilRig:
        rigs.append(HilRig("lab", speed=SPEED, rtt_s=RTT_S, seed=5, **kwargs))
        return rigs[-1]

    yield make
    for rig in rigs:
        rig.close()


def validate(gate: GateServer, plan: dict[str, Any]) -> Verdict:
    with GateClient(gate.url) as client:
        verdict = client.validate(plan, map_name="lab")
    assert verdict.approved, verdict.summary()
    return verdict


def wait_until(pred: Callable[[], bool], what: str, timeout_s: float = 10.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not pred():
        if time.monotonic() > deadline:
            raise TimeoutError(what)
        time.sleep(0.01)


def assert_stopped_and_latched(h: HilRig) -> None:
    """The rover came to rest and holds its STOP latch."""
    wait_until(lambda: h.emulator.status().wheel_mps == (0.0, 0.0), "rover at rest")
    assert h.emulator.status().stop_latched


def moving(h: HilRig) -> bool:
    return any(abs(v) > 0.05 for v in h.emulator.status().wheel_mps)


# -- ending early: STOP whatever the cause -------------------------------------------------


def test_an_exception_from_on_progress_mid_step_stops_the_rover(
    gate: GateServer, hil: Callable[..., HilRig]
) -> None:
    verdict = validate(gate, LONG_STEP)
    h = hil(progress_period_s=0.1)

    def explode(p: ExecutionProgress) -> None:
        if p.status == "running" and moving(h):
            raise RuntimeError("the operator's display crashed")

    with pytest.raises(RuntimeError, match="display crashed"):
        h.executor.execute(Plan.from_dict(LONG_STEP), verdict, on_progress=explode)
    assert_stopped_and_latched(h)
    assert h.emulator.status().x_m < START[0] + 1.2  # stopped well before the step's end


@pytest.fixture
def ctrl_c_raises() -> Iterator[None]:
    """Python's own SIGINT handler for the test, whatever this process inherited.

    A process started in the background by a non-interactive shell (``cmd &`` in a
    script, as a CI runner or a load script may start the test command) inherits SIGINT
    ignored, and Python keeps it so; ``_thread.interrupt_main()`` then does nothing and
    the plan runs to its end (three loaded runs of the test command failed so).
    """
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


@pytest.mark.usefixtures("ctrl_c_raises")
def test_keyboard_interrupt_mid_step_stops_the_rover_then_propagates(
    gate: GateServer, hil: Callable[..., HilRig]
) -> None:
    verdict = validate(gate, LONG_STEP)
    h = hil(progress_period_s=0.1)
    rolling = threading.Event()

    times: dict[str, float] = {}

    def watch(p: ExecutionProgress) -> None:
        if p.status == "running" and moving(h):
            times.setdefault("rolling", time.monotonic())
            rolling.set()

    finished = threading.Event()

    def ctrl_c() -> None:
        if rolling.wait(10.0) and not finished.is_set():
            times["interrupt"] = time.monotonic()
            _thread.interrupt_main()  # SIGINT as the main thread sees it

    interrupter = threading.Thread(target=ctrl_c, name="ctrl-c")
    interrupter.start()
    ended = None
    try:
        try:
            result = h.executor.execute(Plan.from_dict(LONG_STEP), verdict, on_progress=watch)
            ended = f"{result.outcome}: {result.reason}"
            times["ended"] = time.monotonic()
        finally:
            finished.set()
            interrupter.join(10.0)  # an interrupt sent as the plan ended lands here, caught
    except KeyboardInterrupt:
        pass
    assert ended is None, f"the plan ended {ended}; times (monotonic s): {times}"
    assert_stopped_and_latched(h)


def test_cancel_from_another_thread_stops_the_rover(
    gate: GateServer, hil: Callable[..., HilRig]
) -> None:
    verdict = validate(gate, LONG_STEP)
    h = hil(progress_period_s=0.1)
    cancel = threading.Event()

    def watch(p: ExecutionProgress) -> None:
        if p.status == "running" and moving(h):
            threading.Thread(target=cancel.set, name="operator").start()

    result = h.executor.execute(
        Plan.from_dict(LONG_STEP), verdict, on_progress=watch, cancel=cancel
    )
    assert result.outcome == "cancelled" and result.reason == "cancelled by the operator"
    assert result.stopped_s is not None  # the rover confirmed the STOP
    assert_stopped_and_latched(h)


# -- progress during a step ----------------------------------------------------------------


def test_progress_arrives_while_a_long_step_runs(
    gate: GateServer, hil: Callable[..., HilRig]
) -> None:
    verdict = validate(gate, LONG_STEP)
    h = hil(progress_period_s=0.2)
    seen: list[ExecutionProgress] = []
    result = h.executor.execute(Plan.from_dict(LONG_STEP), verdict, on_progress=seen.append)
    assert result.completed, result.reason
    statuses = [p.status for p in seen]
    first_accepted = statuses.index("accepted")
    assert set(statuses[:first_accepted]) == {"published"}
    assert statuses[-1] == "completed" and seen[-1].final
    running = [p for p in seen if p.status == "running"]
    assert len(running) >= 3  # a 2.2 s step, a line every 0.2 s
    assert all(p.drift_linear_m is not None for p in running[1:])  # the ghost is compared
    etas = [p.eta_s for p in running]
    assert etas == sorted(etas, reverse=True)  # counting down
    assert seen[-1].eta_s == 0.0
    assert "step 1/1 running, ETA" in running[0].line(SPEED)


def test_a_step_is_never_said_running_before_the_rover_accepted_it(gate: GateServer) -> None:
    """A round trip longer than the progress period: until 'accepted' comes back, the
    step is only 'published' (it was said 'running' before 'accepted')."""
    verdict = validate(gate, LONG_STEP)
    rig = HilRig("lab", speed=SPEED, rtt_s=0.8 * SPEED, seed=5, progress_period_s=0.1)
    try:
        seen: list[ExecutionProgress] = []
        result = rig.executor.execute(Plan.from_dict(LONG_STEP), verdict, on_progress=seen.append)
    finally:
        rig.close()
    assert result.completed, result.reason
    statuses = [p.status for p in seen]
    first_accepted = statuses.index("accepted")
    assert first_accepted >= 3, statuses  # several progress lines during the round trip
    assert set(statuses[:first_accepted]) == {"published"}, statuses
    assert "running" in statuses[first_accepted:]


def test_a_fault_names_the_step_as_progress_numbers_it(
    gate: GateServer, hil: Callable[..., HilRig]
) -> None:
    """ExecutionProgress says 'step 2/2 fault:...'; the reason says the same step, not 'step 1'."""
    verdict = validate(gate, TWO_STEPS)
    h = hil(faults=("stall:left@d=1.2",), drift_control=False)
    seen: list[ExecutionProgress] = []
    result = h.executor.execute(Plan.from_dict(TWO_STEPS), verdict, on_progress=seen.append)
    assert not result.completed
    final = [p for p in seen if p.final and p.status != "completed"]
    assert final, [p.line() for p in seen]
    said = final[-1].line().split(",")[0].rsplit(" ", 1)[0]  # "step 2/2"
    assert result.reason.startswith(said + ": "), (said, result.reason)


# -- drift control's pose ------------------------------------------------------------------


def test_drift_control_falls_back_to_odom_when_pose_goes_silent(
    gate: GateServer, hil: Callable[..., HilRig]
) -> None:
    verdict = validate(gate, TWO_STEPS)
    # The ground-seeing sensor loses its fix half a metre into the first step.
    h = hil(faults=("pose-dropout@d=0.5",))
    assert h.executor.config.pose_source == "auto"
    result = h.executor.execute(Plan.from_dict(TWO_STEPS), verdict)
    assert result.completed, result.reason  # a lost sensor is not a reason to stop...
    assert h.executor.pose_source_in_use == "odom"
    assert any("fell back to odom" in note for note in result.notes), result.notes
    assert any("fault:pose" in note for note in result.notes), result.notes
    # ... and odom continued where POSE left off: at rest, it says where the rover is.
    assert result.reported_pose is not None
    truth = h.emulator.status()
    assert math.hypot(result.reported_pose.x - truth.x_m, result.reported_pose.y - truth.y_m) < 0.1


def test_drift_control_blind_without_pose_stops_the_rover(
    gate: GateServer, hil: Callable[..., HilRig]
) -> None:
    verdict = validate(gate, LONG_STEP)
    h = hil(pose_source="odom_ground", faults=("pose-dropout@d=0.2",))
    result = h.executor.execute(Plan.from_dict(LONG_STEP), verdict)
    assert result.outcome == "blind", result.reason
    assert result.reason.startswith("drift control blind: no pose from odom_ground")
    assert result.stopped_s is not None
    assert_stopped_and_latched(h)


def test_a_link_that_relays_no_pose_makes_drift_control_blind(
    gate: GateServer, hil: Callable[..., HilRig]
) -> None:
    verdict = validate(gate, LONG_STEP)
    no_pose = tuple(r for r in DEFAULT_ROUTES if r.topic not in ("odom", "odom_ground"))
    h = hil(routes=no_pose)
    result = h.executor.execute(Plan.from_dict(LONG_STEP), verdict)
    assert result.outcome == "blind", result.reason
    assert "no pose from odom_ground or odom" in result.reason
    assert result.stopped_s is not None
    assert_stopped_and_latched(h)


def test_blind_stop_is_off_without_drift_control(
    gate: GateServer, hil: Callable[..., HilRig]
) -> None:
    verdict = validate(gate, LONG_STEP)
    no_pose = tuple(r for r in DEFAULT_ROUTES if r.topic not in ("odom", "odom_ground"))
    h = hil(routes=no_pose, drift_control=False)
    result = h.executor.execute(Plan.from_dict(LONG_STEP), verdict)
    assert result.completed, result.reason


@pytest.mark.parametrize(
    ("overrides", "complaint"),
    [
        ({"pose_source": "gps"}, "pose_source"),
        ({"drift_linear_m": math.nan}, "drift_linear_m"),
        ({"drift_angular_deg": -1.0}, "drift_angular_deg"),
        ({"drift_persistence": 0}, "drift_persistence"),
        ({"pose_stale_s": 1.5}, "blind_margin_s must exceed pose_stale_s"),
        ({"link_rtt_s": math.inf}, "link_rtt_s"),
    ],
)
def test_executor_config_refuses_nonsense(overrides: dict[str, Any], complaint: str) -> None:
    with pytest.raises(ValueError, match=complaint):
        ExecutorConfig(**overrides)
