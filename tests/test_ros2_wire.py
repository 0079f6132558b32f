"""rmw_zenoh's names and payloads as ubf_async.services.ros2 writes them, read back by
zenoh-ros2-sdk's own parsers (an independent implementation), and the distro differences."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
from rosbags.typesys import Stores, get_typestore
from zenoh_ros2_sdk.attachment import Attachment
from zenoh_ros2_sdk.discovery import _parse_liveliness_keyexpr
from zenoh_ros2_sdk.entity import NodeEntity
from zenoh_ros2_sdk.keyexpr import node_liveliness_keyexpr, topic_keyexpr
from zenoh_ros2_sdk.qos import QosHistoryKind, QosProfile, QosReliability

from ubf_async.assembly.robotfile import RemoteSlot, Ros2Spec
from ubf_async.errors import ProtocolError
from ubf_async.services.ros2 import keys as rk
from ubf_async.services.ros2 import messages as rm
from ubf_async.services.ros2.bridge import settings_of_spec
from ubf_async.tools.ros2 import build_parser, settings_of

TWIST_HASH = "RIHS01_9c45bf16fe0983d80e3cfe750d6835843d265a9a6c46bd2e609fcddde6fb8d2a"


def test_tokens_and_keys_read_back_by_an_independent_parser() -> None:
    node = rk.Node(0, "1f2e3d", 4, "/mini", "ubf_bridge")
    assert node.token() == node_liveliness_keyexpr(NodeEntity(
        domain_id=0, session_id="1f2e3d", node_id=4, node_name="ubf_bridge", namespace="/mini"))
    token = node.endpoint_token(rk.PUBLISHER, 9, "/mini/cmd_vel", rm.TWIST, TWIST_HASH)
    parsed = _parse_liveliness_keyexpr(token)
    assert parsed is not None
    assert {k: parsed[k] for k in ("domain_id", "session_id", "node_id", "entity_id", "kind",
                                   "namespace", "node_name", "qualified_name", "dds_type",
                                   "type_hash", "qos")} == {
        "domain_id": 0, "session_id": "1f2e3d", "node_id": 4, "entity_id": 9, "kind": "MP",
        "namespace": "/mini", "node_name": "ubf_bridge", "qualified_name": "/mini/cmd_vel",
        "dds_type": "geometry_msgs::msg::dds_::Twist_", "type_hash": TWIST_HASH,
        "qos": rk.DEFAULT_QOS}
    assert rk.data_key(0, "/mini/cmd_vel", rm.TWIST, TWIST_HASH) == topic_keyexpr(
        0, "/mini/cmd_vel", "geometry_msgs::msg::dds_::Twist_", TWIST_HASH)
    assert QosProfile.decode(rk.DEFAULT_QOS) == QosProfile()
    sensor = QosProfile.decode(rk.SENSOR_QOS)
    assert (sensor.reliability, sensor.history_kind, sensor.history_depth) == (
        QosReliability.BEST_EFFORT, QosHistoryKind.KEEP_LAST, 5)


def test_attachments_both_ways() -> None:
    gid = bytes(range(16))
    ours = rk.attachment(7, 1_700_000_000_000_000_000, gid)
    assert len(ours) == 33
    theirs = Attachment.from_bytes(ours)
    assert (theirs.sequence_id, theirs.timestamp_ns, theirs.gid) == (
        7, 1_700_000_000_000_000_000, gid)
    back = rk.parse_attachment(Attachment(sequence_id=3, timestamp_ns=5, gid=gid).to_bytes())
    assert (back.seq, back.stamp_ns, back.gid) == (3, 5, gid)
    for bad in (None, b"", ours[:32], ours + b"\0", ours[:16] + b"\x08" + ours[17:]):
        with pytest.raises(ProtocolError):
            rk.parse_attachment(bad)


def test_type_hashes_and_range_layouts_per_distro() -> None:
    assert rm.Codec("humble").hash(rm.TWIST) == "TypeHashNotSupported"
    assert rm.Codec("jazzy").hash(rm.TWIST) == rm.Codec("kilted").hash(rm.TWIST) == TWIST_HASH
    for distro, store, variance in (("humble", Stores.ROS2_HUMBLE, False),
                                    ("jazzy", Stores.ROS2_JAZZY, True),
                                    ("kilted", Stores.ROS2_KILTED, True)):
        payload = rm.Codec(distro).range(2_500_000_000, frame_id="range_front", range_m=0.25,
                                         min_m=0.1, max_m=0.8, field_of_view_rad=0.05)
        assert payload[:4] == b"\x00\x01\x00\x00"
        msg = get_typestore(store).deserialize_cdr(payload, rm.RANGE)
        assert hasattr(msg, "variance") is variance
        assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (2, 500_000_000)
        assert msg.range == pytest.approx(0.25) and msg.radiation_type == 1
    with pytest.raises(ValueError, match="unknown ROS 2 distro"):
        rm.Codec("rolling-2099")


def test_units_map_both_ways_and_clamp() -> None:
    units = rm.Units(0.34, 1.62)
    assert units.to_twist(50, -100) == pytest.approx((0.17, -1.62))
    assert units.to_drive(0.17, -1.62) == pytest.approx((50, -100))
    assert units.to_drive(5.0, 40.0) == (100.0, 100.0)
    with pytest.raises(ValueError):
        rm.Units(0.0, 1.0)
    with pytest.raises(ValueError):
        rm.Units(math.nan, 1.0)


def test_settings_from_the_robot_file_and_the_command_line(
        monkeypatch: pytest.MonkeyPatch) -> None:
    slots = [RemoteSlot("seek_pink_ball", "teleop", 10, 1.0)]
    settings = settings_of_spec(Ros2Spec(distro="humble", domain_id=7), slots)
    assert (settings.composite, settings.slot, settings.distro, settings.domain_id) == (
        "seek_pink_ball", "teleop", "humble", 7)
    assert settings.namespace_for("mini") == "/mini"
    with pytest.raises(ValueError, match="not a `remote:` slot"):
        settings_of_spec(Ros2Spec(slot="nav2"), slots)
    monkeypatch.setenv("ROS_DOMAIN_ID", "42")
    args = build_parser().parse_args(["--namespace", "/fleet/a"])
    cli = settings_of(args)
    assert (cli.domain_id, cli.distro, cli.namespace, cli.units) == (
        42, "jazzy", "/fleet/a", rm.Units(0.34, 1.62))
    with pytest.raises(ValueError):
        settings_of(build_parser().parse_args(["--namespace", "no/leading/slash"]))


def test_a_robot_file_s_ros2_section_is_checked_when_it_loads() -> None:
    from ubf_async.assembly.robotfile import load_robot_text
    from ubf_async.errors import RobotFileError

    shipped = (Path(__file__).resolve().parent.parent / "ubf_async" / "robots" /
               "mini-whegs.yaml").read_text()
    robot = load_robot_text(shipped + "\nros2: {distro: humble, domain_id: 5}\n",
                            source="r.yaml")
    assert robot.spec.ros2 is not None and robot.spec.ros2.distro == "humble"
    at = shipped.count("\n") + 2  # the line of the section (after a blank line)
    for section, error in (
            ("ros2:\n  slot: nav2\n", f"r.yaml:{at + 1}: ros2: slot 'nav2' is not a `remote:`"),
            ("ros2: {distro: iron}\n", f"r.yaml:{at}: Invalid enum value 'iron' (at ros2"),
            ("ros2: {cmd_vel_in: 'bad topic'}\n", f"r.yaml:{at}: Expected `str` matching"),
            ("ros2: {domain_id: 300}\n", f"r.yaml:{at}: Expected `int` <= 232")):
        with pytest.raises(RobotFileError) as info:
            load_robot_text(shipped + "\n" + section, source="r.yaml")
        assert str(info.value).startswith(error), info.value


@pytest.mark.asyncio
async def test_the_bridge_needs_a_zenoh_session() -> None:
    from ubf_async.errors import ConfigurationError
    from ubf_async.net.inprocess import InProcessTransport
    from ubf_async.runtime.bus import Bus
    from ubf_async.services.ros2.bridge import Ros2Bridge

    bus = Bus(transport=InProcessTransport(), robot="unit")
    with pytest.raises(ConfigurationError, match="not on a zenoh session"):
        Ros2Bridge(bus=bus)
    await bus.aclose()
