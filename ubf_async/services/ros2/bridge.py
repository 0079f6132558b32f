"""The ROS 2 bridge component: the robot as a node of rmw_zenoh's graph.

Out of the robot (each a ROS publisher with its ``MP`` liveliness token, declared before its
first sample):

===============================  ==============================  ============================
ROS topic (under the namespace)  type                            from
===============================  ==============================  ============================
``cmd_vel``                      ``geometry_msgs/msg/Twist``     ``cmd/drive`` (:class:`Units`)
``odom``                         ``nav_msgs/msg/Odometry``       ``sensor/odometry/<name>``
``range/<name>``                 ``sensor_msgs/msg/Range``       ``sensor/range/<name>``
``camera/<name>/image/compressed`` ``sensor_msgs/msg/CompressedImage`` ``view/camera/<name>``,
                                                                 only while a ROS subscriber
                                                                 exists (its ``MS`` token)
``ubf/trace``                    ``std_msgs/msg/String`` (JSON)  ``trace`` and the camera bins,
                                                                 only while subscribed
``/clock``                       ``rosgraph_msgs/msg/Clock``     ``clock`` (simulated robots)
===============================  ==============================  ============================

Into the robot: ``geometry_msgs/msg/Twist`` on ``cmd_vel_in`` becomes a remote vote in the robot's
``teleop`` slot (:mod:`ubf_async.services.remote`): clamped to ±100, held for ``ttl_s``, given up
at once when the last ROS publisher of ``cmd_vel_in`` leaves. A sample with a wrong type hash, no
or a malformed attachment, bad CDR or a field that is not finite is refused: counted per reason,
logged the first time for each source, never applied.

Stamps: header stamps are the robot clock's — simulated time on a simulated robot (with
``/clock`` for ``use_sim_time``), else the robot host's ``CLOCK_MONOTONIC`` moved onto the
wall clock (ROS time) by one offset taken at start. ``ubf/trace`` says which (``clock``).

Transport: the bridge speaks rmw_zenoh's wire format on the bus's own session, through the
transport seam (:attr:`Bus.connection <ubf_async.runtime.bus.Bus.connection>`: publishers and
subscribers with attachments, liveliness tokens); it never imports zenoh. rmw_zenoh names a node
by its zenoh session, so the bridge needs a transport whose connections have ids (zenoh's).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import threading
import time
from collections import Counter, OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from ubf_async import throttle
from ubf_async.assembly.robotfile import RemoteSlot, Ros2Spec
from ubf_async.core.action import Action
from ubf_async.errors import ConfigurationError, ProtocolError
from ubf_async.net.transport import AsyncDeclaration, Declaration
from ubf_async.runtime.bus import Bus, Publisher, Subscription
from ubf_async.runtime.component import Component
from ubf_async.services.remote import vote_data
from ubf_async.services.ros2 import keys as rk
from ubf_async.services.ros2 import messages as rm
from ubf_async.wire.protocol import decode
from ubf_async.wire.topics import (
    CAMERA,
    CAMERA_VIEW,
    CLOCK,
    DRIVE,
    ODOMETRY,
    RANGE,
    TRACE,
    VOTE,
)

__all__ = ["CLOCK_PERIOD_NS", "DEFAULT_UNITS", "MAX_PENDING", "MAX_SOURCES", "InboundStats",
           "Ros2Bridge", "Ros2Settings", "RosPublisher", "settings_of_spec"]

log = logging.getLogger(__name__)

MAX_PENDING = 64
"""Inbound samples waiting for the event loop; beyond it the newest are dropped (counted)."""
MAX_SOURCES = 256
"""Sources remembered for "logged once per source" (the oldest forgotten first)."""
CLOCK_PERIOD_NS = 10_000_000
"""``/clock`` at most every 10 ms of simulated time (the simulator steps every 5 ms)."""
DEFAULT_UNITS = rm.Units(max_linear_m_s=0.34, max_angular_rad_s=1.62)
"""The simulated Mini-WHEGS, measured (docs/ros2.md, *Units*): 0.34 m/s at speed 100 and
1.62 rad/s at turn 100 (0.17 and 0.81 at 50: linear)."""


@dataclass(frozen=True)
class Ros2Settings:
    """What the bridge is told: the robot file's ``ros2:`` section or the command line."""

    domain_id: int = 0
    distro: str = rm.DEFAULT_DISTRO
    namespace: str | None = None
    """``None``: ``/<robot>``."""
    node: str = "ubf_bridge"
    cmd_vel_in: str = "cmd_vel_in"
    slot: str = "teleop"
    """The remote behaviour the inbound Twist votes as (the robot file's ``remote:`` slot)."""
    composite: str = "seek_pink_ball"
    ttl_s: float = 0.5
    units: rm.Units = DEFAULT_UNITS
    range_fov_rad: float = 0.05
    """The IR beam's full field of view (a GP2Y0A21's is a few degrees)."""
    odom_pose_variance_per_m: tuple[float, float, float] = (0.0025, 0.0025, 0.04)
    """Variance added per metre driven to x, y (m²) and yaw (rad²)…"""
    odom_yaw_variance_per_rad: float = 0.09
    """… and to yaw per radian turned: skid steering slips most when it turns."""

    def __post_init__(self) -> None:
        rk.check_domain_id(self.domain_id)
        rm.typestore(self.distro)  # an unknown distro fails here
        if self.namespace is not None:
            rk.check_name("namespace", self.namespace)
        rk.check_name("node name", "/" + self.node)
        rk.qualify("/x", self.cmd_vel_in)
        if not 0.001 <= self.ttl_s <= 60.0:
            raise ValueError(f"ttl_s must be within 0.001…60 s, got {self.ttl_s}")

    def namespace_for(self, robot: str) -> str:
        return self.namespace if self.namespace is not None else f"/{robot}"


def settings_of_spec(spec: Ros2Spec, slots: list[RemoteSlot]) -> Ros2Settings:
    """The bridge a robot file's ``ros2:`` section asks for; its Twists vote in the
    composite holding the ``slot`` (:class:`ValueError` when the tree has no such slot)."""
    composite = next((s.composite for s in slots if s.name == spec.slot), None)
    if composite is None:
        raise ValueError(f"ros2: slot {spec.slot!r} is not a `remote:` slot of the tree "
                         f"(slots: {', '.join(s.key for s in slots) or 'none'})")
    return Ros2Settings(
        domain_id=spec.domain_id, distro=spec.distro, namespace=spec.namespace, node=spec.node,
        cmd_vel_in=spec.cmd_vel_in, slot=spec.slot, composite=composite, ttl_s=spec.ttl_s,
        units=rm.Units(spec.max_linear_m_s, spec.max_angular_rad_s))


class RosPublisher:
    """One ROS publisher: the data key, its ``MP`` token, GID and sequence numbers."""

    def __init__(self, bridge: Ros2Bridge, topic: str, ros_type: str, *,
                 qos: str = rk.DEFAULT_QOS) -> None:
        self.topic = rk.qualify(bridge.namespace, topic)
        self.ros_type = ros_type
        codec = bridge.codec
        self.key = rk.data_key(bridge.settings.domain_id, self.topic, ros_type,
                               codec.hash(ros_type))
        self.gid = rk.new_gid()
        self.seq = 0
        connection = bridge.bus.connection
        self._publisher = connection.declare_attachment_publisher(self.key,
                                                                  encoding=rk.CDR_ENCODING)
        self.token_key = bridge.ros_node.endpoint_token(
            rk.PUBLISHER, bridge.next_entity_id(), self.topic, ros_type, codec.hash(ros_type),
            qos)
        self._token = connection.declare_token(self.token_key)
        self.sent = 0

    def put(self, payload: bytes) -> None:
        self.seq += 1
        self._publisher.put(payload, attachment=rk.attachment(self.seq, time.time_ns(),
                                                              self.gid))
        self.sent += 1

    def close(self) -> None:
        self._token.undeclare()  # (both idempotent, harmless on a closed session)
        self._publisher.undeclare()


@dataclass
class InboundStats:
    accepted: int = 0
    refused: Counter[str] = field(default_factory=Counter)
    """Per reason: ``hash``, ``attachment``, ``cdr``, ``overflow`` (from ROS); ``robot`` (a
    sample of the robot's own that the bridge cannot convert: malformed, a second odometry)."""
    sources: OrderedDict[str, int] = field(default_factory=OrderedDict)
    """Refusals per source (the publisher's GID, else the key)."""


class Ros2Bridge(Component):
    """The robot's topics as ROS 2 topics over rmw_zenoh's wire format (module docstring)."""

    def __init__(self, *, bus: Bus, settings: Ros2Settings | None = None,
                 name: str = "ros2") -> None:
        super().__init__(bus=bus, name=name)
        self.settings = settings or Ros2Settings()
        self.namespace = self.settings.namespace_for(bus.robot)
        self.codec = rm.Codec(self.settings.distro)
        self.inbound = InboundStats()
        self.votes = 0
        self.ros_node: rk.Node
        self._entity_ids = 0
        self._loop: asyncio.AbstractEventLoop | None = None
        self._pending = 0
        self._pending_lock = threading.Lock()
        self._pubs: dict[str, RosPublisher] = {}
        session_id = bus.connection.session_id()
        if session_id is None:
            raise ConfigurationError(f"the ROS 2 bridge names its node by the zenoh session: "
                                     f"this bus runs on {type(bus.transport).__name__}, not on "
                                     f"a zenoh session")
        self.session_id = session_id
        # The robot clock (this host's CLOCK_MONOTONIC, or the robot host's followed from
        # here) onto the wall clock, once: ROS time is wall time.
        self._wall_offset_ns = 0 if bus.clock.is_simulated else (
            time.time_ns() - bus.clock.now_ns())
        self._last_clock_ns: int | None = None
        self._odom_last: tuple[int, float, float, float] | None = None
        self._odom_var = [0.0, 0.0, 0.0]
        self._bins: dict[str, list[int]] = {}
        self._odom_source: str | None = None
        self._ros_subscribers: dict[str, set[str]] = {}
        self._ros_drivers: set[str] = set()
        self._vote_pub: Publisher | None = None
        self._slot_token: Declaration | None = None
        self._last_vote_ns: int | None = None
        self._on_demand_subs: dict[str, Subscription] = {}
        self.in_key = ""
        """The data key of ``cmd_vel_in`` (its Twist type and hash)."""
        self.ready = asyncio.Event()
        """Set once every token and subscription of a run is declared."""

    # -- names -----------------------------------------------------------------------------
    def next_entity_id(self) -> int:
        self._entity_ids += 1
        return self._entity_ids

    def ros_stamp(self, stamp_ns: int) -> int:
        """A robot-clock stamp as a header stamp: simulated time as is, the robot host's
        ``CLOCK_MONOTONIC`` moved onto the wall clock (module docstring)."""
        return stamp_ns + self._wall_offset_ns

    def ros_publisher(self, topic: str, ros_type: str, *, qos: str = rk.DEFAULT_QOS
                      ) -> RosPublisher:
        pub = self._pubs.get(topic)
        if pub is None:
            pub = self._pubs[topic] = RosPublisher(self, topic, ros_type, qos=qos)
            log.info("ROS 2: publishing %s [%s] on %s", pub.topic, ros_type, pub.key)
        return pub

    def ros_publishers(self) -> list[RosPublisher]:
        """The ROS publishers of this run."""
        return list(self._pubs.values())

    # -- run ---------------------------------------------------------------------------------
    async def run(self) -> None:
        self._loop = asyncio.get_running_loop()
        connection = self.bus.connection
        settings = self.settings
        self.ros_node = rk.Node(settings.domain_id, self.session_id, 0, self.namespace,
                                settings.node)
        node_token = connection.declare_token(self.ros_node.token())
        cmd_in = rk.qualify(self.namespace, settings.cmd_vel_in)
        declared: list[Declaration] = [node_token]
        inbound: AsyncDeclaration | None = None
        try:
            # Outbound: declared before any sample flows.
            self.ros_publisher("cmd_vel", rm.TWIST)
            self.ros_publisher("odom", rm.ODOMETRY)
            if self.bus.clock.is_simulated:
                self.ros_publisher("/clock", rm.CLOCK, qos=rk.SENSOR_QOS)
            keys = self.bus.keys
            self.subscribe(DRIVE.key(keys), self._on_drive)
            self.subscribe(ODOMETRY.key_expr(keys), self._on_odometry)
            self.subscribe(RANGE.key_expr(keys), self._on_range, latest=False)
            self.subscribe(CAMERA.key_expr(keys), self._on_camera, latest=False)
            if self.bus.clock.is_simulated:
                self.subscribe(keys.clock, self._on_clock)
            trace = self.ros_publisher("ubf/trace", rm.STRING)
            self._serve_on_demand(trace.topic, rm.STRING,
                                  lambda on: self._toggle(TRACE.key(keys), on, self._on_trace))
            # Inbound: cmd_vel_in's MS token, its data key (any type and hash: a wrong one is
            # seen, and refused), and its ROS publishers' MP tokens.
            twist_hash = self.codec.hash(rm.TWIST)
            declared.append(connection.declare_token(self.ros_node.endpoint_token(
                rk.SUBSCRIPTION, self.next_entity_id(), cmd_in, rm.TWIST, twist_hash)))
            self._vote_pub = self.publisher(VOTE, composite=settings.composite,
                                               behavior=settings.slot)
            self.in_key = rk.data_key(settings.domain_id, cmd_in, rm.TWIST, twist_hash)
            self._in_prefix = f"{settings.domain_id}/{cmd_in.lstrip('/')}/"
            # On the transport's thread (it only copies and hands over); waited for once
            # undeclared, so no call is left to enter Python (AsyncDeclaration.aclose).
            inbound = connection.declare_attachment_subscriber(self._in_prefix + "**",
                                                               self._on_transport_sample)
            declared.append(inbound)
            self.keep(self.bus.watch_liveliness(
                rk.endpoints_of(settings.domain_id, rk.PUBLISHER, cmd_in, rm.TWIST),
                self._on_driver))
            log.info("ROS 2 bridge: node %s/%s on domain %d (%s), %s → vote %s/%s",
                     self.namespace, settings.node, settings.domain_id, settings.distro,
                     cmd_in, settings.composite, settings.slot)
            self.ready.set()
            while True:  # robot time: the slot's votes expire on it too
                await self.bus.clock.sleep(settings.ttl_s / 2)
                self._expire_slot()
        finally:
            self.ready.clear()
            self._release_slot()
            for pub in self._pubs.values():
                pub.close()
            self._pubs.clear()
            self._on_demand_subs.clear()  # closed with the run attempt's other subscriptions
            self._ros_subscribers.clear()
            self._ros_drivers.clear()
            self._vote_pub = None
            for declaration in reversed(declared):
                declaration.undeclare()  # (idempotent, harmless on a closed session)
            if inbound is not None:
                await inbound.aclose()

    # -- outbound ----------------------------------------------------------------------------
    def _on_drive(self, key: str, payload: bytes, received_ns: int) -> None:
        message = self._decode(payload, DRIVE, key)
        if message is None:
            return
        linear, angular = self.settings.units.to_twist(message.data.speed, message.data.turn)
        self._pubs["cmd_vel"].put(self.codec.twist(linear, angular))

    def _on_odometry(self, key: str, payload: bytes, received_ns: int) -> None:
        message = self._decode(payload, ODOMETRY, key)
        if message is None:
            return
        if self._odom_source is None:
            self._odom_source = key
        elif key != self._odom_source:  # one robot, one odom: the first source keeps it
            self._refuse("robot", key, f"a second odometry source: {self._odom_source} is "
                         "already the robot's odom")
            return
        data = message.data
        linear = angular = 0.0
        last = self._odom_last
        if last is not None and message.stamp_ns > last[0]:
            dt = (message.stamp_ns - last[0]) / 1e9
            dx, dy = data.x_m - last[1], data.y_m - last[2]
            dyaw = math.remainder(data.heading_rad - last[3], math.tau)
            distance = math.hypot(dx, dy)
            linear = (dx * math.cos(data.heading_rad) + dy * math.sin(data.heading_rad)) / dt
            angular = dyaw / dt
            per_m = self.settings.odom_pose_variance_per_m
            self._odom_var[0] += per_m[0] * distance
            self._odom_var[1] += per_m[1] * distance
            self._odom_var[2] += (per_m[2] * distance
                                  + self.settings.odom_yaw_variance_per_rad * abs(dyaw))
        self._odom_last = (message.stamp_ns, data.x_m, data.y_m, data.heading_rad)
        self._pubs["odom"].put(self.codec.odometry(
            self.ros_stamp(message.stamp_ns), x_m=data.x_m, y_m=data.y_m,
            heading_rad=data.heading_rad, linear_x=linear, angular_z=angular,
            pose_variance=self._odom_var,
            # The wheels' speeds from edges 20 ms apart: ~5 cm/s and ~0.3 rad/s (1 σ).
            twist_variance=(0.0025, 0.0025, 0.09)))

    def _on_range(self, key: str, payload: bytes, received_ns: int) -> None:
        message = self._decode(payload, RANGE, key)
        if message is None:
            return
        name = key.rsplit("/", 1)[-1]
        data = message.data
        min_m = (data.min_mm or 0.0) / 1000.0
        max_m = data.max_mm / 1000.0 if data.max_mm is not None else math.inf
        if data.status == "ok" and data.range_mm is not None:
            value = data.range_mm / 1000.0
        else:
            value = -math.inf if data.status == "too_close" else math.inf
        self.ros_publisher(f"range/{name}", rm.RANGE, qos=rk.SENSOR_QOS).put(self.codec.range(
            self.ros_stamp(message.stamp_ns), frame_id=f"range_{name}", range_m=value,
            min_m=min_m, max_m=max_m, field_of_view_rad=self.settings.range_fov_rad))

    def _on_camera(self, key: str, payload: bytes, received_ns: int) -> None:
        message = self._decode(payload, CAMERA, key)
        if message is None:
            return
        name = key.rsplit("/", 1)[-1]
        self._bins[name] = list(message.data.bins)
        topic = f"camera/{name}/image/compressed"
        if topic not in self._pubs:
            pub = self.ros_publisher(topic, rm.COMPRESSED_IMAGE, qos=rk.SENSOR_QOS)
            view = CAMERA_VIEW.key(self.bus.keys, name)
            self._serve_on_demand(pub.topic, rm.COMPRESSED_IMAGE, lambda on: self._toggle(
                view, on, lambda k, p, r: self._on_view(topic, name, k, p)))

    def _on_view(self, topic: str, name: str, key: str, payload: bytes) -> None:
        message = self._decode(payload, CAMERA_VIEW, key)
        pub = self._pubs.get(topic)
        if message is None or pub is None:
            return
        pub.put(self.codec.compressed_image(
            self.ros_stamp(message.stamp_ns), frame_id=f"camera_{name}",
            image_format=message.data.format, data=message.data.data))

    def _on_trace(self, key: str, payload: bytes, received_ns: int) -> None:
        message = self._decode(payload, TRACE, key)
        pub = self._pubs.get("ubf/trace")
        if message is None or pub is None:
            return
        nodes = [{k: v for k, v in (("name", n.name), ("depth", n.depth), ("won", n.won),
                                     ("speed", n.speed), ("turn", n.turn), ("vote", n.vote),
                                     ("fault", n.fault)) if v is not None}
                 for n in message.data.nodes]
        pub.put(self.codec.json({
            "stamp_ns": self.ros_stamp(message.stamp_ns),
            "clock": "sim" if self.bus.clock.is_simulated else "wall",
            "tick": message.data.tick, "nodes": nodes, "camera_bins": self._bins}))

    def _on_clock(self, key: str, payload: bytes, received_ns: int) -> None:
        message = self._decode(payload, CLOCK, key)
        if message is None:
            return
        if self._last_clock_ns is not None and (
                0 <= message.stamp_ns - self._last_clock_ns < CLOCK_PERIOD_NS):
            return
        self._last_clock_ns = message.stamp_ns
        self._pubs["/clock"].put(self.codec.clock(message.stamp_ns))

    def _decode(self, payload: bytes, topic: Any, key: str) -> Any:
        try:
            return decode(payload, topic=topic)
        except ProtocolError as exc:
            self._refuse("robot", key, f"not a valid {topic.schema} sample: {exc}")
            return None

    # -- on-demand topics (while a ROS subscriber exists) ------------------------------------
    def _serve_on_demand(self, topic: str, ros_type: str, toggle: Callable[[bool], None]
                         ) -> None:
        self._ros_subscribers[topic] = set()

        def on_change(key: str, alive: bool) -> None:
            subscribers = self._ros_subscribers.get(topic)
            if subscribers is None:
                return
            before = bool(subscribers)
            (subscribers.add if alive else subscribers.discard)(key)
            if bool(subscribers) != before:
                log.info("ROS 2: %s now %s", topic, "subscribed" if subscribers else
                         "without subscribers")
                toggle(bool(subscribers))

        self.keep(self.bus.watch_liveliness(
            rk.endpoints_of(self.settings.domain_id, rk.SUBSCRIPTION, topic, ros_type),
            on_change))

    def _toggle(self, key: str, on: bool, handler: Any) -> None:
        name = f"on demand {key}"
        if on:
            if name not in self._on_demand_subs:
                self._on_demand_subs[name] = self.subscribe(key, handler)
        else:
            sub = self._on_demand_subs.pop(name, None)
            if sub is not None:
                sub.close()

    # -- inbound -----------------------------------------------------------------------------
    def _on_transport_sample(self, key: str, payload: bytes, attachment: bytes | None) -> None:
        """On the transport's thread: bound, hand to the loop."""
        loop = self._loop
        if loop is None:
            return
        with self._pending_lock:
            if self._pending >= MAX_PENDING:
                self.inbound.refused["overflow"] += 1
                return
            self._pending += 1
        with contextlib.suppress(RuntimeError):  # the loop is closing
            loop.call_soon_threadsafe(self._on_sample, key, payload, attachment)

    def _on_sample(self, key: str, payload: bytes, attachment: bytes | None) -> None:
        with self._pending_lock:
            self._pending -= 1
        self.handle_twist_sample(key, payload, attachment)

    def handle_twist_sample(self, key: str, payload: bytes, attachment: bytes | None) -> bool:
        """Check one sample of ``cmd_vel_in`` and vote it (on the loop). Returns whether it
        was applied; a refused one is counted and logged the first time for its source."""
        source = key
        if key != self.in_key:
            rest = key[len(self._in_prefix):] if key.startswith(self._in_prefix) else key
            self._refuse("hash", source, f"{rest!r} is not {rk.dds_type(rm.TWIST)}/"
                         f"{self.codec.hash(rm.TWIST)} ({self.settings.distro})")
            return False
        try:
            meta = rk.parse_attachment(attachment)
        except ProtocolError as exc:
            self._refuse("attachment", source, str(exc))
            return False
        source = meta.gid.hex()
        try:
            lx, _ly, _lz, _ax, _ay, az = self.codec.read_twist(payload)
        except ProtocolError as exc:
            self._refuse("cdr", source, str(exc))
            return False
        speed, turn = self.settings.units.to_drive(lx, az)
        self._vote(speed, turn)
        self.inbound.accepted += 1
        return True

    def _refuse(self, reason: str, source: str, detail: str) -> None:
        stats = self.inbound
        stats.refused[reason] += 1
        n = stats.sources.pop(source, 0) + 1
        stats.sources[source] = n
        if len(stats.sources) > MAX_SOURCES:
            stats.sources.popitem(last=False)
        if n == 1 or throttle.first_and_every(n):
            log.warning("ROS 2 bridge refuses a sample from %s (%s, %d so far): %s",
                        source, reason, n, detail)

    def _vote(self, speed: float, turn: float) -> None:
        if self._slot_token is None:
            self._slot_token = self.bus.declare_token(self.bus.keys.alive(self.settings.slot))
        assert self._vote_pub is not None
        self._vote_pub.publish(vote_data(Action(speed=speed, turn=turn),
                                         ttl_s=self.settings.ttl_s))
        self._last_vote_ns = self.bus.clock.now_ns()
        self.votes += 1

    def _on_driver(self, key: str, alive: bool) -> None:
        (self._ros_drivers.add if alive else self._ros_drivers.discard)(key)
        if not alive and not self._ros_drivers:
            self._release_slot()

    def _expire_slot(self) -> None:
        last = self._last_vote_ns
        if last is not None and self.bus.clock.now_ns() - last > self.settings.ttl_s * 1e9:
            self._release_slot()

    def _release_slot(self) -> None:
        """Give the slot back: an abstaining vote, then the slot's token goes."""
        if self._slot_token is None:
            return
        if self._vote_pub is not None:
            try:
                self._vote_pub.publish(vote_data(None, ttl_s=self.settings.ttl_s))
            except Exception:  # closing: the token going detaches the vote anyway
                log.debug("abstaining vote not sent", exc_info=True)
        self._slot_token.undeclare()  # (idempotent, harmless on a closed session)
        self._slot_token = None
        self._last_vote_ns = None
