"""The link's ``/diagnostics`` values as docs/bridge.md lists them (issue #40, 9: the
documented ``samples_outside_session`` was never published)."""

from __future__ import annotations

import dataclasses

from bridge.link.linkcore import LinkCore
from bridge.link.linktypes import LinkConfig
from bridge.ros.diagnostics import diagnostic_array
from bridge.ros.rosport.msgs import Time


def test_samples_outside_session_is_published_with_the_link() -> None:
    snapshot = LinkCore(LinkConfig("sim://x")).diagnostics(0.0)
    array = diagnostic_array(dataclasses.replace(snapshot, samples_outside_session=3), Time())
    (link,) = [s for s in array.status if s.name == "rover_bridge: link"]
    assert {kv.key: kv.value for kv in link.values}["samples_outside_session"] == "3"
