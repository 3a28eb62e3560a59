"""The parts of the stack as child processes: the gate, the emulator (or a real
device), the bridge, the onboard program and the link relay, started in order, each
ready when it prints its ready line (``GATE``, ``CONTROL``, ``BRIDGE``, ``ONBOARD``,
``LINK``), ended last started first.

:class:`Stack` is what ``rover stack up`` keeps running and ``rover demo`` starts; each
part is a :class:`ChildProcess` (``python -m firmware_proto.cli <command>``) with the
stack's environment. The stack's random uplink token (:attr:`Stack.uplink_token`) goes
to the onboard program through its environment only, never a command line. With a logs
directory, each part's stderr goes to ``<logs>/<name>.log`` and its stalls to
``<logs>/stalls.jsonl`` (docs/realtime.md); the gate and the relay run at nice
:data:`NICE`.
"""

from __future__ import annotations

import contextlib
import logging
import os
import secrets
import subprocess
import sys
import tempfile
import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType

from firmware_proto.model.uplink import TOKEN_ENV
from firmware_proto.runtime.parentwatch import pipe_for_child
from firmware_proto.runtime.stall import STALL_LOG_ENV
from planner.stack.controllers import pil_target_of

__all__ = ["NICE", "ChildProcess", "Endpoints", "Stack", "StackConfig"]

logger = logging.getLogger(__name__)

_STOP_TIMEOUT_S = 10.0
"""SIGTERM, then SIGKILL after this long."""
_STDERR_KEPT = 200
"""Lines of a part's stderr kept for its failure message."""
NICE = 5
"""Nice value of the gate and link relay, which need not keep time: emulator and bridge go first."""


class ChildProcess:
    """A ``rover`` subcommand as a child process, ready once a stdout line starts with
    ``ready``; its stdout lines are kept (and handed to ``on_line``), the tail of its
    stderr too.

    Raises:
        RuntimeError: it did not print its ready line within ``timeout_s`` (or exited
            first); the message ends with the tail of its stderr. It is stopped.
    """

    def __init__(
        self,
        name: str,
        args: list[str],
        ready: str,
        timeout_s: float,
        env: Mapping[str, str],
        on_line: Callable[[str, str], None] | None = None,
        log: Path | None = None,
    ) -> None:
        self.name = name
        self.args = args
        self.log = log
        """Where its stderr is kept whole (``None``: only its tail, in memory)."""
        # stdin is a pipe never written to: when this process ends, however it ends,
        # the part reads end-of-file and ends too (firmware_proto/runtime/parentwatch.py).
        read_fd, self._lifeline, watch_env = pipe_for_child()
        try:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "firmware_proto.cli", *args],
                stdin=read_fd,
                stdout=subprocess.PIPE,
                stderr=subprocess.PIPE,
                text=True,
                env={**env, **watch_env},
            )
        except BaseException:
            os.close(self._lifeline)
            raise
        finally:
            os.close(read_fd)
        self.lines: list[str] = []
        self._ready = threading.Event()
        self._stderr: list[str] = []
        self._ready_prefix = ready
        self._on_line = on_line
        self._reader = threading.Thread(target=self._read, name=f"part-{name}-out", daemon=True)
        self._reader.start()
        self._err_reader = threading.Thread(
            target=self._read_err, name=f"part-{name}-err", daemon=True
        )
        self._err_reader.start()
        try:
            came_up = self._ready.wait(timeout_s) and any(
                x.startswith(ready) for x in list(self.lines)
            )
        except BaseException:  # interrupted while waiting: no orphan child
            self.stop()
            raise
        if not came_up:
            exited = self.proc.poll()
            self.stop()
            tail = self.stderr_tail()
            what = f"exited with status {exited}" if exited is not None else "did not come up"
            raise RuntimeError(
                f"{name} {what} within {timeout_s:.0f} s" + (f": {tail}" if tail else "")
            )

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for raw in self.proc.stdout:
            line = raw.rstrip()
            self.lines.append(line)
            if line.startswith(self._ready_prefix):
                self._ready.set()
            if self._on_line is not None:
                try:
                    self._on_line(self.name, line)
                except Exception:
                    logger.exception("showing a line of %s failed", self.name)
        self._ready.set()  # end of output: no need to wait longer (checked by the caller)

    def _read_err(self) -> None:
        assert self.proc.stderr is not None
        with contextlib.ExitStack() as files:
            out = files.enter_context(self.log.open("a", encoding="utf-8")) if self.log else None
            for line in self.proc.stderr:
                if out is not None:
                    out.write(line)
                    out.flush()
                self._stderr.append(line)
                if len(self._stderr) > _STDERR_KEPT:
                    del self._stderr[: _STDERR_KEPT // 2]

    def stderr_tail(self, lines: int = 5) -> str:
        """The last lines of its stderr, joined."""
        return " | ".join(x.strip() for x in self._stderr[-lines:] if x.strip())

    def line(self, prefix: str) -> str:
        """The first stdout line starting with ``prefix`` (``RuntimeError``: there is none,
        the part exited before printing it)."""
        hit = next((x for x in self.lines if x.startswith(prefix)), None)
        if hit is None:
            raise RuntimeError(f"{self.name} exited before printing {prefix.strip()!r}")
        return hit

    @property
    def exit_status(self) -> int | None:
        """Its exit status once it has exited, else ``None``."""
        return self.proc.poll()

    def stop(self) -> None:
        """SIGTERM, then SIGKILL after 10 s; join the readers (idempotent)."""
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(_STOP_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)
        for reader in (self._reader, self._err_reader):
            reader.join(5)
        for stream in (self.proc.stdout, self.proc.stderr):
            if stream is not None:
                stream.close()
        if self._lifeline >= 0:
            os.close(self._lifeline)
            self._lifeline = -1


@dataclass(frozen=True)
class StackConfig:
    """What the stack runs.

    Attributes:
        map_name: the gate's default map and the emulator's world (name or JSON file).
        firmware: the emulator's controller, ``python`` or ``c``.
        controller: ``emulator``, or ``pil:TARGET`` (``microbit``, ``atmega2560``): the
            firmware in an emulated MCU, real time only (``speed`` 1).
        device: a real controller's serial device (or pyserial URL) the bridge opens
            instead of an emulator; ``None``: the emulator on a pty.
        baud: with ``device``, its baud rate (``None``: the bridge's default).
        rtt_s: the relay's round trip, s of mission time.
        jitter_s: the relay's jitter, s of mission time, uniform in ``[0, jitter_s]``
            added to each one-way delay.
        loss: the share of messages the relay drops, each way, in [0, 1).
        speed: mission seconds per wall second.
        seed: seeds the emulator and the relay.
        gate_port: the gate's port on 127.0.0.1 (0: a free one).
        ground_namespace: the relay's ground namespace (the operator's topics).
        startup_timeout_s: how long each part may take to print its ready line, s.
        inject: faults scheduled on the emulator from its start.
        realtime: the emulator and the bridge ask for real-time scheduling
            (docs/realtime.md).
        ground: the emulator's ground, unknown to the gate.
        twin: a calibrated twin the gate plays plans on.
        onboard: start ``rover onboard`` beside the bridge (docs/onboard.md).
    """

    map_name: str = "lab"
    firmware: str = "python"
    controller: str = "emulator"
    device: str | None = None
    baud: int | None = None
    rtt_s: float = 3.0
    jitter_s: float = 0.0
    loss: float = 0.0
    speed: float = 1.0
    seed: int = 1
    gate_port: int = 0
    ground_namespace: str = "ground"
    startup_timeout_s: float = 60.0
    inject: tuple[str, ...] = field(default=())
    realtime: bool = True
    ground: str | None = None
    twin: Path | None = None
    onboard: bool = True

    def link_line(self) -> str:
        """The link the relay emulates, in one line (mission seconds)."""
        jitter = f"jitter up to {self.jitter_s:g} s each way" if self.jitter_s else "no jitter"
        loss = f"{self.loss * 100:g} % of messages lost each way" if self.loss else "no loss"
        return f"link: round trip {self.rtt_s:g} s, {jitter}, {loss} (seed {self.seed})"


@dataclass(frozen=True)
class Endpoints:
    """Where the parts are: the gate's URL, the emulator's control ``HOST:PORT``
    (``""`` with a real device), the bridge's device."""

    gate_url: str
    control: str
    device: str


class Stack:
    """Starts the parts (:meth:`start`), tells whether one died (:meth:`failed`),
    stops them all (:meth:`close`, idempotent). A context manager.

    Args:
        env: the environment of every part (with its ROS 2 domain and discovery range).
        say: prints one line of progress.
        on_line: every stdout line of every part after its ready line, with the part's
            name.
        logs: a directory for each part's stderr and the stall log (``None``: none).
    """

    def __init__(
        self,
        config: StackConfig,
        env: Mapping[str, str],
        say: Callable[[str], None] = print,
        on_line: Callable[[str, str], None] | None = None,
        logs: Path | None = None,
    ) -> None:
        self.config = config
        self.logs = logs
        self._env = {k: v for k, v in env.items() if k != TOKEN_ENV}
        self.uplink_token = secrets.token_hex(32)
        """This stack's uplink token (random): the onboard program's environment holds
        it, the ground signs its plans with it."""
        if logs is not None:
            self._env[STALL_LOG_ENV] = str(logs / "stalls.jsonl")
        self._say = say
        self._on_line = on_line
        self.parts: list[ChildProcess] = []
        self._tmp = tempfile.TemporaryDirectory(prefix="rover-stack-")
        self._lock = threading.Lock()

    def _start(
        self, name: str, args: list[str], ready: str, env: Mapping[str, str] | None = None
    ) -> ChildProcess:
        self._say(f"starting {name}: rover {' '.join(args)}")
        part = ChildProcess(
            name,
            args,
            ready,
            self.config.startup_timeout_s,
            {**self._env, **(env or {})},
            self._forward,
            self.logs / f"{name}.log" if self.logs is not None else None,
        )
        with self._lock:
            self.parts.append(part)
        return part

    def _forward(self, name: str, line: str) -> None:
        if self._on_line is not None:
            self._on_line(name, line)

    def start(self) -> Endpoints:
        """Start the gate, the emulator (unless a device is given), the bridge and the
        relay, each once the one before is ready.

        Raises:
            RuntimeError: a part did not come up (what it said on stderr included).
            ValueError: ``speed`` not > 0 or ``rtt_s`` < 0.
        """
        cfg = self.config
        if cfg.speed <= 0 or cfg.rtt_s < 0 or cfg.jitter_s < 0:
            raise ValueError("speed must be > 0, rtt_s and jitter_s >= 0")
        if not 0.0 <= cfg.loss < 1.0:
            raise ValueError("loss must be in [0, 1)")
        pil_target = pil_target_of(cfg.controller)
        if pil_target is not None and cfg.device is None:
            if cfg.speed != 1.0:
                raise ValueError(
                    f"controller {cfg.controller} runs in real time only: speed must be 1"
                )
            if cfg.ground is not None:
                raise ValueError(f"controller {cfg.controller} drives on the description's ground")
        gate = self._start(
            "gate",
            [
                "gate",
                "--port",
                str(cfg.gate_port),
                "--map",
                cfg.map_name,
                "--workers",
                "1",
                "--pool",
                "thread",
                "--nice",
                str(NICE),
                *(["--twin", str(cfg.twin)] if cfg.twin is not None else []),
            ],
            "GATE ",
        )
        realtime = [] if cfg.realtime else ["--no-realtime"]
        url = gate.line("GATE ").split()[1]
        control = ""
        if cfg.device is None and pil_target is not None:
            device = str(Path(self._tmp.name) / "rover-motor")
            pil_args = [
                "pil",
                "--target",
                pil_target,
                "--link",
                device,
                "--map",
                cfg.map_name,
                "--seed",
                str(cfg.seed),
                "--control-port",
                "0",
                *realtime,
            ]
            for fault in cfg.inject:
                pil_args += ["--inject", fault]
            emulator = self._start("emulator", pil_args, "CONTROL ")
            control = emulator.line("CONTROL ").split()[1]
            bridge_args = ["bridge", "--device", device, *realtime]
        elif cfg.device is None:
            device = str(Path(self._tmp.name) / "rover-motor")
            emulator_args = [
                "emulate",
                "--serial",
                "--link",
                device,
                "--map",
                cfg.map_name,
                "--seed",
                str(cfg.seed),
                "--speed-factor",
                f"{cfg.speed:g}",
                "--control-port",
                "0",
                "--firmware",
                cfg.firmware,
                *realtime,
            ]
            if cfg.ground is not None:
                emulator_args += ["--ground", cfg.ground]
            for fault in cfg.inject:
                emulator_args += ["--inject", fault]
            emulator = self._start("emulator", emulator_args, "CONTROL ")
            control = emulator.line("CONTROL ").split()[1]
            bridge_args = ["bridge", "--device", device, *realtime]
        else:
            device = cfg.device
            bridge_args = ["bridge", "--device", device, *realtime]
            if cfg.baud is not None:
                bridge_args += ["--baud", str(cfg.baud)]
        self._start("bridge", bridge_args, "BRIDGE ")
        if cfg.onboard:
            self._start(
                "onboard",
                ["onboard", "--time-scale", f"{cfg.speed:g}", *realtime],
                "ONBOARD ",
                {TOKEN_ENV: self.uplink_token},
            )
        self._start(
            "link",
            [
                "link",
                "--rtt",
                f"{cfg.rtt_s / cfg.speed:g}",
                "--jitter",
                f"{cfg.jitter_s / cfg.speed:g}",
                "--loss",
                f"{cfg.loss:g}",
                "--seed",
                str(cfg.seed),
                "--ground-namespace",
                cfg.ground_namespace,
                "--nice",
                str(NICE),
            ],
            "LINK ",
        )
        return Endpoints(url, control, device)

    def failed(self) -> ChildProcess | None:
        """The first part that has exited, if any."""
        with self._lock:
            parts = list(self.parts)
        return next((p for p in parts if p.exit_status is not None), None)

    def close(self) -> None:
        """Stop every part, last started first (idempotent)."""
        while True:
            with self._lock:
                if not self.parts:
                    break
                part = self.parts.pop()
            part.stop()
        self._tmp.cleanup()

    def __enter__(self) -> Stack:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
