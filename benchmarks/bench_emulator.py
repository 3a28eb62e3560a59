"""The emulator: control-loop rate, CPU share serving in real time, STOP reaction and
stopping distance, beside the bare twin and the pty round trip measured in the same run.

Run: ``.venv/bin/python -m benchmarks.bench_emulator [--quick]``

- Rates: ticks/s of the controller model driving the twin in lockstep (firmware logic,
  one physics step, telemetry), beside the twin alone (benchmarks.bench_twin) at the
  emulator's default 1 ms step; the target is >= 50x real time on one core.
- CPU share: ``rover emulate --serial`` serving a host that heartbeats and drives, in
  real time, measured from the process's own CPU counters over a window.
- STOP reaction: STOP sent on the pty while the rover drives, from the frame's arrival
  (reader thread) to the wheel targets zeroed (control thread); the pty round trip is
  the floor.
- Stopping distance: the STOPPED report after STOP at full speed, beside v^2 / 2a.
  A trial during which the controller's watchdog fired (this process stalled past
  250 ms: beside load) is lost, its latch cleared, and run again; the count is printed.
"""

from __future__ import annotations

import argparse
import itertools
import random
import subprocess
import sys
import time

from benchmarks.bench_twin import twin_rate
from benchmarks.common import pty_round_trip, summary, table, tree_cpu_s
from emulator.controller import ControllerConfig, ControllerModel
from emulator.engine import Emulator
from emulator.serial_frontend import SerialFrontEnd
from emulator.twin import Twin
from firmware_proto.linkio.errors import NotReceivedError
from firmware_proto.linkio.host import ProtocolHost, Received
from firmware_proto.model.rover import RoverDescription, load_rover
from firmware_proto.wire.messages import (
    PROTOCOL_VERSION,
    SCHEMA_HASH,
    Ack,
    AckResult,
    ClearResult,
    Command,
    Fault,
    Hello,
    HostHeartbeat,
    Motion,
    Stop,
    Stopped,
    WheelSpeeds,
)
from tests.emulator.host import serial_host


def controller_rate(rover: RoverDescription, seconds: float) -> float:
    """Lockstep ticks/s of the controller model driving, with telemetry."""
    model = ControllerModel(rover, Twin(rover), ControllerConfig(), seed=1)
    model.boot()
    model.handle(Hello(PROTOCOL_VERSION, SCHEMA_HASH))
    model.handle(Motion(1, Command.FWD, 60, 30000))
    ticks = 0
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        for _ in range(100):
            model.tick()
        model.handle(HostHeartbeat(ticks & 0xFFFF))
        ticks += 100
    return ticks / (time.perf_counter() - t0)


def cpu_share(window_s: float) -> float:
    """Share of one core used by ``rover emulate --serial`` serving a driving host."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "firmware_proto.cli", "emulate", "--serial"],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )
    try:
        assert proc.stdout is not None
        device = proc.stdout.readline().split()[1]
        with serial_host(device) as host:
            host.handshake()
            for seq in range(1, 9):
                host.send(Motion(seq, Command.FWD if seq % 2 else Command.REV, 40, 30000))
            time.sleep(1.0)  # warm up
            c0, t0 = tree_cpu_s(proc.pid), time.monotonic()
            time.sleep(window_s)
            return (tree_cpu_s(proc.pid) - c0) / (time.monotonic() - t0)
    finally:
        proc.terminate()
        proc.communicate(timeout=10)


LOST_TRIALS_ALLOWED = 3
"""Trials the STOP bench may lose per trial kept before it gives up (see :func:`stop_trials`)."""


def _full_speed_or_latched(host: ProtocolHost, since: int) -> bool:
    """Wait (10 s at most) for full speed, or for the first sign the controller will not
    get there: a fault raised (its watchdog: this process stalled past 250 ms) or the
    MOTION refused. True at full speed."""

    def accept(item: Received) -> bool:
        m = item.message
        return (
            (isinstance(m, WheelSpeeds) and abs(m.left_mm_s) >= 299)
            or (isinstance(m, Fault) and bool(m.active))
            or (isinstance(m, Ack) and m.result not in (AckResult.ACCEPTED, AckResult.DUPLICATE))
        )

    found = host.inbox.wait(accept, since=since, timeout_s=host.scaled(10.0))
    return found is not None and isinstance(found[1].message, WheelSpeeds)


def _release(host: ProtocolHost, ids: itertools.count[int]) -> None:
    """Clear the controller's latch, naming its generation as last heard, until it says
    CLEARED or NOT_LATCHED (a clear naming an older generation is answered
    LATCH_CHANGED: the next one names the newer)."""
    for _ in range(5):
        try:
            ack = host.clear_stop(next(ids), every_s=0.05, timeout_s=2.0)
            if ack.result in (ClearResult.CLEARED, ClearResult.NOT_LATCHED):
                return
            host.heartbeat(timeout_s=2.0)  # its generation, for the next request
        except NotReceivedError:
            continue  # a stall again: a new request
    raise SystemExit("bench_emulator: the controller's latch did not clear in 5 requests")


def stop_trials(
    rover: RoverDescription, trials: int, rng: random.Random
) -> tuple[list[float], list[int], int]:
    """Emulator STOP reactions (s), stopping distances from full speed (mm), and the
    trials lost: a trial is lost, and run again, when the controller's watchdog fired
    during it (this process, the host, stalled past 250 ms: beside load) or an answer
    did not come within 10 s; its distance would not be the STOP's. More than
    :data:`LOST_TRIALS_ALLOWED` lost per trial kept ends the bench (SystemExit)."""
    model = ControllerModel(rover, Twin(rover), ControllerConfig(), seed=2)
    distances: list[int] = []
    lost = 0
    ids = itertools.count(1)
    with Emulator(model, SerialFrontEnd(seed=2)) as emu, serial_host(emu.frontend.device) as host:
        host.handshake()
        while len(distances) < trials:
            if lost > LOST_TRIALS_ALLOWED * (len(distances) + 1):
                raise SystemExit(
                    f"bench_emulator: {lost} STOP trials lost (the controller's watchdog fired "
                    f"or an answer did not come) against {len(distances)} kept"
                )
            n = next(ids)
            mark = host.mark()
            command = Command.FWD if len(distances) % 2 == 0 else Command.REV
            host.send(Motion(n & 0xFFFF, command, 60, 30000))
            stopped = None
            if _full_speed_or_latched(host, mark):
                time.sleep(rng.uniform(0.0, 0.2))
                at_stop = host.mark()
                host.send(Stop(n & 0xFFFF, 4))
                stopped = host.find(Stopped, since=at_stop, timeout_s=10)
            fired = host.find(Fault, lambda f: bool(f.active), since=mark, timeout_s=0.0)
            report = stopped[1].message if stopped is not None else None
            if isinstance(report, Stopped) and fired is None:
                distances.append(report.distance_mm)
            else:
                lost += 1
            _release(host, ids)
        reactions = list(emu.stop_reactions)
    return reactions, distances, lost


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--quick", action="store_true", help="shorter runs (smoke test)")
    args = parser.parse_args(argv)
    rover = load_rover()
    seconds, window, trials = (0.5, 1.0, 4) if args.quick else (3.0, 10.0, 100)

    twin = twin_rate(rover, 0.001, None)
    ctl = controller_rate(rover, seconds)
    print("Emulator rates at the default 1 ms step (one core, lockstep)\n")
    print("| case | steps/s | x real time |")
    print("|---|---:|---:|")
    print("| real time (the limit when serving) | 1,000 | 1 |")
    print(f"| twin alone (bench_twin) | {twin:,.0f} | {twin / 1000:,.0f} |")
    print(f"| controller model + twin + telemetry | {ctl:,.0f} | {ctl / 1000:,.0f} |")
    print("\nTarget: >= 50x real time at 1 kHz on one core.\n")

    share = cpu_share(window)
    print(
        f"CPU share serving a driving host in real time (rover emulate --serial, 1 kHz): {share * 100:.1f} % of one core\n"
    )

    rtt = pty_round_trip(2000)
    reactions, distances, lost = stop_trials(rover, trials, random.Random(1))
    print(
        table(
            "STOP reaction in the emulator",
            [
                ("pty round trip (15 B there and back, pyserial)", summary(rtt)),
                ("STOP frame arrival -> wheel targets zero", summary(reactions)),
            ],
            note="The reaction is measured inside the emulator (reader thread timestamp to control thread).",
        )
    )
    v = rover.max_speed_mps
    ideal_mm = v * v / (2 * rover.drive.wheel_accel_limit_mps2) * 1000
    distances.sort()
    print(
        f"\nStopping distance from full speed ({v:.2f} m/s, {rover.drive.wheel_accel_limit_mps2} m/s^2): "
        f"p50 {distances[len(distances) // 2]} mm, max {distances[-1]} mm "
        f"(wheel travel; v^2/2a = {ideal_mm:.0f} mm; n = {len(distances)})"
    )
    print(
        f"Trials lost and run again (the controller's watchdog fired: this process stalled "
        f"past 250 ms; or no answer within 10 s): {lost}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
