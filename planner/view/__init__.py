"""The operator's live view: the ghost (the gate's prediction) against the rover, in a
browser, with a STOP button. See docs/view.md.

- :mod:`planner.view.hub`: the state, fed by the ground station; events to each browser.
- :mod:`planner.view.server`: the HTTP server (page, Server-Sent Events, STOP).
- :mod:`planner.view.live`: both together, as ``rover go --view`` runs them.
"""

from planner.view.hub import ClientQueue, ViewHub, ViewLimits
from planner.view.live import LiveView
from planner.view.server import ViewConfig, ViewServer

__all__ = ["ClientQueue", "LiveView", "ViewConfig", "ViewHub", "ViewLimits", "ViewServer"]
