"""STOP over real SocketCAN: STOP -> STOP_ACK (and -> STOPPED, -> wheels at zero) with
the bus idle, flooded with lower-priority frames, and flooded with malformed frames,
beside the raw vcan round trip measured in the same run.

Run where ``vcan0`` is up (on this machine: inside the micro-VM)::

    .ci/vcan-vm -- .venv/bin/python -m benchmarks.bench_socketcan [--trials N] [--quick]

``rover emulate --can socketcan:vcan0`` runs as a process of its own; the STOP bench
(:mod:`bridge.tools.stopbench`) drives it over python-can's ``socketcan`` interface:
per trial the motion queue is full and the rover moving, STOP comes at a seeded random
moment. Cases: *idle*, *flood* (PARAM_VALUE of another node, the lowest priority, from a
second socket) and *malformed* (wrong length, unknown id, extended id, RTR and error
frames, which the controller must ignore). The floor: a frame sent on one socket and
read back on another. vcan has no arbitration (a flood adds queueing, not contention),
and the VM's CPU may be emulated: compare the cases with each other and the floor, not
with bench_bridge's pty figures.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

import can

from benchmarks.common import summary, table
from bridge.tools.stopbench import BenchConfig, BenchRun, FloodConfig, StopBench

CHANNEL = "vcan0"
NODE = 1


def vcan_round_trip(samples: int) -> list[float]:
    """Seconds from a frame sent on one python-can socket to its arrival on another."""
    out: list[float] = []
    with (
        can.Bus(interface="socketcan", channel=CHANNEL) as tx,
        can.Bus(interface="socketcan", channel=CHANNEL, can_filters=[
            {"can_id": 0x7FE, "can_mask": 0x7FF}
        ]) as rx,
    ):  # fmt: skip
        frame = can.Message(arbitration_id=0x7FE, data=bytes(8), is_extended_id=False)
        for _ in range(samples):
            t0 = time.monotonic()
            tx.send(frame)
            got = rx.recv(timeout=1.0)
            if got is None:
                raise RuntimeError("vcan0 lost a frame of the round trip")
            out.append(time.monotonic() - t0)
    return out


def run_case(trials: int, seed: int, flood: FloodConfig | None, telemetry_hz: int) -> BenchRun:
    config = BenchConfig(
        url=f"can://socketcan/{CHANNEL}?node={NODE}",
        trials=trials,
        seed=seed,
        max_delay_s=0.1,
        telemetry_hz=telemetry_hz,
        flood=flood,
    )
    with StopBench(config) as bench:
        return bench.run()


def _ms(run: BenchRun, name: str) -> dict[str, float]:
    return summary([v / 1e3 for t in run.trials if (v := getattr(t, name)) is not None])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--trials", type=int, default=30, help="STOPs per case (default 30)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--flood-hz", type=float, default=1000.0, help="flood rate (1000)")
    parser.add_argument("--telemetry-hz", type=int, default=50, help="during the run (50)")
    parser.add_argument("--quick", action="store_true", help="3 trials per case (smoke test)")
    tcg = os.environ.get("ROVER_VCAN_VM_ACCEL") == "tcg"
    parser.add_argument(
        "--emulator-dt",
        type=float,
        default=0.004 if tcg else 0.001,
        help="the emulator's physics step, s (0.001; 0.004 on an emulated CPU, which cannot "
        "keep 1 kHz in real time)",
    )
    args = parser.parse_args()
    if not Path(f"/sys/class/net/{CHANNEL}").exists():
        print(f"no {CHANNEL} here: run it in .ci/vcan-vm (see --help)", file=sys.stderr)
        return 2
    trials = 3 if args.quick else args.trials
    emulator = subprocess.Popen(
        [sys.executable, "-m", "firmware_proto.cli", "emulate", "--can", f"socketcan:{CHANNEL}",
         "--node", str(NODE), "--seed", "1", "--dt", str(args.emulator_dt)],
        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
    )  # fmt: skip
    try:
        assert emulator.stdout is not None
        first = emulator.stdout.readline()
        if not first.startswith("CAN "):
            print(f"rover emulate did not start: {first!r}", file=sys.stderr)
            return 1
        floor = vcan_round_trip(50 if args.quick else 1000)
        cases = {
            "idle": None,
            "flood": FloodConfig("socketcan", CHANNEL, rate_hz=args.flood_hz),
            "malformed": FloodConfig("socketcan", CHANNEL, rate_hz=args.flood_hz, malformed=True),
        }
        runs = {
            name: run_case(trials, args.seed, flood, args.telemetry_hz)
            for name, flood in cases.items()
        }
    finally:
        emulator.terminate()
        emulator.wait(15)
        if emulator.stdout is not None:
            emulator.stdout.close()
    rows = [("vcan round trip (python-can, floor)", summary(floor))]
    for measure, label in (
        ("ack_ms", "STOP -> STOP_ACK"),
        ("stopped_ms", "STOP -> STOPPED"),
        ("zero_ms", "STOP -> wheels at zero"),
    ):
        for name, run in runs.items():
            rows.append((f"{label}, {name}", _ms(run, measure)))
    accel = os.environ.get("ROVER_VCAN_VM_ACCEL")
    cpu = {"kvm": "KVM", "tcg": "emulated (TCG)"}.get(accel or "", "this host's")
    note_lines = [
        f"{name}: {run.passed}/{len(run.trials)} trials passed every check; {run.load}"
        + (f"; flood sent {run.flood.sent} frames" if run.flood else "")
        for name, run in runs.items()
    ]
    print(
        table(
            f"STOP over SocketCAN {CHANNEL} ({trials} trials per case, seed {args.seed}, "
            f"telemetry {args.telemetry_hz} Hz, emulator step {args.emulator_dt * 1e3:g} ms; "
            f"CPU: {cpu})",
            rows,
            "\n".join(note_lines),
        )
    )
    return 0 if all(run.passed == len(run.trials) for run in runs.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
