"""What the ROS 2 bridge takes in (``cmd_vel_in``) and what it serves on demand, in-process on
real zenoh sessions: fuzzed samples are refused, counted and never voted; the bridge keeps
running; the camera goes out only while a ROS subscriber's token says someone listens."""

from __future__ import annotations

import math
import struct

import pytest
import zenoh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from rosbags.typesys import Stores, get_typestore
from zenoh_ros2_sdk.entity import EndpointEntity, EntityKind, NodeEntity
from zenoh_ros2_sdk.keyexpr import endpoint_liveliness_keyexpr

from tests.conftest import eventually, zenoh_session
from ubf_async.runtime.bus import Bus
from ubf_async.services.ros2 import keys as rk
from ubf_async.services.ros2.bridge import Ros2Bridge, Ros2Settings
from ubf_async.wire.protocol import decode
from ubf_async.wire.topics import CAMERA, CAMERA_VIEW

HEADER = b"\x00\x01\x00\x00"
GID = bytes(range(16))


def twist_cdr(*values: float) -> bytes:
    """A Twist as CDR, packed by hand: the header, then six little-endian doubles."""
    return HEADER + struct.pack("<6d", *values)


GOOD = twist_cdr(0.1, 0.0, 0.0, 0.0, 0.0, 0.5)
ATTACHMENT = struct.pack("<qqB16s", 1, 1, 16, GID)


async def started(bus: Bus) -> Ros2Bridge:
    bridge = Ros2Bridge(bus=bus, settings=Ros2Settings(composite="root"))
    await bridge.start()
    await eventually(bridge.ready.is_set, what="the bridge to start")
    return bridge


def bad_samples(key: str) -> st.SearchStrategy[tuple[str, bytes, bytes | None]]:
    prefix = key.rsplit("/", 1)[0]
    non_finite = st.sampled_from([math.nan, math.inf, -math.inf])
    finite = st.floats(allow_nan=False, allow_infinity=False)
    return st.one_of(
        # random bytes (never a 52-byte little-endian CDR: those are the next cases')
        st.binary(max_size=200).filter(lambda b: len(b) != 52 or b[:4] != HEADER).map(
            lambda b: (key, b, ATTACHMENT)),
        # truncated, or with more bytes after the message than CDR's alignment padding (up
        # to 3, which rosbags accepts as XCDR1 allows)
        st.integers(0, 51).map(lambda n: (key, GOOD[:n], ATTACHMENT)),
        st.binary(min_size=4, max_size=16).map(lambda b: (key, GOOD + b, ATTACHMENT)),
        # big-endian or other CDR headers
        st.binary(min_size=4, max_size=4).filter(lambda h: h != HEADER).map(
            lambda h: (key, h + GOOD[4:], ATTACHMENT)),
        # a wrong hash segment, or another type
        st.from_regex(r"\A(RIHS01_[0-9a-f]{64}|TypeHashNotSupported|[A-Za-z0-9_]{1,20})\Z"
                      ).filter(lambda h: h != key.rsplit("/", 1)[1]).map(
            lambda h: (f"{prefix}/{h}", GOOD, ATTACHMENT)),
        st.just((key.replace("Twist_", "TwistStamped_"), GOOD, ATTACHMENT)),
        # no attachment, one of the wrong length, a GID length that is not 16
        st.one_of(st.none(), st.binary(max_size=64).filter(lambda b: len(b) != 33)).map(
            lambda a: (key, GOOD, a)),
        st.integers(0, 255).filter(lambda n: n != 16).map(
            lambda n: (key, GOOD, struct.pack("<qqB16s", 1, 1, n, GID))),
        # a field that is not finite
        st.tuples(st.integers(0, 5), non_finite, st.lists(finite, min_size=6, max_size=6)).map(
            lambda t: (key, twist_cdr(*[t[1] if i == t[0] else v for i, v in enumerate(t[2])]),
                       ATTACHMENT)),
    )


@pytest.mark.asyncio
async def test_fuzzed_inbound_samples_are_refused_counted_and_never_voted(
        robot_bus: Bus) -> None:
    bridge = await started(robot_bus)
    try:
        @settings(max_examples=400, deadline=None,
                  suppress_health_check=[HealthCheck.function_scoped_fixture])
        @given(sample=bad_samples(bridge.in_key))
        def refused(sample: tuple[str, bytes, bytes | None]) -> None:
            before = (bridge.votes, sum(bridge.inbound.refused.values()))
            assert bridge.handle_twist_sample(*sample) is False
            assert bridge.votes == before[0]
            assert sum(bridge.inbound.refused.values()) == before[1] + 1

        refused()
        assert set(bridge.inbound.refused) == {"cdr", "hash", "attachment"}
        assert bridge.running.is_set() and bridge.restarts == 0
        assert bridge.handle_twist_sample(bridge.in_key, GOOD, ATTACHMENT) is True
        assert bridge.votes == 1
    finally:
        await bridge.aclose()


@pytest.mark.asyncio
async def test_samples_from_another_session_are_refused_or_voted(
        robot_bus: Bus, peer_bus: Bus) -> None:
    bridge = await started(robot_bus)
    votes: list[object] = []
    robot_bus.subscribe(f"{robot_bus.keys.prefix}/vote/root/teleop",
                        lambda key, payload, received_ns: votes.append(decode(payload)))
    try:
        session = zenoh_session(peer_bus)
        hashless = bridge.in_key.rsplit("/", 1)[0] + "/TypeHashNotSupported"
        publishers = {key: session.declare_publisher(key) for key in (bridge.in_key, hashless)}
        # Declarations travel asynchronously: put only once the bridge's subscriber is known.
        await eventually(lambda: all(p.matching_status.matching for p in publishers.values()),
                         timeout_s=10, what="the peer to know the bridge's subscriber")
        for key, payload, attachment in ((bridge.in_key, GOOD, None),
                                         (hashless, GOOD, ATTACHMENT),
                                         (bridge.in_key, GOOD[:30], ATTACHMENT),
                                         (bridge.in_key, twist_cdr(math.nan, 0, 0, 0, 0, 0),
                                          ATTACHMENT)):
            publishers[key].put(payload, attachment=attachment)
        await eventually(lambda: sum(bridge.inbound.refused.values()) == 4, timeout_s=10,
                         what="four refusals")
        assert bridge.inbound.refused == {"attachment": 1, "hash": 1, "cdr": 2}
        assert votes == [] and bridge.votes == 0
        publishers[bridge.in_key].put(GOOD, attachment=ATTACHMENT)  # 0.1 m/s, 0.5 rad/s
        await eventually(lambda: len(votes) == 1, timeout_s=10, what="the vote")
        vote = votes[0].data  # type: ignore[attr-defined]
        units = bridge.settings.units  # the simulated robot's: 0.34 m/s, 1.62 rad/s at 100
        assert (vote.speed, vote.turn, vote.ttl_s) == pytest.approx(
            (100 * 0.1 / units.max_linear_m_s, 100 * 0.5 / units.max_angular_rad_s, 0.5))
    finally:
        await bridge.aclose()


@pytest.mark.asyncio
async def test_the_camera_goes_out_only_while_a_ros_subscriber_exists(
        robot_bus: Bus, peer_bus: Bus) -> None:
    bridge = await started(robot_bus)
    camera = robot_bus.publisher(CAMERA, "front")
    view = robot_bus.publisher(CAMERA_VIEW, "front")
    store = get_typestore(Stores.ROS2_JAZZY)
    images: list[tuple[object, bytes]] = []
    try:
        camera.publish({"bins": [0, 1, 2, 3, 4], "total": 10})
        topic = f"/{robot_bus.robot}/camera/front/image/compressed"
        await eventually(lambda: any(p.topic == topic for p in bridge._pubs.values()),
                         what="the camera's ROS publisher")
        assert not view.has_subscribers()  # nobody on the ROS side: no view asked for
        ros_type = "sensor_msgs/msg/CompressedImage"
        data_key = rk.data_key(0, topic, ros_type, store.hash_rihs01(ros_type))

        def on_image(sample: zenoh.Sample) -> None:
            attachment = sample.attachment
            images.append((store.deserialize_cdr(sample.payload.to_bytes(), ros_type),
                           b"" if attachment is None else attachment.to_bytes()))

        session = zenoh_session(peer_bus)
        sub = session.declare_subscriber(data_key, on_image)
        node = NodeEntity(domain_id=0, session_id=str(session.info.zid()), node_id=7,
                          node_name="viewer", namespace="/")
        token = session.liveliness().declare_token(endpoint_liveliness_keyexpr(
            EndpointEntity(node=node, entity_id=8, kind=EntityKind.SUBSCRIPTION, name=topic,
                           dds_type_name="sensor_msgs::msg::dds_::CompressedImage_",
                           type_hash=store.hash_rihs01(ros_type), qos="::,10:,:,:,,")))
        await eventually(view.has_subscribers, timeout_s=10,
                         what="the bridge asking for the camera's view")
        jpeg = b"\xff\xd8 not really a jpeg \xff\xd9"
        view.publish({"format": "jpeg", "data": jpeg, "width": 4, "height": 3,
                      "bins": [0, 1, 2, 3, 4]})
        await eventually(lambda: len(images) == 1, timeout_s=10, what="the CompressedImage")
        image, attachment = images[0]
        assert image.format == "jpeg" and bytes(image.data) == jpeg  # type: ignore[attr-defined]
        assert image.header.frame_id == "camera_front"  # type: ignore[attr-defined]
        assert len(attachment) == 33 and attachment[16] == 16
        token.undeclare()
        await eventually(lambda: not view.has_subscribers(), timeout_s=10,
                         what="the bridge letting the view go")
        sub.undeclare()
    finally:
        await bridge.aclose()
