"""DDS configs: loopback-only and rover network; which config and domain a port uses."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import pytest

from bridge.rosport.ddsconfig import (
    loopback_config,
    network_config,
    resolve_config,
    resolve_domain_id,
)


def test_loopback_config_keeps_traffic_on_127_0_0_1() -> None:
    root = ET.fromstring(loopback_config())
    domain = root.find("Domain")
    assert domain is not None
    assert [n.attrib for n in domain.iter("NetworkInterface")] == [{"address": "127.0.0.1"}]
    assert domain.findtext("General/AllowMulticast") == "false"
    assert [p.attrib["address"] for p in domain.iter("Peer")] == ["127.0.0.1"]
    assert domain.findtext("Discovery/ParticipantIndex") == "auto"


def test_network_config_by_name_or_address() -> None:
    by_name = ET.fromstring(network_config("eth0"))
    assert [n.attrib for n in by_name.iter("NetworkInterface")] == [{"name": "eth0"}]
    assert by_name.findtext("Domain/General/AllowMulticast") == "default"
    assert list(by_name.iter("Peer")) == []
    unicast = ET.fromstring(
        network_config("192.168.10.2", peers=["192.168.10.1", "ground.local"], multicast=False)
    )
    assert [n.attrib for n in unicast.iter("NetworkInterface")] == [{"address": "192.168.10.2"}]
    assert [p.attrib["address"] for p in unicast.iter("Peer")] == ["192.168.10.1", "ground.local"]


def test_network_config_refuses_what_cannot_work() -> None:
    with pytest.raises(ValueError, match="needs at least one peer"):
        network_config("eth0", multicast=False)
    with pytest.raises(ValueError, match="interface"):
        network_config("")
    with pytest.raises(ValueError, match="max_participants"):
        loopback_config(max_participants=0)


def test_names_are_escaped() -> None:
    root = ET.fromstring(network_config('eth0"/><x a="'))
    assert [n.attrib["name"] for n in root.iter("NetworkInterface")] == ['eth0"/><x a="']


def test_config_precedence_argument_then_environment() -> None:
    env = {"CYCLONEDDS_URI": "file:///etc/cyclone.xml"}
    assert resolve_config("<CycloneDDS/>", env) == "<CycloneDDS/>"
    assert resolve_config(None, env) == "file:///etc/cyclone.xml"
    assert resolve_config(None, {}) is None
    with pytest.raises(ValueError, match="ASCII"):
        resolve_config("<CycloneDDS>é</CycloneDDS>", {})
    with pytest.raises(ValueError, match="empty"):
        resolve_config("  ", {})


def test_domain_precedence_argument_then_ros_domain_id() -> None:
    assert resolve_domain_id(7, {"ROS_DOMAIN_ID": "3"}) == 7
    assert resolve_domain_id(None, {"ROS_DOMAIN_ID": "3"}) == 3
    assert resolve_domain_id(None, {}) == 0
    with pytest.raises(ValueError, match="not an integer"):
        resolve_domain_id(None, {"ROS_DOMAIN_ID": "three"})
    with pytest.raises(ValueError, match=r"0\.\.232"):
        resolve_domain_id(233, {})
