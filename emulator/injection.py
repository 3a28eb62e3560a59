"""Fault injection: what can go wrong, when, and applying it to the emulator.

A fault is written ``KIND[:SIDE][=VALUE][@TRIGGER]`` (``slip:left=0.3@t=5``,
``clear:stall:right``), kinds in :data:`FAULT_KINDS`, triggers ``@t=`` (twin time, s),
``@d=`` (ground travel, m) or ``@region=`` (a map traction region); docs/emulator.md,
"Fault injection", has the table and what is refused.

:func:`parse_fault` checks the text, :meth:`Injector.check` whether it can apply here,
:meth:`Injector.apply` applies it; :class:`FaultSchedule` holds triggered ones. Link
faults draw from a seeded generator.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Protocol

from emulator.errors import InjectionError
from firmware_proto.wire.message import Message
from firmware_proto.wire.messages import FaultCode

if TYPE_CHECKING:  # the CLI imports this module for its help text; keep it light
    from emulator.controller import ControllerModel

__all__ = [
    "ENCODER_NOISE_MAX_UNITS",
    "FAULT_KINDS",
    "IMU_BIAS_MAX_RAD_S",
    "FaultSchedule",
    "FaultSpec",
    "InjectionListener",
    "InjectionRecord",
    "Injector",
    "LinkFaultTarget",
    "ScheduledFault",
    "Trigger",
    "parse_fault",
]

logger = logging.getLogger(__name__)

FAULT_KINDS: dict[str, str] = {
    "slip": "side=scale: friction of a side scaled (0 < scale <= 1)",
    "stall": "side: that side's wheels locked",
    "encoder-noise": "side=units: 1-sigma noise on a side's count",
    "encoder-dropout": "side: a side's encoder stops counting and flags an error",
    "imu-bias": "=rad_s: constant yaw-rate bias",
    "imu-dropout": "the IMU goes silent",
    "pose-dropout": "the pose sensor loses its fix",
    "reboot": "the controller resets",
    "link-drop": "=ratio: frames dropped, 0..1",
    "link-corrupt": "=ratio: frames with a flipped bit, 0..1 (serial only)",
    "link-delay": "=seconds: every frame delayed",
    "clear": ":kind[:side]: undo a fault",
}
"""Every fault kind and its argument, for help texts."""

ENCODER_NOISE_MAX_UNITS = 100_000.0
"""Largest ``encoder-noise`` accepted, distance units (about 4.3 m of travel, 1 sigma)."""

IMU_BIAS_MAX_RAD_S = 32.767
"""Largest ``imu-bias`` magnitude accepted, rad/s: the IMU message's int16 of mrad/s."""

_SIDED = {"slip", "stall", "encoder-noise", "encoder-dropout"}
_VALUED = {"slip", "encoder-noise", "imu-bias", "link-drop", "link-corrupt", "link-delay"}


@dataclass(frozen=True)
class Trigger:
    """When a scheduled fault fires: at a twin time, after a ground distance, or on
    entering a map region. All ``None``: at once."""

    at_s: float | None = None
    after_m: float | None = None
    region: str | None = None

    @property
    def immediate(self) -> bool:
        """No trigger: the fault applies at once."""
        return self.at_s is None and self.after_m is None and self.region is None

    def describe(self) -> str:
        """When it fires, in words (for logs and the control interface's answers)."""
        if self.at_s is not None:
            return f"at twin time t={self.at_s:g} s"
        if self.after_m is not None:
            return f"when the ground travel reaches {self.after_m:g} m"
        if self.region is not None:
            return f"when the rover's centre is inside region {self.region!r}"
        return "now"

    def __str__(self) -> str:
        if self.at_s is not None:
            return f"@t={self.at_s:g}"
        if self.after_m is not None:
            return f"@d={self.after_m:g}"
        if self.region is not None:
            return f"@region={self.region}"
        return ""


@dataclass(frozen=True)
class FaultSpec:
    """One fault: its kind, side (``left``/``right``/``both`` or ``None``), value, and
    for ``clear`` the kind it undoes."""

    kind: str
    side: str | None = None
    value: float | None = None
    target: str | None = None
    trigger: Trigger = field(default_factory=Trigger)

    @property
    def untriggered(self) -> FaultSpec:
        """The same fault without its trigger (what is in force once it fired)."""
        return replace(self, trigger=Trigger())

    def __str__(self) -> str:
        text = self.kind
        if self.kind == "clear":
            text += f":{self.target}" + (f":{self.side}" if self.side else "")
        elif self.side is not None:
            text += f":{self.side}" + (f"={self.value:g}" if self.value is not None else "")
        elif self.value is not None:
            text += f"={self.value:g}"
        return text + str(self.trigger)


def _parse_trigger(text: str) -> Trigger:
    key, sep, value = text.partition("=")
    if not sep:
        raise InjectionError(f"trigger '@{text}' must be @t=SECONDS, @d=METRES or @region=ID")
    if key == "region":
        if not value:
            raise InjectionError("@region needs a region id")
        return Trigger(region=value)
    try:
        number = float(value)
    except ValueError:
        raise InjectionError(f"trigger '@{text}': {value!r} is not a number") from None
    if not math.isfinite(number) or number < 0:
        raise InjectionError(f"trigger '@{text}' must be a finite number >= 0")
    if key == "t":
        return Trigger(at_s=number)
    if key == "d":
        return Trigger(after_m=number)
    raise InjectionError(f"unknown trigger '@{key}': use @t=, @d= or @region=")


def parse_fault(text: str) -> FaultSpec:
    """Parse ``KIND[:SIDE][=VALUE][@TRIGGER]`` (see the module doc).

    Raises:
        InjectionError: unknown kind, missing or bad side or value (the kinds listed).
    """
    body, _, trig = text.strip().partition("@")
    trigger = _parse_trigger(trig) if trig else Trigger()
    head, _, value_text = body.partition("=")
    kind, _, side = head.partition(":")
    if kind not in FAULT_KINDS:
        raise InjectionError(f"unknown fault {kind!r}; known: {', '.join(FAULT_KINDS)}")
    if kind == "clear":
        target, _, side = side.partition(":")
        if target not in FAULT_KINDS or target in ("clear", "reboot"):
            raise InjectionError(f"clear needs a fault kind to undo, got {target!r}")
        return FaultSpec("clear", side or None, None, target, trigger)
    if kind in _SIDED:
        if side not in ("left", "right", "both"):
            raise InjectionError(f"{kind} needs a side: {kind}:left, {kind}:right or {kind}:both")
    elif side:
        raise InjectionError(f"{kind} takes no side")
    value: float | None = None
    if kind in _VALUED:
        try:
            value = float(value_text)
        except ValueError:
            raise InjectionError(
                f"{kind} needs a number: {kind}{':' + side if side else ''}=VALUE"
            ) from None
        if not math.isfinite(value):
            raise InjectionError(f"{kind}: value must be finite")
    elif value_text:
        raise InjectionError(f"{kind} takes no value")
    return FaultSpec(kind, side or None, value, None, trigger)


class LinkFaultTarget(Protocol):
    """What a front end exposes for link faults (and for a reboot)."""

    def restart(self) -> None:
        """The controller rebooted: drop what it had queued, restart its frame counter."""

    def check_link_faults(
        self,
        *,
        drop: float | None = None,
        corrupt: float | None = None,
        delay_s: float | None = None,
    ) -> None:
        """Raise InjectionError if a level cannot apply; change nothing."""

    def set_link_faults(
        self,
        *,
        drop: float | None = None,
        corrupt: float | None = None,
        delay_s: float | None = None,
    ) -> None:
        """Set any of the link fault levels; raise InjectionError if one cannot apply."""


@dataclass(frozen=True)
class InjectionRecord:
    """An applied injection: twin time (s), the fault as asked for (its trigger
    included), and who asked (cli, control, api, schedule)."""

    time_s: float
    fault: str
    source: str

    def line(self) -> str:
        """One line for a terminal: ``INJECT t=5.001 slip:left=0.3@t=5 (schedule)``."""
        return f"INJECT t={self.time_s:.3f} {self.fault} ({self.source})"


@dataclass(frozen=True)
class ScheduledFault:
    """A fault accepted for later: when it was scheduled (twin time, s) and, in words,
    when it fires (:meth:`Trigger.describe`, with the current value it waits on)."""

    fault: str
    scheduled_s: float
    fires: str


InjectionListener = Callable[[InjectionRecord], None]
"""Told of every injection applied, on the thread that applied it."""


class Injector:
    """Applies faults to a controller model, its twin and (optionally) its link.

    :meth:`check` reads configuration only (the map, the link's capabilities) and may be
    called from any thread; :meth:`apply` must be called from the thread that owns the
    model. :attr:`log` lists every injection; :attr:`listeners` are told of each one.
    """

    def __init__(self, model: ControllerModel, link: LinkFaultTarget | None = None) -> None:
        self.model = model
        self.link = link
        self.log: list[InjectionRecord] = []
        self.listeners: list[InjectionListener] = []
        self._slip = [1.0, 1.0]
        self._in_force: dict[tuple[str, int], FaultSpec] = {}
        world = model.twin.world
        self.regions: dict[str, tuple[tuple[float, float], ...]] = (
            {r.id: r.polygon for r in world.traction_regions} if world else {}
        )
        """Traction regions of the map by id: what ``@region=`` may name."""

    # -- checking -----------------------------------------------------------------------
    def check(self, spec: FaultSpec) -> None:
        """Whether ``spec`` can apply here; changes nothing.

        Raises:
            InjectionError: a value out of range (docs/emulator.md), a link fault the
                link cannot carry, or a trigger region the map lacks.
        """
        region = spec.trigger.region
        if region is not None and region not in self.regions:
            known = ", ".join(sorted(self.regions)) or "none in this map"
            raise InjectionError(f"@region: unknown region {region!r} (regions: {known})")
        kind, value = spec.kind, spec.value
        if kind == "slip":
            assert value is not None
            if not 0.0 < value <= 1.0:
                raise InjectionError(f"slip scale must be in (0, 1], got {value:g}")
        elif kind == "encoder-noise":
            assert value is not None
            if not 0.0 <= value <= ENCODER_NOISE_MAX_UNITS:
                raise InjectionError(
                    f"encoder-noise must be in 0..{ENCODER_NOISE_MAX_UNITS:g} units, got {value:g}"
                )
        elif kind == "imu-bias":
            assert value is not None
            if not abs(value) <= IMU_BIAS_MAX_RAD_S:
                raise InjectionError(
                    f"imu-bias must be within +/-{IMU_BIAS_MAX_RAD_S:g} rad/s (what IMU can "
                    f"carry), got {value:g}"
                )
        elif kind in _LINK_KEYS:
            assert value is not None
            self._link_target(kind).check_link_faults(**{_LINK_KEYS[kind]: value})
        elif kind == "clear" and spec.target in _LINK_KEYS:
            self._link_target(f"clear:{spec.target}")

    def _link_target(self, what: str) -> LinkFaultTarget:
        if self.link is None:
            raise InjectionError(f"{what} needs a link: this emulator has no front end")
        return self.link

    # -- applying -----------------------------------------------------------------------
    def apply(self, spec: FaultSpec, source: str = "api") -> list[Message]:
        """Check ``spec`` and apply it now (its trigger is the caller's business);
        returns messages the controller sends because of it (FAULT, IDENT). Recorded in
        :attr:`log`, logged at WARNING and handed to every listener.

        Raises:
            InjectionError: it cannot apply here (:meth:`check`); nothing changed.
        """
        self.check(spec)
        out = self._apply(spec)
        self._track(spec)
        record = InjectionRecord(self.model.now_s, str(spec), source)
        self.log.append(record)
        trigger = f", trigger {spec.trigger}" if not spec.trigger.immediate else ""
        if spec.kind == "clear":
            what = f"{spec.target}" + (f":{spec.side}" if spec.side else "")
            logger.warning(
                "fault cleared: %s at t=%.3f s (%s%s)", what, record.time_s, source, trigger
            )
        else:
            logger.warning(
                "fault injected: %s at t=%.3f s (%s%s)",
                spec.untriggered,
                record.time_s,
                source,
                trigger,
            )
        for listener in list(self.listeners):
            try:
                listener(record)
            except Exception:
                logger.exception("injection listener failed")
        return out

    def in_force(self) -> tuple[str, ...]:
        """The injected faults in force now, as fault texts without triggers, sorted; a
        reboot or a neutral level (slip 1, link level 0) is never in force."""
        texts: list[str] = []
        kinds = sorted({kind for kind, _ in self._in_force})
        for kind in kinds:
            left = self._in_force.get((kind, 0))
            right = self._in_force.get((kind, 1))
            if kind not in _SIDED:
                assert left is not None
                texts.append(str(left))
            elif left is not None and right is not None and left.value == right.value:
                texts.append(str(replace(left, side="both")))
            else:
                texts += [str(s) for s in (left, right) if s is not None]
        return tuple(texts)

    def _track(self, spec: FaultSpec) -> None:
        """Keep :meth:`in_force` up to date after ``spec`` was applied."""
        if spec.kind == "reboot":
            return
        kind = spec.target if spec.kind == "clear" else spec.kind
        assert kind is not None
        keys = [(kind, s) for s in self._sides(spec.side)] if kind in _SIDED else [(kind, 0)]
        neutral = spec.kind == "clear" or (
            spec.value == (1.0 if kind == "slip" else 0.0)
            and kind in ("slip", "link-drop", "link-corrupt", "link-delay")
        )
        for key in keys:
            if neutral:
                self._in_force.pop(key, None)
            else:
                side = ("left", "right")[key[1]] if kind in _SIDED else None
                self._in_force[key] = replace(spec.untriggered, side=side)

    def _sides(self, side: str | None) -> tuple[int, ...]:
        return {"left": (0,), "right": (1,), "both": (0, 1), None: (0, 1)}[side]

    def _apply(self, spec: FaultSpec) -> list[Message]:
        m = self.model
        kind, value = spec.kind, spec.value
        if kind == "slip":
            assert value is not None
            for s in self._sides(spec.side):
                self._slip[s] = value
            m.twin.set_traction_scale(self._slip[0], self._slip[1])
            return []
        if kind == "stall":
            for s in self._sides(spec.side):
                m.twin.set_wheel_locked(("left", "right")[s], True)
            return []
        if kind == "encoder-noise":
            assert value is not None
            for s in self._sides(spec.side):
                m.encoders.noise_units[s] = value
            return []
        if kind == "encoder-dropout":
            for s in self._sides(spec.side):
                m.encoders.dropout[s] = True
            return m.raise_fault(FaultCode.ENCODER, condition=True)
        if kind == "imu-bias":
            assert value is not None
            m.imu.bias_rad_s = value
            return []
        if kind == "imu-dropout":
            m.imu.dropout = True
            return m.raise_fault(FaultCode.IMU, condition=True)
        if kind == "pose-dropout":
            m.pose_sensor.dropout = True
            return m.raise_fault(FaultCode.POSE, condition=True)
        if kind == "reboot":
            if self.link is not None:
                self.link.restart()  # before the new boot's IDENT: its frame is seq 0
            return m.reboot()
        if kind in _LINK_KEYS:
            assert value is not None
            self._link_target(kind).set_link_faults(**{_LINK_KEYS[kind]: value})
            return []
        if kind == "clear":
            return self._clear(spec)
        raise InjectionError(f"unknown fault {kind!r}")  # pragma: no cover - parse_fault guards

    def _clear(self, spec: FaultSpec) -> list[Message]:
        m = self.model
        target = spec.target
        sides = self._sides(spec.side)
        if target == "slip":
            for s in sides:
                self._slip[s] = 1.0
            m.twin.set_traction_scale(self._slip[0], self._slip[1])
        elif target == "stall":
            for s in sides:
                m.twin.set_wheel_locked(("left", "right")[s], False)
        elif target == "encoder-noise":
            for s in sides:
                m.encoders.noise_units[s] = m.config.sensors.encoder_noise_units
        elif target == "encoder-dropout":
            for s in sides:
                m.encoders.dropout[s] = False
            if not any(m.encoders.dropout):
                return m.clear_fault_condition(FaultCode.ENCODER)
        elif target == "imu-bias":
            m.imu.bias_rad_s = m.config.sensors.imu_bias_rad_s
        elif target == "imu-dropout":
            m.imu.dropout = False
            return m.clear_fault_condition(FaultCode.IMU)
        elif target == "pose-dropout":
            m.pose_sensor.dropout = False
            return m.clear_fault_condition(FaultCode.POSE)
        elif target in _LINK_KEYS:
            self._link_target(f"clear:{target}").set_link_faults(**{_LINK_KEYS[target]: 0.0})
        return []


_LINK_KEYS = {"link-drop": "drop", "link-corrupt": "corrupt", "link-delay": "delay_s"}
"""Link fault kinds and the :meth:`LinkFaultTarget.set_link_faults` argument of each."""


class FaultSchedule:
    """Faults waiting for their trigger; :meth:`poll` fires the due ones, in order.

    A fault is checked (:meth:`Injector.check`) when scheduled, not when it fires.
    Ground distance is integrated from the twin's pose at every poll.
    """

    def __init__(
        self,
        injector: Injector,
        faults: list[FaultSpec] | None = None,
        source: str = "schedule",
    ) -> None:
        """Args:
        injector: applies the faults when they fire.
        faults: faults to schedule now.
        source: who asked for ``faults`` (recorded with each injection).

        Raises:
            InjectionError: one of ``faults`` cannot apply; nothing is scheduled.
        """
        self.injector = injector
        for spec in faults or []:
            injector.check(spec)
        self._pending: list[tuple[FaultSpec, str]] = [(spec, source) for spec in faults or []]
        twin = injector.model.twin
        self._last_xy = (twin.pose.x_m, twin.pose.y_m)
        self.ground_m = 0.0
        """Ground travel of the rover's centre since the schedule was created, m."""

    @property
    def pending(self) -> list[FaultSpec]:
        """Faults waiting for their trigger, in the order they were scheduled."""
        return [spec for spec, _ in self._pending]

    def add(self, spec: FaultSpec, source: str = "schedule") -> ScheduledFault:
        """Schedule ``spec`` (no trigger: at the next poll); ``source`` is recorded. Call
        from the thread that owns the model.

        Returns:
            when it was scheduled and, in words, when it will fire.

        Raises:
            InjectionError: it cannot apply (see :meth:`Injector.check`).
        """
        self.injector.check(spec)
        self._pending.append((spec, source))
        now = self.injector.model.now_s
        fires = spec.trigger.describe()
        t = spec.trigger
        if t.at_s is not None and t.at_s <= now:
            fires += f" (passed: now t={now:.3f} s, so at the next tick)"
        elif t.after_m is not None:
            fires += f" (now {self.ground_m:.3f} m)"
        logger.info("scheduled %s: fires %s", spec, fires)
        return ScheduledFault(str(spec), now, fires)

    def poll(self) -> list[Message]:
        """Fire every fault whose trigger is met; returns the controller's messages."""
        twin = self.injector.model.twin
        x, y = twin.position_m  # every tick: the pose's x and y, without its yaw
        self.ground_m += math.hypot(x - self._last_xy[0], y - self._last_xy[1])
        self._last_xy = (x, y)
        if not self._pending:
            return []
        out: list[Message] = []
        keep = []
        for spec, source in self._pending:
            if self._due(spec, twin.time_s, x, y):
                try:
                    out += self.injector.apply(spec, source=source)
                except InjectionError as exc:  # pragma: no cover - checked when scheduled
                    logger.error("scheduled fault %s refused: %s", spec, exc)
            else:
                keep.append((spec, source))
        self._pending = keep
        return out

    def _due(self, spec: FaultSpec, now_s: float, x: float, y: float) -> bool:
        t = spec.trigger
        if t.at_s is not None:
            return now_s + 1e-9 >= t.at_s
        if t.after_m is not None:
            return self.ground_m >= t.after_m
        if t.region is not None:
            return _inside(x, y, self.injector.regions[t.region])
        return True


def _inside(x: float, y: float, polygon: tuple[tuple[float, float], ...]) -> bool:
    """Point in polygon (even-odd rule)."""
    inside = False
    n = len(polygon)
    for i in range(n):
        (x1, y1), (x2, y2) = polygon[i], polygon[(i + 1) % n]
        if (y1 > y) != (y2 > y) and x < x1 + (y - y1) * (x2 - x1) / (y2 - y1):
            inside = not inside
    return inside
