"""The project's Fast DDS profile (bridge/ros/rosport/discovery.py): what it sets, that the
user's own wins, and that a real rclpy port puts it in place before its participant.
How much faster a program finds running ones is benchmarks/bench_discovery.py's to
measure (docs/rosport.md, "Discovery")."""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from bridge.ros.rosport import discovery
from bridge.ros.rosport.discovery import (
    ANNOUNCEMENT_PERIOD_S,
    PROFILE,
    PROFILE_ENVS,
    use_fast_discovery,
)

_NS = {"p": "http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles"}


def test_the_profile_is_a_default_participant_profile_with_the_announcement_period() -> None:
    root = ET.parse(PROFILE).getroot()
    participant = root.find("p:participant", _NS)
    assert participant is not None and participant.get("is_default_profile") == "true"
    lease = participant.find("p:rtps/p:builtin/p:discovery_config/p:leaseAnnouncement", _NS)
    assert lease is not None
    sec = int(lease.findtext("p:sec", namespaces=_NS) or "")
    nanosec = int(lease.findtext("p:nanosec", namespaces=_NS) or "")
    assert sec + nanosec / 1e9 == ANNOUNCEMENT_PERIOD_S == 0.5


def test_it_names_the_profile_for_both_fast_dds_versions_unless_one_is_set() -> None:
    env: dict[str, str] = {"ROS_DOMAIN_ID": "7"}
    assert use_fast_discovery(env) is True
    assert {name: env[name] for name in PROFILE_ENVS} == dict.fromkeys(PROFILE_ENVS, str(PROFILE))
    assert use_fast_discovery(env) is False  # set already: unchanged
    for name in PROFILE_ENVS:
        mine = {name: "/etc/my_profile.xml"}
        assert use_fast_discovery(mine) is False and mine == {name: "/etc/my_profile.xml"}
    empty = dict.fromkeys(PROFILE_ENVS, "")  # set but empty: as unset
    assert use_fast_discovery(empty) is True and empty[PROFILE_ENVS[0]] == str(PROFILE)


def test_an_installation_without_the_profile_keeps_fast_dds_defaults(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    monkeypatch.setattr(discovery, "PROFILE", tmp_path / "missing.xml")
    env: dict[str, str] = {}
    assert discovery.use_fast_discovery(env) is False and env == {}


@pytest.mark.rclpy
def test_an_rclpy_port_names_the_profile_in_its_process_environment(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from bridge.ros.rosport import open_port

    for name in PROFILE_ENVS:
        monkeypatch.delenv(name, raising=False)
    with open_port("rclpy", node_name="discovery_probe"):
        assert [os.environ.get(name) for name in PROFILE_ENVS] == [str(PROFILE)] * 2
