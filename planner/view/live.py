"""The live view as ``rover go`` and ``rover demo`` run it: the hub and its server in
one object (their options: :mod:`planner.view.cli_view`)."""

from __future__ import annotations

from collections.abc import Callable

from firmware_proto.model.worldmap import WorldMap
from planner.view.hub import ViewHub, ViewLimits
from planner.view.server import ViewConfig, ViewServer

__all__ = ["LiveView"]


class LiveView:
    """A started :class:`ViewHub` served by a started :class:`ViewServer`.

    Feed it through :attr:`hub` (``hub.tap`` on the ground port, ``hub.planned``,
    ``hub.progress``, ``hub.event``); :meth:`close` ends both (idempotent).

    Raises:
        OSError: the address cannot be bound.
    """

    def __init__(
        self,
        world: WorldMap,
        config: ViewConfig,
        *,
        rtt_s: float,
        time_scale: float,
        on_stop: Callable[[], str],
        on_clear: Callable[[], bool] | None = None,
        drift_source: Callable[[], tuple[float, float] | None] | None = None,
        limits: ViewLimits | None = None,
    ) -> None:
        self.config = config
        self.hub = ViewHub(
            world, rtt_s=rtt_s, time_scale=time_scale, drift_source=drift_source, limits=limits
        ).start()
        try:
            self.server = ViewServer(self.hub, config, on_stop=on_stop, on_clear=on_clear).start()
        except BaseException:
            self.hub.close()
            raise

    @property
    def url(self) -> str:
        """The page's address."""
        return self.server.url

    def close(self) -> None:
        """Stop serving, stop the hub (idempotent)."""
        self.server.close()
        self.hub.close()

    def __enter__(self) -> LiveView:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
