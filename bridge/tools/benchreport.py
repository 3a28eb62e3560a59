"""Reports of the STOP bench: percentiles, the terminal table, CSV, JSON and a histogram
PNG (docs/bench.md).

Percentiles are numpy's default (linear interpolation between order statistics): with
30 trials p99 lies between the two largest values, so read it beside ``max``.
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from bridge.tools.stopbench import BenchRun, TrialResult

__all__ = [
    "MEASURES",
    "Summary",
    "format_table",
    "summarize",
    "write_csv",
    "write_histogram_png",
    "write_json",
    "write_reports",
]

MEASURES: tuple[tuple[str, str], ...] = (
    ("ack_ms", "STOP -> STOP_ACK"),
    ("stopped_ms", "STOP -> STOPPED"),
    ("zero_ms", "STOP -> wheels at zero"),
)
"""Each measure's field in :class:`TrialResult` and its label."""


@dataclass(frozen=True)
class Summary:
    """One measure over the trials that saw it, ms."""

    measure: str
    label: str
    n: int
    p50: float
    p95: float
    p99: float
    max: float
    mean: float


def summarize(trials: tuple[TrialResult, ...] | list[TrialResult]) -> list[Summary]:
    """Percentiles of every measure (NaN where no trial saw it)."""
    out = []
    for name, label in MEASURES:
        values = [v for t in trials if (v := getattr(t, name)) is not None]
        if values:
            p50, p95, p99 = (float(x) for x in np.percentile(values, [50, 95, 99]))
            out.append(
                Summary(
                    name, label, len(values), p50, p95, p99, max(values), float(np.mean(values))
                )
            )
        else:
            nan = math.nan
            out.append(Summary(name, label, 0, nan, nan, nan, nan, nan))
    return out


def format_table(run: BenchRun) -> str:
    """The terminal report: conditions, the percentile table, the checks."""
    trials = run.trials
    lines = [
        f"STOP bench: {len(trials)} trials on {run.config.url} ({run.medium}), "
        f"seed {run.config.seed}, speed {run.config.speed}, {run.duration_s:.1f} s",
        f"controller: {run.ident}",
        f"load: {run.load}",
        f"note: {run.arbitration_note}",
        "",
        f"{'measure (ms)':<24}{'n':>4}{'p50':>9}{'p95':>9}{'p99':>9}{'max':>9}",
    ]
    for s in summarize(trials):
        lines.append(f"{s.label:<24}{s.n:>4}{s.p50:>9.2f}{s.p95:>9.2f}{s.p99:>9.2f}{s.max:>9.2f}")
    n = len(trials)
    checks = [
        ("queue purged", sum(t.purged == t.queued and t.queued > 0 for t in trials)),
        ("targets zero from STOP_ACK to STOPPED", sum(t.targets_zero for t in trials)),
        ("latch held (MOTION refused STOP_LATCHED)", sum(t.latch_held for t in trials)),
        ("CLEAR_STOP released (CLEARED)", sum(t.clear_result == "CLEARED" for t in trials)),
        ("MOTION accepted after clear", sum(t.resumed for t in trials)),
    ]
    lines.append("")
    lines += [f"{name}: {count}/{n}" for name, count in checks]
    stopping = [t.controller_distance_mm for t in trials if t.controller_distance_mm is not None]
    if stopping:
        lines.append(
            f"stopping distance (controller): median {float(np.median(stopping)):.0f} mm, "
            f"max {max(stopping)} mm; STOP repeats: {sum(t.stop_repeats for t in trials)}"
        )
    if run.flood is not None:
        lines.append(f"flood: {run.flood.sent} frames sent, {run.flood.refused} refused by the bus")
    for t in trials:
        if t.error:
            lines.append(f"trial {t.trial}: {t.error}")
    lines.append(f"trials passed: {run.passed}/{n}")
    return "\n".join(lines)


def write_csv(run: BenchRun, path: Path) -> None:
    """Every trial, one row each."""
    rows = [t.as_dict() for t in run.trials]
    with path.open("w", newline="", encoding="utf-8") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]) if rows else ["trial"])
        writer.writeheader()
        writer.writerows(rows)


def _finite(value: float) -> float | None:
    return value if math.isfinite(value) else None


def write_json(run: BenchRun, path: Path) -> None:
    """Conditions, summary and every trial."""
    config: dict[str, Any] = asdict(run.config)
    doc = {
        "config": config,
        "medium": run.medium,
        "controller": run.ident,
        "load": run.load,
        "note": run.arbitration_note,
        "telemetry_hz_set": run.telemetry_hz_set,
        "flood": asdict(run.flood) if run.flood is not None else None,
        "duration_s": run.duration_s,
        "passed": run.passed,
        "summary": {
            s.measure: {
                "label": s.label,
                "n": s.n,
                **{k: _finite(getattr(s, k)) for k in ("p50", "p95", "p99", "max", "mean")},
            }
            for s in summarize(run.trials)
        },
        "trials": [t.as_dict() for t in run.trials],
    }
    path.write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8")


_W, _PANEL_H, _TITLE_H = 900, 230, 40
_MARGIN_L, _MARGIN_R, _MARGIN_T, _MARGIN_B = 70, 20, 30, 40
_BINS = 20


def write_histogram_png(run: BenchRun, path: Path) -> None:
    """One histogram per measure, stacked, with p50/p95/max marked."""
    summaries = summarize(run.trials)
    height = _TITLE_H + _PANEL_H * len(summaries)
    image = Image.new("RGB", (_W, height), "white")
    draw = ImageDraw.Draw(image)
    font = ImageFont.load_default()
    draw.text(
        (10, 10),
        f"STOP bench, {len(run.trials)} trials, {run.medium} ({run.config.url}); {run.load}",
        fill="black",
        font=font,
    )
    for index, (summary, (name, _label)) in enumerate(zip(summaries, MEASURES, strict=True)):
        top = _TITLE_H + index * _PANEL_H
        values = [v for t in run.trials if (v := getattr(t, name)) is not None]
        _panel(draw, font, top, summary, values)
    path.parent.mkdir(parents=True, exist_ok=True)
    image.save(path, format="PNG")


def _panel(
    draw: ImageDraw.ImageDraw,
    font: Any,
    top: int,
    summary: Summary,
    values: list[float],
) -> None:
    x0, x1 = _MARGIN_L, _W - _MARGIN_R
    y0, y1 = top + _MARGIN_T, top + _PANEL_H - _MARGIN_B
    draw.text((x0, top + 8), f"{summary.label} (ms), n={summary.n}", fill="black", font=font)
    draw.line([(x0, y1), (x1, y1)], fill="black")
    draw.line([(x0, y0), (x0, y1)], fill="black")
    if not values:
        draw.text((x0 + 10, (y0 + y1) // 2), "no data", fill="gray", font=font)
        return
    lo, hi = min(values), max(values)
    if hi - lo < 1e-9:
        lo, hi = lo - 0.5, hi + 0.5
    span = hi - lo
    lo = max(0.0, lo - span * 0.05)
    hi += span * 0.05
    counts, edges = np.histogram(values, bins=_BINS, range=(lo, hi))
    peak = max(1, int(counts.max()))

    def x_of(v: float) -> float:
        return x0 + (v - lo) / (hi - lo) * (x1 - x0)

    for count, left, right in zip(counts, edges[:-1], edges[1:], strict=True):
        if count:
            y = y1 - count / peak * (y1 - y0)
            draw.rectangle([x_of(left) + 1, y, x_of(right) - 1, y1], fill=(70, 110, 180))
    for row, (label, value, colour) in enumerate(
        (
            ("p50", summary.p50, (0, 140, 0)),
            ("p95", summary.p95, (220, 120, 0)),
            ("max", summary.max, (200, 0, 0)),
        )
    ):
        x = x_of(value)
        draw.line([(x, y0), (x, y1)], fill=colour)
        text = f"{label} {value:.2f}"
        width = draw.textlength(text, font=font)
        tx = x + 3 if x + 3 + width < x1 else x - 3 - width  # keep labels inside
        draw.text((tx, y0 + 2 + 12 * row), text, fill=colour, font=font)
    for fraction in (0.0, 0.5, 1.0):
        value = lo + fraction * (hi - lo)
        draw.text((x_of(value) - 15, y1 + 5), f"{value:.2f}", fill="black", font=font)
    draw.text((5, y0), f"{peak}", fill="black", font=font)
    draw.text((5, y1 - 10), "0", fill="black", font=font)


def write_reports(run: BenchRun, out_dir: Path) -> list[Path]:
    """Write ``stop_trials.csv``, ``stop_trials.json`` and ``stop_hist.png`` into
    ``out_dir`` (created); returns their paths.

    Raises:
        OSError: the directory or a file cannot be written.
    """
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = [out_dir / "stop_trials.csv", out_dir / "stop_trials.json", out_dir / "stop_hist.png"]
    write_csv(run, paths[0])
    write_json(run, paths[1])
    write_histogram_png(run, paths[2])
    return paths
