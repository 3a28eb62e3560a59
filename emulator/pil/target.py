"""A processor-in-the-loop target: the firmware image running in an emulated MCU, served
as ``rover emulate`` serves a controller (a device path and the same control port).

:class:`PilTarget` checks faults, keeps the injection log and answers ``status`` from
the image's ``pil_view`` and ``pil_stats``. A target fills :meth:`_start_emulator`,
:meth:`_apply`, :meth:`_read_port` and :meth:`_close_emulator`, and may override
:meth:`_check`. :meth:`inject` and :meth:`status` may be called from any thread; a lock
serialises them.
"""

from __future__ import annotations

import logging
import threading
import time
from abc import ABC, abstractmethod
from collections.abc import Callable
from pathlib import Path
from types import TracebackType

from emulator.engine import EmulatorStatus
from emulator.errors import InjectionError
from emulator.injection import FaultSpec, InjectionRecord, ScheduledFault, parse_fault
from emulator.pil.errors import PilError
from emulator.pil.images import Image
from emulator.pil.view import PilStats, PortView
from firmware_proto.wire.messages import FaultCode

__all__ = ["PilTarget"]

logger = logging.getLogger(__name__)


class PilTarget(ABC):
    """One emulated MCU running one image, with its device and control hooks.

    Args:
        image: the built image (:func:`emulator.pil.images.build_image`).
        link: a symlink to create to the device (``None``: none).
        realtime_priority: the emulator's real-time priority (0: none); where refused,
            :attr:`realtime_note` says so.
        seed: seeds whatever the target draws at random (the twin's sensor noise).
        say: one line of progress (stderr in ``rover pil``).
    """

    name = "target"
    """The target's name (``emulator.pil.registry.TARGETS``)."""
    plant_name = "plant"
    """What the plant is, in words, for the ``PLANT`` line."""

    def __init__(
        self,
        image: Image,
        *,
        link: Path | None = None,
        realtime_priority: int = 0,
        seed: int = 1,
        say: Callable[[str], None] | None = None,
    ) -> None:
        self.image = image
        self.link = link
        self.realtime_priority = realtime_priority
        self.seed = seed
        self.device = ""
        self.realtime_note = ""
        self.frontend = None
        self._say = say or (lambda line: None)
        self._lock = threading.Lock()
        self._log: list[InjectionRecord] = []
        self._in_force: dict[tuple[str, str | None], FaultSpec] = {}
        self._started = 0.0
        self._closed = False
        self._pending: list[tuple[FaultSpec, str]] = []
        self._scheduler: threading.Thread | None = None
        self._stopping = threading.Event()

    # -- lifecycle ---------------------------------------------------------------------------
    def start(self) -> PilTarget:
        """Start the emulator; :attr:`device` is the controller's device once it returns.

        Raises:
            PilError: the emulator did not come up (what it said included).
        """
        self._started = time.monotonic()
        try:
            self._start_emulator()
        except BaseException:
            self.close()
            raise
        if self.link is not None:
            self.link.unlink(missing_ok=True)
            self.link.symlink_to(self.device)
        return self

    def close(self) -> None:
        """End the emulator and everything it started; remove the link (idempotent)."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
        self._stopping.set()
        if self._scheduler is not None:
            self._scheduler.join(5)
        try:
            self._close_emulator()
        finally:
            if self.link is not None and self.link.is_symlink():
                self.link.unlink(missing_ok=True)

    def __enter__(self) -> PilTarget:
        return self.start()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    @abstractmethod
    def _start_emulator(self) -> None:
        """Start the emulator and set :attr:`device`."""

    @abstractmethod
    def _close_emulator(self) -> None:
        """End the emulator and every process and thread it started."""

    @abstractmethod
    def alive(self) -> bool:
        """Whether the emulator still runs."""

    # -- faults ------------------------------------------------------------------------------
    @property
    def injections(self) -> list[InjectionRecord]:
        """Every injection applied so far."""
        with self._lock:
            return list(self._log)

    def inject(
        self, fault: str | FaultSpec, source: str = "api"
    ) -> InjectionRecord | ScheduledFault:
        """Apply a fault now, or keep it until its ``@t=`` (target time) or ``@d=``
        (ground travel) trigger is met.

        Raises:
            InjectionError: malformed, not applicable here, or ``@region=``.
        """
        spec = parse_fault(fault) if isinstance(fault, str) else fault
        if spec.trigger.region is not None:
            raise InjectionError(
                f"{spec}: a PIL target has no map regions; use @t= or @d= (or rover emulate)"
            )
        self._check(spec)
        if not spec.trigger.immediate:
            return self._schedule(spec, source)
        return self._apply_now(spec, source)

    def _apply_now(self, spec: FaultSpec, source: str) -> InjectionRecord:
        with self._lock:
            if self._closed:
                raise PilError("the PIL target is closed")
            self._apply(spec)
            self._remember(spec)
            record = InjectionRecord(self.time_s(), str(spec), source)
            self._log.append(record)
        self._settle(spec)
        logger.warning("%s", record.line())
        self._say(record.line())
        return record

    # -- triggers ----------------------------------------------------------------------------
    def ground_travel_m(self) -> float:
        """Ground travel since the target started, m (``@d=``); default: in-image odometer."""
        with self._lock:
            return self._read_port()[0].travel_mm / 1000.0

    def _schedule(self, spec: FaultSpec, source: str) -> ScheduledFault:
        """Keep a triggered fault; a thread applies it once met (polled every 5 ms, wall)."""
        trig = spec.trigger
        value = (
            f" (now {self.ground_travel_m():.3f} m)"
            if trig.after_m is not None
            else f" (now t={self.time_s():.3f} s)"
        )
        with self._lock:
            if self._closed:
                raise PilError("the PIL target is closed")
            self._pending.append((spec, source))
            if self._scheduler is None:
                self._scheduler = threading.Thread(
                    target=self._run_schedule, name="pil-schedule", daemon=True
                )
                self._scheduler.start()
        logger.info("scheduled %s (%s)", spec, source)
        return ScheduledFault(str(spec), round(self.time_s(), 6), trig.describe() + value)

    def _run_schedule(self) -> None:
        while not self._stopping.wait(0.005):
            with self._lock:
                pending = list(self._pending)
            if not pending:
                continue
            travel = self.ground_travel_m()
            now = self.time_s()
            for item in pending:
                trig = item[0].trigger
                due = (trig.at_s is not None and now >= trig.at_s) or (
                    trig.after_m is not None and travel >= trig.after_m
                )
                if not due:
                    continue
                with self._lock:
                    if item not in self._pending:
                        continue
                    self._pending.remove(item)
                try:
                    self._apply_now(item[0], "schedule")
                except (PilError, InjectionError) as exc:
                    logger.warning("scheduled %s failed: %s", item[0], exc)

    def _remember(self, spec: FaultSpec) -> None:
        if spec.kind == "reboot":
            return
        if spec.kind == "clear":
            for key in [k for k in self._in_force if k[0] == spec.target]:
                if spec.side in (None, "both") or key[1] in (spec.side, "both"):
                    del self._in_force[key]
            return
        neutral = spec.kind == "slip" and spec.value == 1.0
        key = (spec.kind, spec.side)
        if neutral:
            self._in_force.pop(key, None)
        else:
            self._in_force[key] = spec

    def _check(self, spec: FaultSpec) -> None:
        """Refuse a fault this target cannot apply (raise InjectionError)."""
        kind = spec.target if spec.kind == "clear" else spec.kind
        if kind not in ("reboot", "stall", "encoder-dropout", "slip"):
            raise InjectionError(
                f"{spec} cannot apply on the {self.name} image: it takes reboot, stall, "
                "encoder-dropout and slip (and clear: of them)"
            )
        if spec.kind == "slip" and spec.value is not None and not 0.0 < spec.value <= 1.0:
            raise InjectionError(f"{spec}: slip scale must be in (0, 1]")

    def _settle(self, spec: FaultSpec) -> None:
        """Return once the firmware's ENCODER fault bit follows an encoder dropout or its
        end, as the emulator's ``inject`` returns once the controller has acted.

        Raises:
            PilError: the firmware did not follow within 2 s of wall time.
        """
        kind = spec.target if spec.kind == "clear" else spec.kind
        if kind != "encoder-dropout":
            return
        want = any(key[0] == "encoder-dropout" for key in self._in_force)
        bit = 1 << (FaultCode.ENCODER.value - 1)
        deadline = time.monotonic() + 2.0
        while time.monotonic() < deadline:
            with self._lock:
                view, _stats = self._read_port()
            if bool(view.faults & bit) == want:
                return
            time.sleep(0.001)
        raise PilError(f"the firmware did not follow {spec} within 2 s")

    @abstractmethod
    def _apply(self, spec: FaultSpec) -> None:
        """Put one checked fault into effect (called under the lock)."""

    # -- status ------------------------------------------------------------------------------
    @abstractmethod
    def _read_port(self) -> tuple[PortView, PilStats]:
        """The image's ``pil_view`` and ``pil_stats`` now."""

    def time_s(self) -> float:
        """Seconds since the emulator started (wall; lockstep targets: twin time)."""
        return time.monotonic() - self._started

    def pose(self, view: PortView) -> tuple[float, float, float]:
        """Ground truth, m, m, deg: the in-image plant's by default."""
        return view.x_mm / 1000.0, view.y_mm / 1000.0, view.yaw_ddeg / 10.0

    def port_stats(self) -> PilStats:
        """The image's counters now."""
        with self._lock:
            return self._read_port()[1]

    def status(self) -> EmulatorStatus:
        """The control port's ``status``, from the image's view of itself."""
        with self._lock:
            if self._closed:
                raise PilError("the PIL target is closed")
            view, stats = self._read_port()
            injected = tuple(sorted(str(s) for s in self._in_force.values()))
        x, y, yaw = self.pose(view)
        sign = (-1, 1)
        return EmulatorStatus(
            time_s=round(self.time_s(), 6),
            state=view.state_name,
            x_m=x,
            y_m=y,
            yaw_deg=yaw,
            wheel_mps=(
                sign[0] * view.speed_um_s[0] / 1e6,
                sign[1] * view.speed_um_s[1] / 1e6,
            ),
            setpoints_mps=(view.commanded_um_s[0] / 1e6, view.commanded_um_s[1] / 1e6),
            queue_depth=view.queue_depth,
            stop_latched=view.latch != 0,
            faults=view.fault_names,
            boot_nonce=view.boot_nonce,
            device=self.device,
            rx_frames=0,
            rx_errors=view.rx_errors,
            tx_frames=0,
            tx_dropped=stats.tx_drops,
            overruns=stats.late_ticks,
            collision=None,
            injected=injected,
            latch=view.latch_names,
            catchups=stats.late_ticks,
        )
