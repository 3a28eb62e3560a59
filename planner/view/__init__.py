"""The operator's live view: the ghost (the gate's prediction) against the rover, in a
browser, with a STOP button. See docs/view.md.

- :mod:`planner.view.hub`: the state, fed by the ground station; events to each browser.
- :mod:`planner.view.server`: the HTTP server (page, Server-Sent Events, STOP).
- :mod:`planner.view.live`: both together, as ``rover go --view`` runs them.
- :mod:`planner.view.cli_view`: their command-line options (light: no server loaded).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from firmware_proto.lazyexports import lazy_exports

if TYPE_CHECKING:
    from planner.view.hub import ClientQueue, ViewHub, ViewLimits
    from planner.view.live import LiveView
    from planner.view.server import ViewConfig, ViewServer

__getattr__, __dir__ = lazy_exports(
    __name__,
    {
        "planner.view.hub": ("ClientQueue", "ViewHub", "ViewLimits"),
        "planner.view.live": ("LiveView",),
        "planner.view.server": ("ViewConfig", "ViewServer"),
    },
)

__all__ = ["ClientQueue", "LiveView", "ViewConfig", "ViewHub", "ViewLimits", "ViewServer"]
