"""rmw_zenoh's names on the wire: data keys, liveliness tokens, attachments, GIDs.

As rmw_zenoh_cpp (``docs/design.md``, ``liveliness_utils.cpp``, ``attachment_helpers.cpp``)
writes them, and zenoh-ros2-sdk / ros-z read them:

* a topic's data key: ``<domain>/<topic without leading slash>/<dds type>/<type hash>``,
  e.g. ``0/mini/cmd_vel/geometry_msgs::msg::dds_::Twist_/RIHS01_9c45…8d2a``;
* a node's liveliness token:
  ``@ros2_lv/<domain>/<zid>/<nid>/<nid>/NN/<enclave>/<namespace>/<node>``;
* a publisher's (``MP``) or subscription's (``MS``):
  ``@ros2_lv/<domain>/<zid>/<nid>/<eid>/MP/<enclave>/<namespace>/<node>/<topic>/<dds type>/
  <type hash>/<qos>``, names mangled (``/`` → ``%``; an empty name is ``%``);
* every published sample carries a 33-byte attachment, ``<qqB16s``: sequence number (+1 per
  sample per publisher), source timestamp in ns, 16 (the GID's length) and the publisher's
  GID.
"""

from __future__ import annotations

import os
import re
import struct
from dataclasses import dataclass

from ubf_async.errors import ProtocolError
from ubf_async.wire.keys import ROS2_ADMIN_SPACE

__all__ = ["ADMIN_SPACE", "ATTACHMENT", "ATTACHMENT_SIZE", "CDR_ENCODING", "DEFAULT_QOS",
           "GID_SIZE", "MAX_DOMAIN_ID", "SENSOR_QOS", "Attachment", "Node", "attachment",
           "check_domain_id", "check_name", "data_key", "dds_type", "endpoints_of", "mangle",
           "new_gid", "parse_attachment", "qualify"]

ADMIN_SPACE = ROS2_ADMIN_SPACE  # (the wire's: a secure set-up grants the same tokens)
NODE, PUBLISHER, SUBSCRIPTION = "NN", "MP", "MS"
GID_SIZE = 16
ATTACHMENT = struct.Struct("<qqB16s")
ATTACHMENT_SIZE = ATTACHMENT.size  # 33
CDR_ENCODING = "application/cdr"
"""The encoding of rmw_zenoh's samples (zenoh's name for it)."""
DEFAULT_QOS = "::,10:,:,:,,"
"""rmw_zenoh's QoS field for the default profile (reliable, volatile, keep last 10): every
field equal to the default is left empty."""
SENSOR_QOS = "2::,5:,:,:,,"
"""``rclcpp::SensorDataQoS``: best effort, keep last 5."""
MAX_DOMAIN_ID = 232
"""ROS 2 domain ids are 0–232 (DDS's port arithmetic; rmw_zenoh keeps the range)."""

_NAME = re.compile(r"^/([A-Za-z_~{][A-Za-z0-9_~{}]*)(/[A-Za-z_][A-Za-z0-9_]*)*$|^/$")


def check_domain_id(domain_id: int) -> int:
    if not 0 <= domain_id <= MAX_DOMAIN_ID:
        raise ValueError(f"a ROS domain id is within 0…{MAX_DOMAIN_ID}, got {domain_id}")
    return domain_id


def check_name(what: str, name: str) -> str:
    """A fully qualified ROS name (``/mini/cmd_vel``); raises :class:`ValueError`."""
    if not _NAME.match(name) or "//" in name:
        raise ValueError(f"{what} {name!r} is not a fully qualified ROS name: '/' then "
                         "segments of letters, digits and '_', not starting with a digit")
    return name


def qualify(namespace: str, topic: str) -> str:
    """``topic`` under ``namespace`` unless it is absolute: ``("/mini", "odom")`` →
    ``/mini/odom``; ``("/mini", "/clock")`` → ``/clock``."""
    if topic.startswith("/"):
        return check_name("topic", topic)
    return check_name("topic", namespace.rstrip("/") + "/" + topic)


def mangle(name: str) -> str:
    """``/mini/odom`` → ``%mini%odom``; the empty name → ``%`` (zenoh keys have no empty
    segments)."""
    return name.replace("/", "%") if name else "%"


def dds_type(ros_type: str) -> str:
    """``geometry_msgs/msg/Twist`` → ``geometry_msgs::msg::dds_::Twist_``."""
    package, kind, name = ros_type.split("/")
    return f"{package}::{kind}::dds_::{name}_"


def data_key(domain_id: int, topic: str, ros_type: str, type_hash: str) -> str:
    return f"{domain_id}/{topic.lstrip('/')}/{dds_type(ros_type)}/{type_hash}"


@dataclass(frozen=True)
class Node:
    """A ROS node as the graph knows it: its session's zid, its id in that session."""

    domain_id: int
    zid: str
    node_id: int
    namespace: str
    name: str
    enclave: str = ""

    def token(self) -> str:
        return (f"{ADMIN_SPACE}/{self.domain_id}/{self.zid}/{self.node_id}/{self.node_id}/"
                f"{NODE}/{mangle(self.enclave)}/{mangle(self.namespace)}/{mangle(self.name)}")

    def endpoint_token(self, kind: str, entity_id: int, topic: str, ros_type: str,
                       type_hash: str, qos: str = DEFAULT_QOS) -> str:
        return (f"{ADMIN_SPACE}/{self.domain_id}/{self.zid}/{self.node_id}/{entity_id}/{kind}/"
                f"{mangle(self.enclave)}/{mangle(self.namespace)}/{mangle(self.name)}/"
                f"{mangle(topic)}/{dds_type(ros_type)}/{type_hash}/{qos}")


def endpoints_of(domain_id: int, kind: str, topic: str, ros_type: str) -> str:
    """Key expression of every ``kind`` (``MP``/``MS``) token of ``topic`` with ``ros_type``,
    whatever its node, hash and QoS."""
    return (f"{ADMIN_SPACE}/{domain_id}/*/*/*/{kind}/*/*/*/{mangle(topic)}/"
            f"{dds_type(ros_type)}/*/*")


def new_gid() -> bytes:
    """A publisher's GID: 16 random bytes (rmw_zenoh hashes its own ids into 16 bytes; only
    uniqueness matters to a receiver)."""
    return os.urandom(GID_SIZE)


def attachment(seq: int, stamp_ns: int, gid: bytes) -> bytes:
    return ATTACHMENT.pack(seq, stamp_ns, GID_SIZE, gid)


@dataclass(frozen=True, slots=True)
class Attachment:
    seq: int
    stamp_ns: int
    gid: bytes


def parse_attachment(raw: bytes | None) -> Attachment:
    """The attachment of a received sample; :class:`ProtocolError` when it is missing or
    is not rmw_zenoh's 33 bytes with a 16-byte GID."""
    if raw is None:
        raise ProtocolError("no attachment (rmw_zenoh sends sequence number, time stamp and "
                            "GID with every sample)")
    if len(raw) != ATTACHMENT_SIZE:
        raise ProtocolError(f"attachment of {len(raw)} bytes, expected {ATTACHMENT_SIZE}")
    seq, stamp_ns, gid_len, gid = ATTACHMENT.unpack(raw)
    if gid_len != GID_SIZE:
        raise ProtocolError(f"attachment's GID length is {gid_len}, expected {GID_SIZE}")
    return Attachment(seq, stamp_ns, gid)
