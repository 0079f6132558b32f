"""CDR payloads and type hashes of the ROS 2 messages the bridge speaks, per distro.

Every payload is made and read by ``rosbags``' type store of the distro
(``get_typestore(Stores.ROS2_JAZZY)``…): ``serialize_cdr`` / ``deserialize_cdr`` (XCDR1,
little-endian, the ``00 01 00 00`` header rmw_zenoh writes) and ``hash_rihs01`` for the type
hash in the data key and the liveliness tokens (Humble has none: ``TypeHashNotSupported``).
The distros differ where ROS changed a message: Humble's ``sensor_msgs/msg/Range`` has no
``variance`` field, Jazzy's and Kilted's have it; the type store of each knows.

Units (REP-103): metres, radians, seconds; x forward, y left, z up; a positive yaw turns
left. The robot's ±100 ``speed``/``turn`` map linearly to ``linear.x`` m/s and ``angular.z``
rad/s through :class:`Units` (the robot file's ``ros2:`` calibration, docs/ros2.md).
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import cache
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from ubf_async import extras
from ubf_async.errors import ProtocolError

if TYPE_CHECKING:
    from rosbags.typesys.store import Typestore

__all__ = ["CDR_HEADER", "CLOCK", "COMPRESSED_IMAGE", "DEFAULT_DISTRO", "DISTROS", "INFRARED",
           "NO_TYPE_HASH", "ODOMETRY", "RANGE", "STRING", "TWIST", "UNKNOWN_COVARIANCE", "Codec",
           "Distro", "Units", "planar_covariance", "type_hash", "typestore"]

Distro = Literal["humble", "jazzy", "kilted"]
DISTROS: tuple[Distro, ...] = ("humble", "jazzy", "kilted")
DEFAULT_DISTRO: Distro = "jazzy"
_STORES: dict[str, str] = {"humble": "ROS2_HUMBLE", "jazzy": "ROS2_JAZZY",
                           "kilted": "ROS2_KILTED"}
"""Each distro's member of rosbags' ``Stores`` (rosbags is the ros2 extra: imported by
:func:`typestore`, which every payload goes through)."""
NO_TYPE_HASH = "TypeHashNotSupported"
CDR_HEADER = b"\x00\x01\x00\x00"
"""XCDR1 (plain CDR), little-endian, no options: what rmw_zenoh writes and reads."""

TWIST = "geometry_msgs/msg/Twist"
ODOMETRY = "nav_msgs/msg/Odometry"
RANGE = "sensor_msgs/msg/Range"
COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"
CLOCK = "rosgraph_msgs/msg/Clock"
STRING = "std_msgs/msg/String"
INFRARED = 1
"""``sensor_msgs/msg/Range.INFRARED``."""
UNKNOWN_COVARIANCE = 1e6
"""A variance that says "not measured" for a planar robot's z, roll and pitch (REP-105 odom
is planar here), large enough that a filter ignores it, finite so every tool reads it."""


@cache
def typestore(distro: str) -> Typestore:
    typesys = extras.require("ros2", "rosbags.typesys", who="the ROS 2 bridge")
    try:
        return typesys.get_typestore(getattr(typesys.Stores, _STORES[distro]))
    except KeyError:
        raise ValueError(f"unknown ROS 2 distro {distro!r}: one of {', '.join(DISTROS)}") from None


@cache
def type_hash(distro: str, ros_type: str) -> str:
    """The hash segment of ``ros_type``'s keys on ``distro``: ``RIHS01_<sha256>`` from Iron
    on, ``TypeHashNotSupported`` on Humble."""
    store = typestore(distro)
    if distro == "humble":
        return NO_TYPE_HASH
    return str(store.hash_rihs01(ros_type))


@dataclass(frozen=True)
class Units:
    """The robot's ±100 drive command in SI units: ``speed`` 100 is ``max_linear_m_s``
    forward, ``turn`` 100 is ``max_angular_rad_s`` to the left (linear in between)."""

    max_linear_m_s: float
    max_angular_rad_s: float

    def __post_init__(self) -> None:
        for name in ("max_linear_m_s", "max_angular_rad_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive number, got {value}")

    def to_twist(self, speed: float, turn: float) -> tuple[float, float]:
        return speed / 100.0 * self.max_linear_m_s, turn / 100.0 * self.max_angular_rad_s

    def to_drive(self, linear_x: float, angular_z: float) -> tuple[float, float]:
        """m/s and rad/s → ±100 speed and turn, clamped (a faster request is full speed)."""
        speed = 100.0 * linear_x / self.max_linear_m_s
        turn = 100.0 * angular_z / self.max_angular_rad_s
        return max(-100.0, min(100.0, speed)), max(-100.0, min(100.0, turn))


class Codec:
    """The messages of one distro: build them from the robot's values, read a Twist."""

    def __init__(self, distro: str) -> None:
        self.distro = distro
        self.store = typestore(distro)
        t = self.store.types
        self._time, self._header = t["builtin_interfaces/msg/Time"], t["std_msgs/msg/Header"]
        self._vector3 = t["geometry_msgs/msg/Vector3"]
        self._range_fields = {name for name, _ in self.store.fielddefs[RANGE][1]}

    def hash(self, ros_type: str) -> str:
        return type_hash(self.distro, ros_type)

    def serialize(self, message: object, ros_type: str) -> bytes:
        return bytes(self.store.serialize_cdr(message, ros_type))

    def stamp(self, stamp_ns: int) -> Any:
        sec, nanosec = divmod(stamp_ns, 1_000_000_000)
        return self._time(sec=sec, nanosec=nanosec)

    def header(self, stamp_ns: int, frame_id: str) -> Any:
        return self._header(stamp=self.stamp(stamp_ns), frame_id=frame_id)

    # -- out -------------------------------------------------------------------------------
    def twist(self, linear_x: float, angular_z: float) -> bytes:
        v = self._vector3
        msg = self.store.types[TWIST](linear=v(x=float(linear_x), y=0.0, z=0.0),
                                      angular=v(x=0.0, y=0.0, z=float(angular_z)))
        return self.serialize(msg, TWIST)

    def odometry(self, stamp_ns: int, *, x_m: float, y_m: float, heading_rad: float,
                 linear_x: float, angular_z: float, pose_variance: Sequence[float],
                 twist_variance: Sequence[float], frame_id: str = "odom",
                 child_frame_id: str = "base_link") -> bytes:
        """``pose_variance``/``twist_variance``: (x, y, yaw) variances; z, roll and pitch
        are not measured (:data:`UNKNOWN_COVARIANCE`)."""
        t = self.store.types
        half = heading_rad / 2.0
        pose = t["geometry_msgs/msg/Pose"](
            position=t["geometry_msgs/msg/Point"](x=float(x_m), y=float(y_m), z=0.0),
            orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=math.sin(half),
                                                          w=math.cos(half)))
        twist = t[TWIST](linear=self._vector3(x=float(linear_x), y=0.0, z=0.0),
                         angular=self._vector3(x=0.0, y=0.0, z=float(angular_z)))
        msg = t[ODOMETRY](
            header=self.header(stamp_ns, frame_id), child_frame_id=child_frame_id,
            pose=t["geometry_msgs/msg/PoseWithCovariance"](
                pose=pose, covariance=planar_covariance(pose_variance)),
            twist=t["geometry_msgs/msg/TwistWithCovariance"](
                twist=twist, covariance=planar_covariance(twist_variance)))
        return self.serialize(msg, ODOMETRY)

    def range(self, stamp_ns: int, *, frame_id: str, range_m: float, min_m: float,
              max_m: float, field_of_view_rad: float, variance: float = 0.0) -> bytes:
        """REP-117: a reading below the minimum is −inf, beyond the maximum +inf.
        ``variance`` (0: unknown) is sent where the distro has the field (not Humble)."""
        fields: dict[str, Any] = dict(
            header=self.header(stamp_ns, frame_id), radiation_type=INFRARED,
            field_of_view=float(field_of_view_rad), min_range=float(min_m),
            max_range=float(max_m), range=float(range_m))
        if "variance" in self._range_fields:
            fields["variance"] = float(variance)
        return self.serialize(self.store.types[RANGE](**fields), RANGE)

    def compressed_image(self, stamp_ns: int, *, frame_id: str, image_format: str,
                         data: bytes) -> bytes:
        msg = self.store.types[COMPRESSED_IMAGE](
            header=self.header(stamp_ns, frame_id), format=image_format,
            data=np.frombuffer(data, dtype=np.uint8))
        return self.serialize(msg, COMPRESSED_IMAGE)

    def clock(self, stamp_ns: int) -> bytes:
        return self.serialize(self.store.types[CLOCK](clock=self.stamp(stamp_ns)), CLOCK)

    def string(self, text: str) -> bytes:
        return self.serialize(self.store.types[STRING](data=text), STRING)

    def json(self, value: Mapping[str, Any]) -> bytes:
        return self.string(json.dumps(value, separators=(",", ":"), allow_nan=False))

    # -- in --------------------------------------------------------------------------------
    def read_twist(self, payload: bytes) -> tuple[float, float, float, float, float, float]:
        """A Twist's six numbers (linear x y z, angular x y z); :class:`ProtocolError` for
        anything but a well-formed little-endian CDR Twist with finite fields."""
        if payload[:4] != CDR_HEADER:
            raise ProtocolError(f"not little-endian XCDR1: header {payload[:4].hex(' ')!r}, "
                                f"expected {CDR_HEADER.hex(' ')}")
        from rosbags.serde import SerdeError  # installed: self.store came from it

        try:
            msg: Any = self.store.deserialize_cdr(payload, TWIST)
        except (SerdeError, ValueError, TypeError, IndexError, KeyError) as exc:
            raise ProtocolError(f"not a CDR {TWIST}: {exc}") from None
        values = (msg.linear.x, msg.linear.y, msg.linear.z,
                  msg.angular.x, msg.angular.y, msg.angular.z)
        if not all(math.isfinite(v) for v in values):
            raise ProtocolError(f"{TWIST} with a field that is not finite: {values}")
        return values


def planar_covariance(variance: Sequence[float]) -> np.ndarray:
    """The 6×6 row-major covariance of (x, y, z, roll, pitch, yaw) for a planar estimate:
    ``variance`` = (x, y, yaw); z, roll and pitch unmeasured."""
    vx, vy, vyaw = (float(v) for v in variance)
    cov = np.zeros(36, dtype=np.float64)
    for i, v in enumerate((vx, vy, UNKNOWN_COVARIANCE, UNKNOWN_COVARIANCE,
                           UNKNOWN_COVARIANCE, vyaw)):
        cov[i * 7] = v
    return cov
