"""ROS 2 type names and type hashes (RIHS01, REP 2016) from our message definitions.

rmw_zenoh puts the type hash in every key expression
(``<domain>/<topic>/<dds type name>/<type hash>``, :mod:`drovisio.sinks.zenoh`): a subscriber
receives only the samples whose hash equals its own type's. RIHS01 is ``RIHS01_`` + the
SHA-256 of the JSON of the type description (``rosidl_generator_type_description``): the
type's fields (name, type id, capacities, nested type name; default values and comments left
out) and, sorted by name, every type it references; ``json.dumps`` with its default
separators. Checked against the hashes ROS 2 itself gives (``std_msgs/msg/String``,
``std_msgs/msg/Header``, ``builtin_interfaces/msg/Time``) and against ``rosbags`` for every
type (``tests/ros/test_type_hash.py``).
"""

from __future__ import annotations

import functools
import hashlib
import json

from drovisio.ros.msgdefs import DEFINITIONS

__all__ = ["dds_type_name", "full_name", "rihs01"]

#: ``type_description_interfaces/msg/FieldType`` ids of the primitive types.
_TYPE_ID = {"int8": 2, "uint8": 3, "int16": 4, "uint16": 5, "int32": 6, "uint32": 7,
            "int64": 8, "uint64": 9, "float32": 10, "float64": 11, "char": 13, "bool": 15,
            "byte": 16, "string": 17}
_NESTED = 1
_ARRAY, _BOUNDED_SEQUENCE, _SEQUENCE = 48, 96, 144


def full_name(name: str) -> str:
    """``pkg/Type`` or ``pkg/msg/Type`` → ``pkg/msg/Type``."""
    parts = name.split("/")
    return f"{parts[0]}/msg/{parts[-1]}"


def _short(name: str) -> str:
    parts = name.split("/")
    return f"{parts[0]}/{parts[-1]}"


def dds_type_name(name: str) -> str:
    """The type's DDS name, as rmw_zenoh's keys carry it: ``std_msgs::msg::dds_::String_``."""
    pkg, _msg, typ = full_name(name).split("/")
    return f"{pkg}::msg::dds_::{typ}_"


def _fields(name: str) -> list[tuple[str, str, str]]:
    """(field name, base type, array suffix) of a definition (``float64[36] covariance``)."""
    out = []
    for line in DEFINITIONS[_short(name)].splitlines():
        parts = line.split()
        if not parts:
            continue
        typ, field = parts[0], parts[1]
        base, _, rest = typ.partition("[")
        out.append((field, base, "[" + rest if rest else ""))
    return out


def _description(name: str, refs: dict[str, dict]) -> dict:
    pkg = name.split("/")[0]
    fields = []
    for field, base, arr in _fields(name):
        nested = ""
        if base in _TYPE_ID:
            tid = _TYPE_ID[base]
        else:
            nested = full_name(base if "/" in base else f"{pkg}/{base}")
            tid = _NESTED
            if nested not in refs:
                refs[nested] = {}   # placeholder against cycles, filled below
                refs[nested] = _description(nested, refs)
        capacity = 0
        if arr == "[]":
            tid += _SEQUENCE
        elif arr.startswith("[<="):
            tid += _BOUNDED_SEQUENCE
            capacity = int(arr[3:-1])
        elif arr:
            tid += _ARRAY
            capacity = int(arr[1:-1])
        fields.append({"name": field, "type": {"type_id": tid, "capacity": capacity,
                                               "string_capacity": 0,
                                               "nested_type_name": nested}})
    return {"type_name": full_name(name), "fields": fields}


@functools.cache
def rihs01(name: str) -> str:
    """The RIHS01 type hash of a type of :data:`drovisio.ros.msgdefs.DEFINITIONS`."""
    refs: dict[str, dict] = {}
    top = _description(full_name(name), refs)
    refs.pop(full_name(name), None)
    doc = {"type_description": top,
           "referenced_type_descriptions": [refs[k] for k in sorted(refs)]}
    return "RIHS01_" + hashlib.sha256(json.dumps(doc).encode()).hexdigest()
