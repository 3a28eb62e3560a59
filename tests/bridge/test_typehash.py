"""The RIHS01 type hashes we advertise are the ones ROS 2 Jazzy computes (REP-2011).

rosbags computes them independently from its own copy of the Jazzy interface
definitions (``Typestore.hash_rihs01``); a wrong constant fails here.
"""

from __future__ import annotations

import re

import pytest
from rosbags.typesys import Stores, get_typestore

from bridge.rosport.msgs import MESSAGE_TYPES

JAZZY = get_typestore(Stores.ROS2_JAZZY)


@pytest.mark.parametrize("ros_type", sorted(MESSAGE_TYPES))
def test_type_hash_constant_matches_rosbags(ros_type: str) -> None:
    cls = MESSAGE_TYPES[ros_type]
    assert re.fullmatch(r"RIHS01_[0-9a-f]{64}", cls.ROS_HASH)
    assert JAZZY.hash_rihs01(ros_type) == cls.ROS_HASH


def test_graph_announcement_hash_matches_rosbags() -> None:
    from bridge.rosport.dds import PARTICIPANT_ENTITIES_INFO_HASH

    assert (
        JAZZY.hash_rihs01("rmw_dds_common/msg/ParticipantEntitiesInfo")
        == PARTICIPANT_ENTITIES_INFO_HASH
    )


def test_string_hash_is_the_one_rosidl_generates() -> None:
    # A fixed anchor besides rosbags: rosidl writes this hash into the generated C type
    # support of std_msgs/msg/String (TYPE_HASH in string__struct.h) on Jazzy.
    assert MESSAGE_TYPES["std_msgs/msg/String"].ROS_HASH == (
        "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
    )
