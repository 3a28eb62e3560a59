"""Cyclone DDS configurations for the ``dds`` backend, and where a port's config comes from.

A config is what Cyclone DDS accepts in ``CYCLONEDDS_URI``: an XML document, a
``file://`` URI of one, or several of those separated by commas. This module builds the
two we need and picks the one a port uses; it does not import cyclonedds.

- :func:`loopback_config`: traffic never leaves the machine: bind 127.0.0.1, multicast
  off, 127.0.0.1 the only discovery peer. Tests and demos use it.
- :func:`network_config`: the rover network: one interface (by name or address), with
  multicast discovery, or unicast to listed peers where multicast is unwelcome.
"""

from __future__ import annotations

import ipaddress
import os
from collections.abc import Mapping, Sequence
from typing import Final
from xml.sax.saxutils import quoteattr

__all__ = [
    "CONFIG_ENV",
    "DOMAIN_ENV",
    "loopback_config",
    "network_config",
    "resolve_config",
    "resolve_domain_id",
]

#: Cyclone DDS's own variable for its configuration.
CONFIG_ENV: Final = "CYCLONEDDS_URI"
#: ROS 2's variable for the DDS domain.
DOMAIN_ENV: Final = "ROS_DOMAIN_ID"
#: ROS 2's default domain.
DEFAULT_DOMAIN_ID: Final = 0
#: Participant indices tried by unicast discovery (Cyclone's default, 9, is too few for a
#: test run with several ports and processes on one host).
DEFAULT_MAX_PARTICIPANTS: Final = 32
#: Highest domain id whose RTPS ports fit in 16 bits with the default port mapping.
MAX_DOMAIN_ID: Final = 232


def loopback_config(*, max_participants: int = DEFAULT_MAX_PARTICIPANTS) -> str:
    """A config that keeps all DDS traffic on 127.0.0.1 (no multicast, no other peer).

    Args:
        max_participants: how many participants on this host can discover each other
            (unicast discovery probes one port per participant index).
    """
    return network_config(
        "127.0.0.1", peers=["127.0.0.1"], multicast=False, max_participants=max_participants
    )


def network_config(
    interface: str,
    *,
    peers: Sequence[str] = (),
    multicast: bool = True,
    max_participants: int = DEFAULT_MAX_PARTICIPANTS,
) -> str:
    """A config that binds DDS to one network interface.

    Args:
        interface: interface name (``"eth0"``, ``"wlan0"``) or its IP address.
        peers: addresses (or host names) to send unicast discovery to, in addition to
            multicast when that is on. Needed when ``multicast`` is False.
        multicast: use multicast (SPDP discovery and data) on this interface.
        max_participants: participant indices probed per peer when unicast discovery is
            used (``multicast=False``).

    Raises:
        ValueError: no interface, unicast only without peers, or ``max_participants`` < 1.
    """
    if not interface:
        raise ValueError("network_config needs an interface name or address")
    if not multicast and not peers:
        raise ValueError("without multicast, discovery needs at least one peer address")
    if max_participants < 1:
        raise ValueError(f"max_participants must be at least 1, got {max_participants}")
    try:
        ipaddress.ip_address(interface)
        nic = f"<NetworkInterface address={quoteattr(interface)}/>"
    except ValueError:
        nic = f"<NetworkInterface name={quoteattr(interface)}/>"
    peer_xml = "".join(f"<Peer address={quoteattr(p)}/>" for p in peers)
    discovery = f"<Peers>{peer_xml}</Peers>" if peers else ""
    if not multicast:
        discovery = (
            "<ParticipantIndex>auto</ParticipantIndex>"
            f"<MaxAutoParticipantIndex>{max_participants}</MaxAutoParticipantIndex>" + discovery
        )
    return (
        '<CycloneDDS><Domain Id="any">'
        f"<General><Interfaces>{nic}</Interfaces>"
        f"<AllowMulticast>{'default' if multicast else 'false'}</AllowMulticast></General>"
        f"<Discovery>{discovery}</Discovery>"
        "</Domain></CycloneDDS>"
    )


def resolve_config(config: str | None, environ: Mapping[str, str] | None = None) -> str | None:
    """The config a port uses: the argument, else ``$CYCLONEDDS_URI``, else None.

    None means Cyclone DDS's built-in defaults (which use multicast on a default
    interface: fine on a robot's network, wrong for tests).

    Raises:
        ValueError: the config is empty or not ASCII (Cyclone takes ASCII only).
    """
    env = os.environ if environ is None else environ
    chosen = config if config is not None else env.get(CONFIG_ENV) or None
    if chosen is None:
        return None
    if not chosen.strip():
        raise ValueError("the DDS config is empty")
    if not chosen.isascii():
        raise ValueError("the DDS config must be ASCII")
    return chosen


def resolve_domain_id(domain_id: int | None, environ: Mapping[str, str] | None = None) -> int:
    """The DDS domain a port joins: the argument, else ``$ROS_DOMAIN_ID``, else 0.

    Raises:
        ValueError: not an integer in 0..232.
    """
    env = os.environ if environ is None else environ
    if domain_id is None:
        text = env.get(DOMAIN_ENV, "").strip()
        try:
            domain_id = int(text) if text else DEFAULT_DOMAIN_ID
        except ValueError:
            raise ValueError(f"{DOMAIN_ENV}={text!r} is not an integer") from None
    if isinstance(domain_id, bool) or not 0 <= domain_id <= MAX_DOMAIN_ID:
        raise ValueError(f"DDS domain id must be in 0..{MAX_DOMAIN_ID}, got {domain_id!r}")
    return domain_id
