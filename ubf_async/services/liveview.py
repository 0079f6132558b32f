"""The robot, live, in Foxglove: ``launch --foxglove [PORT]`` or ``python -m ubf_async.liveview``.

A live view subscribes to every key of one robot, turns what it hears into `Foxglove
<https://foxglove.dev>`_ messages and serves them through ``foxglove-sdk``'s WebSocket server
(protocol ``foxglove.sdk.v1``): open ``ws://HOST:PORT`` in Foxglove and load
``docs/foxglove-layout.json``. The same conversion feeds ``--record`` (MCAP files open in
Foxglove with the same layout). Channels (docs/liveview.md):

===========================  =================================  ================================
``/camera/<name>/image``     ``foxglove.CompressedImage``       the camera's view: the pixels
                                                                seekcolor reads, the matches
                                                                and the five bins marked
``/robot/pose``, ``/tf``     ``foxglove.PoseInFrame``,          where the robot truly is (a
                             ``foxglove.FrameTransform``        simulator's ground truth):
                                                                ``world`` → ``base_link``
``/robot/trail``             ``foxglove.SceneUpdate``           the path it took
``/odometry/<name>``         ``foxglove.PoseInFrame``           where its encoders say it is
                                                                (frame ``odom``)
``/ir/<name>``               ``foxglove.SceneUpdate``           each IR beam, as long as its
                                                                reading (frame ``base_link``)
``/arena``                   ``foxglove.SceneUpdate``           walls, obstacles, ball, robot
                                                                (from a simulator's world)
``/ubf/<key>``               JSON                               every other message of the
                                                                robot's keys as
                                                                ``{stamp_ns, seq, data}``:
                                                                ``/ubf/cmd/drive`` (with who
                                                                won), ``/ubf/trace`` (each
                                                                tick's behaviour tree), ...
===========================  =================================  ================================

Converters are objects with a ``convert`` method (:class:`LiveConverter`); besides the
framework's own, packages add theirs under the entry-point group ``ubf_async.live_views`` (the
simulator's arena comes from there). Log times are the robot's clock (simulated time on a
simulated robot). A converter that raises is cut off and logged; the others go on. Nothing on
the event loop decodes an image or draws: the camera sends its view drawn and compressed.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import logging
import math
import threading
from collections import deque
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol

import msgspec

from ubf_async import extras
from ubf_async.assembly.registry import LIVE_VIEWS
from ubf_async.errors import ConfigurationError, ProtocolError
from ubf_async.runtime.bus import Bus
from ubf_async.runtime.component import EveryMessageComponent
from ubf_async.wire.protocol import Message, decode
from ubf_async.wire.topics import BY_SCHEMA, PlainData

if TYPE_CHECKING:
    from foxglove.websocket import ChannelView, Client, ServerListener

__all__ = ["CLIENT_GONE", "CLIENT_LOGGERS", "DEFAULT_HOST", "DEFAULT_PORT", "IR_MOUNT_X_M",
           "NOT_AS_JSON", "ODOM_FRAME", "ROBOT_FRAME", "TRAIL_POINTS", "TRAIL_REFRESH_S",
           "TRAIL_STEP_M", "WORLD_FRAME", "CameraViewConverter", "ClientGoneIsNews",
           "FoxgloveServer", "JsonConverter", "LiveConverter", "LiveMessage",
           "LiveSchema", "LiveView", "LiveViewStats", "OdometryConverter", "RangeConverter",
           "TruthConverter", "foxglove_message", "framework_converters", "layout", "layout_json",
           "pose", "registered_converters", "relative_source", "rgba", "timestamp",
           "yaw_quaternion"]

log = logging.getLogger(__name__)

DEFAULT_PORT = 8765
DEFAULT_HOST = "127.0.0.1"
WORLD_FRAME = "world"
ROBOT_FRAME = "base_link"
ODOM_FRAME = "odom"
TRAIL_POINTS = 2000
TRAIL_STEP_M = 0.01
"""The trail gets a point each time the robot has moved this far."""
TRAIL_REFRESH_S = 1.0
"""A robot standing still has its trail sent again this often (robot time), so a viewer that
connects then still sees the path it took: Foxglove keeps no message for late subscribers."""
IR_MOUNT_X_M = 0.05
"""Where the IR beams start, ahead of ``base_link`` (the Mini-WHEGS's nose)."""
NOT_AS_JSON = frozenset({"camera.view", "clock", "sim.world", "sim.pulses"})
"""Schemas with no JSON channel: images, and what only simulators and tools read at a high
rate."""


# -- what a converter produces ------------------------------------------------------------------

@dataclass(frozen=True, slots=True)
class LiveSchema:
    """A channel's schema as Foxglove and MCAP know it (``encoding``: ``protobuf`` with a
    file descriptor set, or ``jsonschema``)."""

    name: str
    encoding: str
    data: bytes


@dataclass(frozen=True, slots=True)
class LiveMessage:
    """One message for a Foxglove channel: its ``topic``, schema, message encoding
    (``protobuf`` or ``json``) and bytes, logged at ``log_time_ns`` on the robot's clock."""

    topic: str
    schema: LiveSchema
    encoding: str
    data: bytes
    log_time_ns: int


class LiveConverter(Protocol):
    """Turns the robot's messages of some schemas into Foxglove messages.

    ``schemas`` lists the schema names it takes; :meth:`convert` is called for each message of
    them, in the order they arrive, from one thread at a time, with ``source`` the key under
    ``ubf/<robot>/`` (``sensor/range/front``). It may keep state (a trail) and return nothing.
    """

    schemas: frozenset[str]

    def convert(self, source: str, message: Message[Any],
                log_time_ns: int) -> Iterable[LiveMessage]: ...


@functools.cache
def _schema_of(kind: Any) -> LiveSchema:
    schema = kind.get_schema()
    return LiveSchema(name=schema.name, encoding=schema.encoding, data=bytes(schema.data))


def foxglove_message(topic: str, message: Any, log_time_ns: int) -> LiveMessage:
    """A message of ``foxglove.messages`` for ``topic``, protobuf-encoded."""
    kind: Any = type(message)
    return LiveMessage(topic=topic, schema=_schema_of(kind), encoding="protobuf",
                       data=message.encode(), log_time_ns=log_time_ns)


# -- geometry helpers (shared with the converters packages add) --------------------------------

def timestamp(stamp_ns: int) -> Any:
    from foxglove.messages import Timestamp

    return Timestamp(stamp_ns // 1_000_000_000, stamp_ns % 1_000_000_000)


def yaw_quaternion(yaw_rad: float) -> Any:
    from foxglove.messages import Quaternion

    return Quaternion(x=0.0, y=0.0, z=math.sin(yaw_rad / 2), w=math.cos(yaw_rad / 2))


def pose(x_m: float, y_m: float, z_m: float = 0.0, yaw_rad: float = 0.0) -> Any:
    """A ``foxglove.Pose`` on the ground plane, turned ``yaw_rad`` about z."""
    from foxglove.messages import Pose, Vector3

    return Pose(position=Vector3(x=x_m, y=y_m, z=z_m), orientation=yaw_quaternion(yaw_rad))


def rgba(rgb: Sequence[int], alpha: float = 1.0) -> Any:
    """A ``foxglove.Color`` from 0–255 RGB."""
    from foxglove.messages import Color

    return Color(r=rgb[0] / 255, g=rgb[1] / 255, b=rgb[2] / 255, a=alpha)


def relative_source(robot_prefix: str, key: str) -> str | None:
    head = robot_prefix + "/"
    return key[len(head):] if key.startswith(head) else None


# -- the framework's converters ------------------------------------------------------------------

class CameraViewConverter:
    """``view/camera/<name>`` → ``/camera/<name>/image`` (``foxglove.CompressedImage``)."""

    schemas = frozenset({"camera.view"})

    def convert(self, source: str, message: Message[Any],
                log_time_ns: int) -> Iterator[LiveMessage]:
        from foxglove.messages import CompressedImage

        name = source.rsplit("/", 1)[-1]
        view = message.data
        yield foxglove_message(f"/camera/{name}/image", CompressedImage(
            timestamp=timestamp(message.stamp_ns), frame_id=f"camera_{name}", data=view.data,
            format=view.format), log_time_ns)


class TruthConverter:
    """``sim/truth`` → ``/robot/pose``, ``/tf`` (``world`` → ``base_link``) and
    ``/robot/trail`` (a point every :data:`TRAIL_STEP_M`, the last :data:`TRAIL_POINTS`; sent
    when it grows, and at least every :data:`TRAIL_REFRESH_S` of robot time)."""

    schemas = frozenset({"sim.truth"})

    def __init__(self) -> None:
        self.trail: deque[tuple[float, float]] = deque(maxlen=TRAIL_POINTS)
        self._trail_sent_ns: int | None = None

    def convert(self, source: str, message: Message[Any],
                log_time_ns: int) -> Iterator[LiveMessage]:
        from foxglove.messages import (
            FrameTransform,
            LinePrimitive,
            Point3,
            PoseInFrame,
            SceneEntity,
            SceneUpdate,
            Vector3,
        )

        robot = message.data.robot
        stamp = timestamp(message.stamp_ns)
        yield foxglove_message("/robot/pose", PoseInFrame(
            timestamp=stamp, frame_id=WORLD_FRAME,
            pose=pose(robot.x_m, robot.y_m, 0.0, robot.heading_rad)), log_time_ns)
        yield foxglove_message("/tf", FrameTransform(
            timestamp=stamp, parent_frame_id=WORLD_FRAME, child_frame_id=ROBOT_FRAME,
            translation=Vector3(x=robot.x_m, y=robot.y_m, z=0.0),
            rotation=yaw_quaternion(robot.heading_rad)), log_time_ns)
        last = self.trail[-1] if self.trail else None
        if last is None or math.dist(last, (robot.x_m, robot.y_m)) >= TRAIL_STEP_M:
            self.trail.append((robot.x_m, robot.y_m))
        elif (self._trail_sent_ns is not None
              and message.stamp_ns - self._trail_sent_ns < TRAIL_REFRESH_S * 1e9):
            return
        self._trail_sent_ns = message.stamp_ns
        yield foxglove_message("/robot/trail", SceneUpdate(entities=[SceneEntity(
            timestamp=stamp, frame_id=WORLD_FRAME, id="trail", lines=[LinePrimitive(
                thickness=0.008, color=rgba((40, 110, 220)),
                points=[Point3(x=x, y=y, z=0.002) for x, y in self.trail])])]), log_time_ns)


class OdometryConverter:
    """``sensor/odometry/<name>`` → ``/odometry/<name>`` (``foxglove.PoseInFrame``, frame
    ``odom``: the encoders' start pose is its origin)."""

    schemas = frozenset({"odometry"})

    def convert(self, source: str, message: Message[Any],
                log_time_ns: int) -> Iterator[LiveMessage]:
        from foxglove.messages import PoseInFrame

        odom = message.data
        yield foxglove_message(f"/odometry/{source.rsplit('/', 1)[-1]}", PoseInFrame(
            timestamp=timestamp(message.stamp_ns), frame_id=ODOM_FRAME,
            pose=pose(odom.x_m, odom.y_m, 0.0, odom.heading_rad)), log_time_ns)


class RangeConverter:
    """``sensor/range/<name>`` → ``/ir/<name>`` (``foxglove.SceneUpdate`` in ``base_link``):
    the beam from the robot's nose as long as the reading, red; grey to the sensor's maximum
    when nothing is in range; with the reading as text."""

    schemas = frozenset({"range"})

    def __init__(self, *, mount_x_m: float = IR_MOUNT_X_M) -> None:
        self.mount_x_m = mount_x_m

    def convert(self, source: str, message: Message[Any],
                log_time_ns: int) -> Iterator[LiveMessage]:
        from foxglove.messages import (
            LinePrimitive,
            Point3,
            SceneEntity,
            SceneUpdate,
            TextPrimitive,
        )

        reading = message.data
        name = source.rsplit("/", 1)[-1]
        if reading.status == "ok" and reading.range_mm is not None:
            length_m, color, text = reading.range_mm / 1000, (230, 40, 40), \
                f"{reading.range_mm} mm"
        else:
            far = reading.max_mm if reading.status == "too_far" else reading.min_mm
            length_m = (far or 0) / 1000
            color, text = (150, 150, 150), reading.status.replace("_", " ")
        start, end = self.mount_x_m, self.mount_x_m + length_m
        yield foxglove_message(f"/ir/{name}", SceneUpdate(entities=[SceneEntity(
            timestamp=timestamp(message.stamp_ns), frame_id=ROBOT_FRAME, id=f"ir_{name}",
            lines=[LinePrimitive(thickness=0.006, color=rgba(color), points=[
                Point3(x=start, y=0.0, z=0.03), Point3(x=end, y=0.0, z=0.03)])],
            texts=[TextPrimitive(pose=pose(end, 0.0, 0.06), billboard=True, font_size=14.0,
                                 scale_invariant=True, color=rgba(color), text=text)])]),
            log_time_ns)


class JsonConverter:
    """Every declared schema but :data:`NOT_AS_JSON`, and undeclared ones, →
    ``/ubf/<key under the robot>`` as JSON ``{stamp_ns, seq, data}``, with a JSON Schema from
    :mod:`ubf_async.wire.topics` (for plots and raw-message panels)."""

    schemas: frozenset[str] = frozenset()  # every schema: see :meth:`takes`

    def __init__(self) -> None:
        self._schemas: dict[str, LiveSchema] = {}

    @staticmethod
    def takes(schema: str) -> bool:
        return schema not in NOT_AS_JSON

    def _schema(self, name: str) -> LiveSchema:
        found = self._schemas.get(name)
        if found is None:
            topic = BY_SCHEMA.get(name)
            data_type: Any = topic.type if topic is not None else PlainData
            (data,), defs = msgspec.json.schema_components([data_type],
                                                           ref_template="#/$defs/{name}")
            schema: dict[str, Any] = {
                "title": name, "type": "object",
                "properties": {"stamp_ns": {"type": "integer"}, "seq": {"type": "integer"},
                               "data": data},
            }
            if defs:
                schema["$defs"] = defs
            found = LiveSchema(name=f"ubf.{name}", encoding="jsonschema",
                               data=msgspec.json.encode(schema))
            self._schemas[name] = found
        return found

    def convert(self, source: str, message: Message[Any],
                log_time_ns: int) -> Iterator[LiveMessage]:
        body = msgspec.json.encode({"stamp_ns": message.stamp_ns, "seq": message.seq,
                                    "data": message.data})
        yield LiveMessage(topic=f"/ubf/{source}", schema=self._schema(message.schema),
                          encoding="json", data=body, log_time_ns=log_time_ns)


def framework_converters() -> list[LiveConverter]:
    return [CameraViewConverter(), TruthConverter(), OdometryConverter(), RangeConverter()]


def registered_converters() -> list[LiveConverter]:
    """Converters packages register under the ``ubf_async.live_views`` entry points (each a
    callable taking no argument and returning a :class:`LiveConverter`)."""
    found: list[LiveConverter] = []
    for name in LIVE_VIEWS.names():
        try:
            found.append(LIVE_VIEWS.get(name)())
        except Exception as exc:  # a broken plug-in must not take the view down
            log.error("live view %r (%s) could not be loaded: %s", name,
                      LIVE_VIEWS.origin(name), exc)
    return found


class LiveView:
    """Every converter, routed by schema: :meth:`convert` a decoded message, get Foxglove
    messages. Use one per sink (converters keep state) and from one thread at a time."""

    def __init__(self, *, robot_prefix: str,
                 converters: Sequence[LiveConverter] | None = None,
                 as_json: bool = True) -> None:
        self.robot_prefix = robot_prefix
        self.converters = list(converters if converters is not None
                               else [*framework_converters(), *registered_converters()])
        self.json = JsonConverter() if as_json else None
        self.failed: dict[str, str] = {}
        """Converters cut off after raising: name → why."""
        self._routes: dict[str, list[LiveConverter]] = {}
        for converter in self.converters:
            for schema in converter.schemas:
                self._routes.setdefault(schema, []).append(converter)

    def convert(self, key: str, message: Message[Any], log_time_ns: int) -> list[LiveMessage]:
        source = relative_source(self.robot_prefix, key)
        if source is None:
            return []
        out: list[LiveMessage] = []
        converters = list(self._routes.get(message.schema, ()))
        if self.json is not None and self.json.takes(message.schema):
            converters.append(self.json)
        for converter in converters:
            try:
                out.extend(converter.convert(source, message, log_time_ns))
            except Exception as exc:
                self._cut_off(converter, exc)
        return out

    def _cut_off(self, converter: LiveConverter, exc: Exception) -> None:
        name = type(converter).__name__
        self.failed[name] = repr(exc)
        log.exception("live view: %s failed and is cut off: %s", name, exc)
        for routes in self._routes.values():
            with contextlib.suppress(ValueError):
                routes.remove(converter)
        if converter is self.json:
            self.json = None


# -- the Foxglove WebSocket server ---------------------------------------------------------------

@dataclass
class LiveViewStats:
    received: int = 0
    malformed: int = 0
    """Messages that were not valid envelopes (skipped)."""
    logged: int = 0
    """Live messages converted and logged to their Foxglove channel."""
    sent: int = 0
    """Of those, the ones logged while a client subscribed to their channel (the server sends
    a channel's messages only to its subscribers)."""
    clients: set[int] = field(default_factory=set)
    """The clients (ids) that ever subscribed to a channel."""

    def summary(self) -> str:
        """What was served, truthfully: nothing, when no client ever subscribed."""
        if not self.clients:
            return (f"no Foxglove client subscribed: {self.logged} messages converted, none "
                    f"sent")
        return (f"{self.sent} of {self.logged} messages converted went to "
                f"{len(self.clients)} Foxglove client(s)")


class _Subscriptions:
    """Which channels have a subscriber now, as the server tells its listener
    (:meth:`listener`). Written on the SDK's threads, read on the loop: a lock keeps it
    whole."""

    def __init__(self, stats: LiveViewStats) -> None:
        self._lock = threading.Lock()
        self._stats = stats
        self._by_topic: dict[str, set[int]] = {}

    def subscribed(self, topic: str, client: int) -> None:
        with self._lock:
            self._by_topic.setdefault(topic, set()).add(client)
            self._stats.clients.add(client)

    def unsubscribed(self, topic: str, client: int) -> None:
        with self._lock:
            self._by_topic.get(topic, set()).discard(client)

    def watched(self, topic: str) -> bool:
        with self._lock:
            return bool(self._by_topic.get(topic))

    def listener(self) -> ServerListener:
        """The SDK's listener reporting to this (built here: the SDK is imported only by a
        process that serves)."""
        from foxglove.websocket import ServerListener

        subscriptions = self

        class Listener(ServerListener):
            def on_subscribe(self, client: Client, channel: ChannelView) -> None:
                subscriptions.subscribed(channel.topic, client.id)

            def on_unsubscribe(self, client: Client, channel: ChannelView) -> None:
                subscriptions.unsubscribed(channel.topic, client.id)

        return Listener()


CLIENT_LOGGERS = ("foxglove.websocket.connected_client.poller", "foxglove.websocket.server")
"""foxglove-sdk's loggers of what it receives from and sends to each client (a filter on a
logger sees only its own records, not its children's)."""
CLIENT_GONE = ("Connection reset without closing handshake", "Connection reset by peer")
"""How foxglove-sdk says that a viewer went without a goodbye (a closed browser tab): the
WebSocket's words, or the socket's when the reset comes first."""


class ClientGoneIsNews(logging.Filter):
    """foxglove-sdk logs a viewer that went away without the WebSocket's closing handshake
    (a browser tab closed) as an ERROR; it is how viewers leave, so it is said at INFO."""

    def filter(self, record: logging.LogRecord) -> bool:
        if record.levelno > logging.INFO and any(
                words in record.getMessage() for words in CLIENT_GONE):
            record.levelno, record.levelname = logging.INFO, "INFO"
        return True


_CLIENT_GONE_FILTER = ClientGoneIsNews()


class FoxgloveServer(EveryMessageComponent):
    """Serves one robot live to Foxglove (module docstring) on ``host``:``port`` (``port`` 0:
    any free port; :attr:`port` says which once started). Loopback by default: the server has
    no authentication, so bind it wider only on a network you trust."""

    def __init__(self, *, bus: Bus, port: int = DEFAULT_PORT, host: str = DEFAULT_HOST,
                 name: str = "foxglove", view: LiveView | None = None) -> None:
        # The feature's entry: a missing extra is one line before anything starts.
        extras.require("view", "foxglove", who="the live view")
        super().__init__(bus=bus, name=name)
        if not 0 <= port <= 65535:
            raise ConfigurationError(f"--foxglove port must be 0..65535, got {port}")
        self.host = host
        self.requested_port = port
        self.view = view if view is not None else LiveView(robot_prefix=bus.keys.prefix)
        self.stats = LiveViewStats()
        self._subscriptions = _Subscriptions(self.stats)
        self._server: Any = None
        self._context: Any = None
        self._channels: dict[str, Any] = {}

    @property
    def port(self) -> int | None:
        return None if self._server is None else int(self._server.port)

    @property
    def url(self) -> str | None:
        return None if self.port is None else f"ws://{self.host}:{self.port}"

    async def start(self) -> None:
        """Start the WebSocket server, then subscribe. A port in use raises
        :class:`~ubf_async.errors.ConfigurationError` here."""
        if self._server is None and not self.closed:
            import foxglove

            for name in CLIENT_LOGGERS:
                logging.getLogger(name).addFilter(_CLIENT_GONE_FILTER)  # (once)
            self._context = foxglove.Context()
            try:
                self._server = foxglove.start_server(
                    name=f"ubf_async robot {self.bus.robot}", host=self.host,
                    port=self.requested_port, context=self._context,
                    server_listener=self._subscriptions.listener())
            except RuntimeError as exc:
                raise ConfigurationError(
                    f"Foxglove server on {self.host}:{self.requested_port}: {exc}") from None
        await super().start()

    def _on_message(self, key: str, payload: bytes, received_ns: int) -> None:
        self.stats.received += 1
        try:
            message = decode(payload)
        except ProtocolError:
            self.stats.malformed += 1
            return
        for live in self.view.convert(key, message, self.bus.clock.now_ns()):
            self._channel(live).log(live.data, log_time=live.log_time_ns)
            self.stats.logged += 1
            if self._subscriptions.watched(live.topic):
                self.stats.sent += 1

    def _channel(self, live: LiveMessage) -> Any:
        channel = self._channels.get(live.topic)
        if channel is None:
            import foxglove

            channel = foxglove.Channel(
                live.topic, message_encoding=live.encoding, context=self._context,
                schema=foxglove.Schema(name=live.schema.name, encoding=live.schema.encoding,
                                       data=live.schema.data))
            self._channels[live.topic] = channel
        return channel

    async def aclose(self) -> None:
        if self.closed:
            return
        await super().aclose()
        server, self._server = self._server, None
        if server is not None:
            await asyncio.to_thread(server.stop)
        for channel in self._channels.values():
            channel.close()
        self._channels.clear()


# -- the layout ----------------------------------------------------------------------------------

def layout(*, camera: str = "front", range_finder: str = "front") -> Any:
    """The Foxglove layout ``docs/foxglove-layout.json`` is: camera, 3-D scene, drive plot,
    each tick's trace."""
    import foxglove.layouts as fl

    scene = fl.ThreeDeePanel(title="arena", config=fl.ThreeDeeConfig(
        follow_tf=WORLD_FRAME,
        topics={
            "/arena": fl.BaseRendererSceneUpdateTopicSettings(visible=True),
            "/robot/trail": fl.BaseRendererSceneUpdateTopicSettings(visible=True),
            f"/ir/{range_finder}": fl.BaseRendererSceneUpdateTopicSettings(visible=True),
            "/robot/pose": fl.BaseRendererPoseTopicSettings(visible=True, type="arrow"),
        }))
    camera_panel = fl.ImagePanel(title=f"camera {camera}", config=fl.ImageConfig(
        image_mode=fl.ImageModeConfig(image_topic=f"/camera/{camera}/image")))
    drive = fl.PlotPanel(title="drive command", config=fl.PlotConfig(paths=[
        fl.PlotSeries(value="/ubf/cmd/drive.data.speed", label="speed"),
        fl.PlotSeries(value="/ubf/cmd/drive.data.turn", label="turn")]))
    trace = fl.RawMessagesPanel(title="tick trace", config=fl.RawMessagesConfig(
        topic_path="/ubf/trace.data.nodes"))
    winners = fl.RawMessagesPanel(title="drive and who won", config=fl.RawMessagesConfig(
        topic_path="/ubf/cmd/drive.data"))
    return fl.Layout(content=fl.SplitContainer(direction="row", items=[
        fl.SplitItem(proportion=1, content=fl.SplitContainer(direction="column", items=[
            fl.SplitItem(proportion=1, content=camera_panel),
            fl.SplitItem(proportion=1, content=drive)])),
        fl.SplitItem(proportion=1, content=scene),
        fl.SplitItem(proportion=1, content=fl.SplitContainer(direction="column", items=[
            fl.SplitItem(proportion=1, content=winners),
            fl.SplitItem(proportion=2, content=trace)])),
    ]))


def layout_json() -> str:
    """:func:`layout` as the JSON Foxglove imports (indented, one stable form)."""
    import json

    return json.dumps(json.loads(layout().to_json()), indent=2, sort_keys=True) + "\n"
