"""ROS 2 message definitions (.msg text) of the messages `sebvs data export --format mcap`
writes, and the concatenated form MCAP's ros2msg schema encoding wants.

A schema is the message's own .msg text followed, for each type it uses, by a line of 80
'=', a line ``MSG: package/Type`` and that type's text (as rosbag2 writes it); Foxglove,
`ros2 bag` and mcap_ros2 decode a message from this text alone. Field names, types and
order are those of the ROS 2 packages (sensor_msgs, geometry_msgs, tf2_msgs, std_msgs,
builtin_interfaces, and event_camera_msgs of ros-event-camera); comments are left out,
and in-package types are written with their package so no reader has to resolve them.
"""
from __future__ import annotations

import re

SEPARATOR = "=" * 80

# package/Type -> .msg text
DEFINITIONS: dict[str, str] = {
    "builtin_interfaces/Time": "int32 sec\nuint32 nanosec",
    "std_msgs/Header": "builtin_interfaces/Time stamp\nstring frame_id",
    "sensor_msgs/Image": ("std_msgs/Header header\nuint32 height\nuint32 width\n"
                          "string encoding\nuint8 is_bigendian\nuint32 step\nuint8[] data"),
    "geometry_msgs/Vector3": "float64 x\nfloat64 y\nfloat64 z",
    "geometry_msgs/Point": "float64 x\nfloat64 y\nfloat64 z",
    "geometry_msgs/Quaternion": "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1",
    "geometry_msgs/Pose": "geometry_msgs/Point position\ngeometry_msgs/Quaternion orientation",
    "geometry_msgs/PoseStamped": "std_msgs/Header header\ngeometry_msgs/Pose pose",
    "geometry_msgs/Twist": "geometry_msgs/Vector3 linear\ngeometry_msgs/Vector3 angular",
    "geometry_msgs/Transform": ("geometry_msgs/Vector3 translation\n"
                                "geometry_msgs/Quaternion rotation"),
    "geometry_msgs/TransformStamped": ("std_msgs/Header header\nstring child_frame_id\n"
                                       "geometry_msgs/Transform transform"),
    "tf2_msgs/TFMessage": "geometry_msgs/TransformStamped[] transforms",
    # ros-event-camera's packet: events in a sensor encoding, here "mono" (export_mcap.py)
    "event_camera_msgs/EventPacket": ("std_msgs/Header header\nuint32 height\nuint32 width\n"
                                      "uint64 seq\nuint64 time_base\nstring encoding\n"
                                      "bool is_bigendian\nuint8[] events"),
}

_TYPE = re.compile(r"^([A-Za-z_][\w]*/[A-Za-z_]\w*)(\[\d*\])?\s")


def _dependencies(name: str) -> list[str]:
    """Types ``name`` uses, depth first, each once (the order rosbag2 writes them)."""
    seen: list[str] = []

    def visit(n: str) -> None:
        for line in DEFINITIONS[n].splitlines():
            m = _TYPE.match(line)
            if m and m.group(1) not in seen:
                seen.append(m.group(1))
                visit(m.group(1))
    visit(name)
    return seen


def schema_text(name: str) -> str:
    """The concatenated definition of ``name`` ("package/Type" or "package/msg/Type")."""
    short = name.replace("/msg/", "/")
    parts = [DEFINITIONS[short]]
    for dep in _dependencies(short):
        parts.append(f"{SEPARATOR}\nMSG: {dep}\n{DEFINITIONS[dep]}")
    return "\n".join(parts) + "\n"
