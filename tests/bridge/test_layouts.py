"""The RViz config and the Foxglove layout that ship with the package
(``bridge/ros/layouts/``) load, have the structure their tools read, and name only topics
(and message fields) that the stack publishes, with the message types they carry.

- ``rover.rviz``: RViz 2's YAML; its displays are RViz's default plugins; their topics
  are the bridge's (root namespace, its default topic names), its frames the bridge's.
- ``mission.foxglove.json``: a Foxglove layout (``configById`` panels, a ``layout`` tree
  of splits naming them), checked against a JSON Schema of that format; its topics are
  what a mission's recording and ``--foxglove`` serve (the ground station's namespace
  ``ground``: what the link relays down, and the gate's topics), its plot paths fields of
  those messages.
"""

from __future__ import annotations

import importlib
import json
from pathlib import Path
from typing import Any

import fastjsonschema

from bridge.ros.params import BridgeParams
from bridge.ros.rosport import msgs
from planner.ground.relay import DEFAULT_ROUTES
from planner.record.mcaprec import (
    MAP_MARKERS_TOPIC,
    PLAN_MARKERS_TOPIC,
    PREDICTED_TOPIC,
    REJECTED_TOPIC,
    TF_TOPIC,
    VERDICT_TOPIC,
)

ROOT = Path(__file__).resolve().parents[2]
LAYOUTS = ROOT / "bridge" / "ros" / "layouts"

RVIZ_PLUGINS = {
    "rviz_default_plugins/Grid",
    "rviz_default_plugins/TF",
    "rviz_default_plugins/Odometry",
    "rviz_default_plugins/Path",
    "rviz_default_plugins/MarkerArray",
}
"""The RViz 2 display classes the config may use (rviz_default_plugins' names)."""

BRIDGE = BridgeParams()
BRIDGE_TOPICS = {
    f"/{BRIDGE.topic_odom}": "nav_msgs/Odometry",
    f"/{BRIDGE.topic_ground_pose}": "nav_msgs/Odometry",
    TF_TOPIC: "tf2_msgs/TFMessage",
}
"""What a bridge in the root namespace publishes that RViz can draw."""


def _mission_topics() -> dict[str, str]:
    """Topic -> type of a mission's recording and live Foxglove (namespace ``ground``)."""
    topics = {
        f"/ground/{r.topic}": f"{r.msg_type.__module__.split('.')[0]}/{r.msg_type.__name__}"
        for r in DEFAULT_ROUTES
        if not r.uplink
    }
    topics |= {
        PREDICTED_TOPIC: "nav_msgs/Path",
        REJECTED_TOPIC: "nav_msgs/Path",
        VERDICT_TOPIC: "std_msgs/String",
        MAP_MARKERS_TOPIC: "visualization_msgs/MarkerArray",
        PLAN_MARKERS_TOPIC: "visualization_msgs/MarkerArray",
        TF_TOPIC: "tf2_msgs/TFMessage",
    }
    return topics


def test_the_rviz_config_draws_what_the_bridge_publishes() -> None:
    yaml = importlib.import_module("yaml")  # PyYAML: what ROS 2 reads its YAML with
    doc = yaml.safe_load((LAYOUTS / "rover.rviz").read_text())
    manager = doc["Visualization Manager"]
    assert manager["Global Options"]["Fixed Frame"] == BRIDGE.map_frame
    assert {"Panels", "Window Geometry"} <= set(doc)
    displays = manager["Displays"]
    assert {d["Class"] for d in displays} <= RVIZ_PLUGINS
    assert all(isinstance(d["Enabled"], bool) and d["Name"] for d in displays)
    drawn = {d["Topic"]["Value"]: d["Class"] for d in displays if "Topic" in d}
    assert drawn == {
        f"/{BRIDGE.topic_odom}": "rviz_default_plugins/Odometry",
        f"/{BRIDGE.topic_ground_pose}": "rviz_default_plugins/Odometry",
    }
    assert set(drawn) <= set(BRIDGE_TOPICS)
    for display in displays:
        if "Topic" in display:
            # QoS the bridge's publishers match (docs/bridge.md: odom reliable, volatile).
            assert display["Topic"]["Reliability Policy"] == "Reliable"
            assert display["Topic"]["Durability Policy"] == "Volatile"
    assert any(d["Class"] == "rviz_default_plugins/TF" for d in displays)  # /tf


_TREE: dict[str, Any] = {
    "oneOf": [
        {"type": "string", "pattern": "^[A-Za-z0-9]+![A-Za-z0-9_-]+$"},
        {
            "type": "object",
            "required": ["first", "second", "direction"],
            "properties": {
                "first": {"$ref": "#/definitions/tree"},
                "second": {"$ref": "#/definitions/tree"},
                "direction": {"enum": ["row", "column"]},
                "splitPercentage": {"type": "number", "minimum": 0, "maximum": 100},
            },
            "additionalProperties": False,
        },
    ]
}
FOXGLOVE_LAYOUT_SCHEMA: dict[str, Any] = {
    "$schema": "http://json-schema.org/draft-07/schema#",
    "definitions": {"tree": _TREE},
    "type": "object",
    "required": ["configById", "layout", "globalVariables", "userNodes", "playbackConfig"],
    "properties": {
        "configById": {
            "type": "object",
            "propertyNames": {"pattern": "^[A-Za-z0-9]+![A-Za-z0-9_-]+$"},
            "additionalProperties": {"type": "object"},
        },
        "layout": {"$ref": "#/definitions/tree"},
        "globalVariables": {"type": "object"},
        "userNodes": {"type": "object"},
        "playbackConfig": {
            "type": "object",
            "properties": {"speed": {"type": "number", "exclusiveMinimum": 0}},
        },
    },
    "additionalProperties": False,
}
"""Foxglove's layout format as its app exports it: panels by ``Kind!id``, and a tree of
row/column splits whose leaves name them."""


def _leaves(tree: Any) -> list[str]:
    if isinstance(tree, str):
        return [tree]
    return _leaves(tree["first"]) + _leaves(tree["second"])


def _field_type(type_name: str, path: list[str]) -> str:
    """The ROS type of ``path`` (fields) inside ``type_name`` (``pkg/Name``)."""
    package, name = type_name.split("/")
    cls = getattr(__import__(f"{package}.msg", fromlist=[name]), name)
    for i, part in enumerate(path):
        fields = cls.get_fields_and_field_types()
        assert part in fields, f"{type_name} has no field {'.'.join(path[: i + 1])}"
        kind: str = fields[part]
        if "/" not in kind:
            assert i == len(path) - 1, f"{kind} has no fields"
            return kind
        package, name = kind.split("/")
        cls = getattr(__import__(f"{package}.msg", fromlist=[name]), name)
    return f"{package}/{name}"


def test_the_foxglove_layout_has_foxgloves_format_and_the_missions_topics() -> None:
    doc = json.loads((LAYOUTS / "mission.foxglove.json").read_text())
    fastjsonschema.compile(FOXGLOVE_LAYOUT_SCHEMA)(doc)  # raises, naming the path, if not
    panels = doc["configById"]
    assert sorted(_leaves(doc["layout"])) == sorted(panels)  # each panel shown once
    topics = _mission_topics()
    kinds = {key.split("!")[0] for key in panels}
    assert kinds == {"3D", "RawMessages", "DiagnosticSummary", "Plot"}
    for key, config in panels.items():
        kind = key.split("!")[0]
        if kind == "3D":
            assert set(config["topics"]) <= set(topics), set(config["topics"]) - set(topics)
            assert config["followTf"] == BRIDGE.map_frame
            assert config["layers"]["grid"]["frameId"] == BRIDGE.map_frame
        elif kind == "RawMessages":
            assert config["topicPath"] in topics, config["topicPath"]
        elif kind == "DiagnosticSummary":
            assert topics[config["topicToRender"]] == "diagnostic_msgs/DiagnosticArray"
        elif kind == "Plot":
            for path in config["paths"]:
                topic, *fields = path["value"].split(".")
                assert topic in topics, topic
                assert _field_type(topics[topic], fields) == "double", path["value"]
    assert msgs.Odometry is not None  # the generated classes the paths were checked on
