"""RIHS01 type hashes (REP 2016) of our definitions: ROS 2's own values, and rosbags'."""

from __future__ import annotations

import pytest

from drovisio.ros.msgdefs import DEFINITIONS
from drovisio.ros.type_hash import dds_type_name, full_name, rihs01

# as ROS 2 (rosidl) gives them
KNOWN = {
    "std_msgs/msg/String":
        "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18",
    "std_msgs/msg/Header":
        "RIHS01_f49fb3ae2cf070f793645ff749683ac6b06203e41c891e17701b1cb597ce6a01",
    "builtin_interfaces/msg/Time":
        "RIHS01_b106235e25a4c5ed35098aa0a61a3ee9c9b18d197f398b0e4206cea9acf9c197",
}


@pytest.mark.parametrize("name", sorted(KNOWN))
def test_the_hashes_ros2_gives(name):
    assert rihs01(name) == KNOWN[name]


def test_every_type_hashes_as_rosbags_hashes_it():
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    extra = {}
    for n, text in DEFINITIONS.items():
        if n.startswith("vision_msgs"):
            extra.update(get_types_from_msg(text, full_name(n)))
    store.register(extra)
    for n in DEFINITIONS:
        assert rihs01(n) == store.hash_rihs01(full_name(n)), n


def test_dds_type_names():
    assert dds_type_name("vision_msgs/msg/Detection3DArray") == \
        "vision_msgs::msg::dds_::Detection3DArray_"
    assert dds_type_name("std_msgs/String") == "std_msgs::msg::dds_::String_"
