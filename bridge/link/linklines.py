"""What ``rover bridge`` says about its link at the default verbosity: one line when
something an operator must know happens, never one per retry.

:class:`LinkNarrator` is fed snapshots of the link
(:class:`~bridge.link.controllerlink.LinkDiagnostics`) with the time they were taken
and returns the lines to print (examples: docs/bridge.md):

- the device cannot be opened (missing, not a serial port, busy), once per distinct error;
- the device is open but no controller answers within :data:`SILENT_AFTER_S`: nothing
  arrives, or bytes that are no frames (**wrong baud suspected**);
- the handshake is done, and later the link lost (why) and back;
- the link flaps: heartbeats missed again and again while frames keep arriving
  (:meth:`LinkNarrator._flap_line` says why); a loss during a stall of this process, or
  in silence, is not counted;
- a protocol or schema mismatch.

Pure: no I/O, no clock of its own. :attr:`LinkNarrator.reached` tells whether a
controller was ever reached (``rover bridge`` exits 3 when it was not).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from bridge.link.controllerlink import LinkDiagnostics

__all__ = ["FLAP_LOSSES", "GARBAGE_SHARE", "SILENT_AFTER_S", "LinkNarrator"]

SILENT_AFTER_S = 3.0
"""An open device with no frame from a controller for this long is 'not answering', s."""
FLAP_LOSSES = 3
"""Heartbeat losses (frames still arriving) in :data:`FLAP_WINDOW_S` that suspect a slow link."""
FLAP_WINDOW_S = 10.0
GARBAGE_SHARE = 0.25
"""Least share of receive errors (CRC, resyncs) among frames and errors over the counted losses
that suspects a wrong baud: then almost nothing frames; a cut breaks one or two of hundreds."""


_OPEN_CAUSES = (
    ("No such file or directory", "no such device (plugged in? 'rover devices' lists them)"),
    ("Is a directory", "it is a directory, not a serial device"),
    ("Inappropriate ioctl", "not a serial port (it takes no serial settings)"),
    ("Permission denied", "permission denied (the dialout group, or 'rover udev install')"),
)
"""Substrings of the usual errors of opening a device, and what they mean."""


def _nonce(value: int | None) -> str:
    return "?" if value is None else f"0x{value:04X}"


@dataclass
class LinkNarrator:
    """Turns link snapshots into the bridge's start-up and failure lines.

    Args:
        device: the device or URL, as the operator gave it.
        baud: the bridge's baud rate (``None`` on CAN).
    """

    device: str
    baud: int | None = None
    reached: bool = False
    """A handshake with a controller has completed at least once."""
    _state: str = ""
    _errors_said: set[str] = field(default_factory=set)
    _open_since: float | None = None
    _silence_said: bool = False
    _frames_at_open: int = 0
    _losses: list[tuple[float, int, int]] = field(default_factory=list)
    """The counted heartbeat losses: (when, frames, receive errors since the snapshot before)."""
    _last_losses: int = 0
    _last_frames: int = 0
    _last_garbage: int = 0
    _last_stalls: int = 0
    _flap_said: bool = False
    _reboots: int = 0

    @staticmethod
    def _ready_line(diag: LinkDiagnostics, what: str) -> str:
        return (
            f"{what}: controller firmware {diag.firmware or '?'}, boot nonce "
            f"{_nonce(diag.boot_nonce)}"
        )

    def _flap_line(self) -> str:
        """What the counted losses say: a wrong baud when bytes that do not frame came with
        them (:data:`GARBAGE_SHARE`), else a link that drops out or is too slow."""
        seen = {x[0]: x for x in self._losses}.values()  # one snapshot's losses share it
        frames = sum(x[1] for x in seen)
        garbage = sum(x[2] for x in seen)
        head = (
            f"the controller's heartbeats come late again and again ({len(self._losses)} "
            f"link losses in {FLAP_WINDOW_S:g} s) while its frames keep arriving"
        )
        if garbage and garbage >= GARBAGE_SHARE * (frames + garbage):
            return (
                f"{head}, with bytes that do not frame ({garbage} CRC errors and resyncs "
                f"beside {frames} frames): wrong baud suspected" + self._baud_hint()
            )
        return (
            f"{head}; its bytes frame (the baud is right): the link drops out or is slower than "
            "the controller's telemetry"
        )

    def _baud_hint(self) -> str:
        return f" (the bridge is at {self.baud} baud: --baud)" if self.baud else ""

    def _open_error(self, error: str) -> str:
        """A failed open in words: the usual causes named, else the error as it is."""
        for needle, words in _OPEN_CAUSES:
            if needle in error:
                return f"cannot open {self.device}: {words}"
        if self.reached:
            return f"link failed: {error}"
        return error if error.startswith("cannot open") else f"cannot open {self.device}: {error}"

    def update(self, diag: LinkDiagnostics, now: float) -> list[str]:
        """The lines this snapshot calls for (usually none). ``now``: monotonic, s."""
        out: list[str] = []
        state = diag.state
        if not self.reached and diag.boot_nonce is not None and state in ("ready", "lost"):
            # The handshake completed between two snapshots and the link was lost since:
            # say it in the order it happened.
            out.append(self._ready_line(diag, "handshake done"))
            self.reached = True
            self._state = "ready"
        if diag.reboots > self._reboots:
            out.append(
                f"the controller rebooted (boot nonce {_nonce(diag.boot_nonce)}); steps in "
                "flight were dropped, none is replayed"
            )
        self._reboots = diag.reboots
        if state == "disconnected":
            self._open_since = None
            error = diag.last_error
            if error and error not in self._errors_said:
                self._errors_said.add(error)
                out.append(f"{self._open_error(error)}; retrying")
        elif self._open_since is None:
            self._open_since = now
            self._silence_said = False
            self._frames_at_open = diag.rx_frames
        if state == "ready":
            self._silence_said = True  # a controller answered since this open
        if (
            state == "handshake"
            and not self._silence_said
            and self._open_since is not None
            and now - self._open_since >= SILENT_AFTER_S
        ):
            self._silence_said = True
            garbage = diag.crc_errors + diag.resyncs + diag.rx_dropped
            if diag.rx_frames == self._frames_at_open and garbage:
                out.append(
                    f"{self.device} is open but what arrives is no frame ({diag.crc_errors} "
                    f"CRC errors, {diag.resyncs} resyncs): wrong baud suspected" + self._baud_hint()
                )
            elif diag.rx_frames == self._frames_at_open:
                out.append(
                    f"{self.device} is open but no controller answers (nothing in "
                    f"{SILENT_AFTER_S:g} s): is it powered, is this its device"
                    + (f", is it at {self.baud} baud" if self.baud else "")
                    + "?"
                )
            else:
                out.append(
                    f"{self.device}: a controller sends frames but does not answer the "
                    "handshake in time"
                )
        if state != self._state:
            if state == "ready" and not (self.reached and self._flap_said):
                out.append(
                    self._ready_line(diag, "link back" if self.reached else "handshake done")
                )
                self.reached = True
            elif state == "lost" and not self._flap_said:
                out.append(f"link lost: {diag.last_error or 'no reason given'}; handshaking again")
            elif state == "mismatch":
                out.append(f"refusing to drive: {diag.last_error}")
            elif (
                state == "disconnected"
                and self._state in ("ready", "lost", "handshake")
                and diag.last_error in self._errors_said
            ):
                out.append(f"link failed: {diag.last_error}; reconnecting")
        # The same state may come and go between two snapshots: count the losses, not
        # the states seen.
        garbage = diag.crc_errors + diag.resyncs
        if diag.heartbeat_losses > self._last_losses:
            frames = diag.rx_frames - self._last_frames
            held_up = diag.stalls > self._last_stalls  # the bridge's own stall, not the link
            if frames > 0 and not held_up:
                evidence = (now, frames, max(0, garbage - self._last_garbage))
                self._losses.extend([evidence] * (diag.heartbeat_losses - self._last_losses))
            if state == self._state == "ready" and not self._flap_said:
                why = " (this process was held up)" if held_up else ""
                out.append(f"link lost and back{why}: {diag.last_error}")
        self._losses = [x for x in self._losses if now - x[0] <= FLAP_WINDOW_S]
        if len(self._losses) >= FLAP_LOSSES and not self._flap_said:
            self._flap_said = True
            out.append(self._flap_line())
        self._last_losses = diag.heartbeat_losses
        self._last_frames = diag.rx_frames
        self._last_garbage = garbage
        self._last_stalls = diag.stalls
        self._state = state
        return out
