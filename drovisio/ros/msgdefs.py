"""ROS 2 message definitions (the ``.msg`` text), concatenated as ROS 2 bags store them.

A schema's text is its own definition followed, for every type it uses, by a line of 80
``=`` and ``MSG: package/Type`` and that type's definition (the form ``ros2 bag`` writes into
MCAP files and that Foxglove, ``rosbags`` and ``mcap-ros2-support`` read). Field names,
types, array bounds and constants follow ROS 2 Humble's ``std_msgs``, ``geometry_msgs``,
``sensor_msgs``, ``tf2_msgs`` and ``vision_msgs`` (4.x: ``Detection3D`` has ``string id``,
hypotheses are ``ObjectHypothesis``). Comments are left out: they do not change the encoding.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

__all__ = ["DEFINITIONS", "encoder", "decoder", "schema_text"]

_SEP = "=" * 80

#: Every definition used, by full name (``package/msg/Type`` is normalised to ``package/Type``).
DEFINITIONS: dict[str, str] = {
    "builtin_interfaces/Time": "int32 sec\nuint32 nanosec\n",
    "std_msgs/Header": "builtin_interfaces/Time stamp\nstring frame_id\n",
    "std_msgs/String": "string data\n",
    "geometry_msgs/Point": "float64 x\nfloat64 y\nfloat64 z\n",
    "geometry_msgs/Vector3": "float64 x\nfloat64 y\nfloat64 z\n",
    "geometry_msgs/Quaternion": "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n",
    "geometry_msgs/Pose": "Point position\nQuaternion orientation\n",
    "geometry_msgs/PoseWithCovariance": "Pose pose\nfloat64[36] covariance\n",
    "geometry_msgs/PoseWithCovarianceStamped": "std_msgs/Header header\nPoseWithCovariance pose\n",
    "geometry_msgs/Transform": "Vector3 translation\nQuaternion rotation\n",
    "geometry_msgs/TransformStamped": "std_msgs/Header header\nstring child_frame_id\n"
                                      "Transform transform\n",
    "tf2_msgs/TFMessage": "geometry_msgs/TransformStamped[] transforms\n",
    "sensor_msgs/CompressedImage": "std_msgs/Header header\nstring format\nuint8[] data\n",
    "sensor_msgs/RegionOfInterest": "uint32 x_offset\nuint32 y_offset\nuint32 height\n"
                                    "uint32 width\nbool do_rectify\n",
    "sensor_msgs/CameraInfo": "std_msgs/Header header\nuint32 height\nuint32 width\n"
                              "string distortion_model\nfloat64[] d\nfloat64[9] k\n"
                              "float64[9] r\nfloat64[12] p\nuint32 binning_x\n"
                              "uint32 binning_y\nRegionOfInterest roi\n",
    "vision_msgs/ObjectHypothesis": "string class_id\nfloat64 score\n",
    "vision_msgs/ObjectHypothesisWithPose": "ObjectHypothesis hypothesis\n"
                                            "geometry_msgs/PoseWithCovariance pose\n",
    "vision_msgs/BoundingBox3D": "geometry_msgs/Pose center\ngeometry_msgs/Vector3 size\n",
    "vision_msgs/Detection3D": "std_msgs/Header header\nObjectHypothesisWithPose[] results\n"
                               "BoundingBox3D bbox\nstring id\n",
    "vision_msgs/Detection3DArray": "std_msgs/Header header\nDetection3D[] detections\n",
}

_PRIMITIVES = {"bool", "byte", "char", "int8", "uint8", "int16", "uint16", "int32", "uint32",
               "int64", "uint64", "float32", "float64", "string", "wstring"}


def _short(name: str) -> str:
    parts = name.split("/")
    return f"{parts[0]}/{parts[-1]}"


def _deps(name: str) -> list[str]:
    """Types ``name`` uses, depth first, each once (full names)."""
    out: list[str] = []

    def visit(n: str) -> None:
        for line in DEFINITIONS[n].splitlines():
            t = line.split()[0].split("[")[0]
            if t in _PRIMITIVES:
                continue
            full = t if "/" in t else f"{n.split('/')[0]}/{t}"
            if full not in out:
                out.append(full)
                visit(full)

    visit(name)
    return out


@functools.cache
def schema_text(name: str) -> str:
    """The concatenated definition of ``name`` (``pkg/Type`` or ``pkg/msg/Type``)."""
    n = _short(name)
    parts = [DEFINITIONS[n]]
    for d in _deps(n):
        parts.append(f"{_SEP}\nMSG: {d}\n{DEFINITIONS[d]}")
    return "".join(parts)


@functools.cache
def encoder(name: str) -> Callable[[object], bytes]:
    """CDR encoder (little-endian, with its 4-byte encapsulation header) of ``name``; takes
    a dict (or an object) with the message's fields."""
    from mcap_ros2._dynamic import serialize_dynamic

    n = _short(name)
    return serialize_dynamic(n, schema_text(n))[n]


@functools.cache
def decoder(name: str) -> Callable[[bytes], Any]:
    """CDR decoder of ``name`` (returns an object with the fields as attributes)."""
    from mcap_ros2._dynamic import generate_dynamic

    n = _short(name)
    return generate_dynamic(n, schema_text(n))[n]
