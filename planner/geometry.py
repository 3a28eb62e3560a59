"""The planner's names for the shared geometry: ``Point`` and ``wrap_deg``.

The geometry helpers are defined once, in :mod:`firmware_proto.geometry`, and the pose in
:mod:`firmware_proto.pose`; the planner imports them from there. This module defines
nothing: it names the two that ``planner/drift.py`` and ``planner/executor.py`` still
import from here.
"""

from __future__ import annotations

from firmware_proto.geometry import Point, wrap_deg

__all__ = ["Point", "wrap_deg"]
