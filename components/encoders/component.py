"""The encoders component: quadrature phases in, edge counts and odometry out.

Every ``period_s`` (robot clock) it reads the A/B states each encoder went through since the
last read, decodes them (direction from the motors' commanded direction, as the thesis did,
or from the phase order), integrates odometry, and publishes
``sensor/encoders/<name>`` (schema ``encoders``) and ``sensor/odometry/<name>`` (schema
``odometry``). The commanded directions come from the motors' ``motors.applied`` samples
(``sensor/motors/*``); malformed ones are counted and ignored.

A backend that stamps its edges (``encoders.gpio``: ``edge_timing``) also gives each wheel's
speed, ``left_rad_s`` / ``right_rad_s``: the period's decoded edges over the time those edges
took by their stamps (:func:`wheel_speed_rad_s`) — at low speed a period holds a few edges or
none, and edges per period would jump between 0 and a few times the true speed. A period
without edges reads 0 (the wheel turned less than one edge: under 2π/4096 rad per period);
``None`` when the time is not known (a single edge after standing still, dropped edges). Its
dropped edges (``overflowed``) are published as ``dropped``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Annotated, Literal

import msgspec

from components.encoders.backend import EdgeTiming, EncoderBackend
from components.encoders.odometry import EFFECTIVE_TRACK_M, OdometryPose, WheelOdometry
from components.miniwhegs import MINI_WHEGS, MiniWhegsGeometry
from components.quadrature import (
    DirectionMode,
    QuadratureDecoder,
    edges_to_counts,
    edges_to_radians,
)
from ubf_async.assembly.body import DEFAULT_BODY, BodySpec
from ubf_async.clocks.clock import every
from ubf_async.runtime.bus import Bus
from ubf_async.runtime.component import Component
from ubf_async.wire.protocol import Message
from ubf_async.wire.topics import ENCODERS, MOTORS, ODOMETRY, MotorsApplied

__all__ = ["EncodersComponent", "build_device", "wheel_speed_rad_s"]


def wheel_speed_rad_s(edges: int, timing: EdgeTiming,
                      geometry: MiniWhegsGeometry = MINI_WHEGS) -> float | None:
    """A wheel's speed from ``edges`` decoded (signed) edges of one batch and how long the
    batch's edges took; 0 for a batch without edges, ``None`` when the time is unknown."""
    if timing.edges == 0:
        return 0.0
    if timing.span_s is None or not timing.span_s > 0 or timing.intervals <= 0:
        return None
    # ``edges`` is the net of the batch's edges; the span covers ``intervals`` of them.
    per_interval = edges / timing.edges
    return edges_to_radians(per_interval * timing.intervals, geometry) / timing.span_s


class EncodersComponent(Component):
    def __init__(
        self,
        *,
        bus: Bus,
        backend: EncoderBackend,
        name: str = "wheels",
        period_s: float = 0.02,
        mode: DirectionMode = DirectionMode.COMMANDED,
        geometry: MiniWhegsGeometry = MINI_WHEGS,
        initial_states: tuple[int, int] | None = None,
        effective_track_m: float | None = EFFECTIVE_TRACK_M,
        origin: OdometryPose | None = None,
        **component_options: float,
    ) -> None:
        super().__init__(bus=bus, name=f"encoders-{name}", **component_options)
        if not period_s > 0:
            raise ValueError(f"period_s must be > 0, got {period_s}")
        self.source_name = name
        self.backend = backend
        self.period_s = period_s
        self.mode = mode
        self.geometry = geometry
        left0, right0 = initial_states if initial_states is not None else (None, None)
        self.left = QuadratureDecoder(mode=mode, initial_state=left0)
        self.right = QuadratureDecoder(mode=mode, initial_state=right0)
        self.odometry = WheelOdometry(geometry, pose=origin, effective_track_m=effective_track_m)
        self.malformed: dict[str, int] = {}
        self.update_hooks: list[Callable[[], None]] = []
        """Called on the event loop right after each odometry update, before anything else
        runs: a simulator compares the odometry with its world at the very instant the
        wheels were read (the run summary's heading audit). A hook must not block."""

    async def run(self) -> None:
        keys = self.bus.keys
        counts_pub = self.publisher(ENCODERS, self.source_name,
                                    period_s=self.period_s)
        odom_pub = self.publisher(ODOMETRY, self.source_name,
                                  period_s=self.period_s)
        self.subscribe_topic(MOTORS.key_expr(keys), MOTORS, self._on_motors, self.malformed)
        mode = "commanded" if self.mode is DirectionMode.COMMANDED else "phase"
        async for stamp in every(self.bus.clock, self.period_s):
            left_states, right_states = self.backend.read_phases()
            d_left = self.left.feed(left_states)
            d_right = self.right.feed(right_states)
            pose = self.odometry.update(
                edges_to_radians(d_left, self.geometry), edges_to_radians(d_right, self.geometry)
            )
            for hook in self.update_hooks:
                hook()
            counts = {
                "left_edges": self.left.edges, "right_edges": self.right.edges,
                "left_counts": edges_to_counts(self.left.edges, self.geometry),
                "right_counts": edges_to_counts(self.right.edges, self.geometry),
                "errors": self.left.errors + self.right.errors, "mode": mode,
            }
            timing = self.backend.edge_timing
            if timing is not None:  # a backend that stamps its edges
                left_timing, right_timing = timing
                counts["left_rad_s"] = wheel_speed_rad_s(d_left, left_timing, self.geometry)
                counts["right_rad_s"] = wheel_speed_rad_s(d_right, right_timing, self.geometry)
            dropped = self.backend.overflowed
            if dropped is not None:
                counts["dropped"] = int(dropped)
            counts_pub.publish(counts, stamp_ns=stamp)
            odom_pub.publish(
                {"x_m": pose.x_m, "y_m": pose.y_m, "heading_rad": pose.heading_rad},
                stamp_ns=stamp,
            )

    def _on_motors(self, key: str, message: Message[MotorsApplied], received_ns: int) -> None:
        self.left.set_commanded_direction(message.data.left_dir)
        self.right.set_commanded_direction(message.data.right_dir)


def build_device(
    *,
    bus: Bus,
    name: str,
    backend: EncoderBackend,
    period_s: Annotated[float, msgspec.Meta(gt=0)] = 0.02,
    direction: Literal["commanded", "phase"] = "commanded",
    effective_track_m: Annotated[float, msgspec.Meta(gt=0)] | None = None,
    origin_x_m: Annotated[float, msgspec.Meta(ge=-1e4, le=1e4)] | None = None,
    origin_y_m: Annotated[float, msgspec.Meta(ge=-1e4, le=1e4)] | None = None,
    origin_heading_deg: Annotated[float, msgspec.Meta(ge=-360, le=360)] | None = None,
    body: BodySpec = DEFAULT_BODY,
) -> EncodersComponent:
    """The ``encoders`` device kind: reads ``backend`` every ``period_s`` (robot clock),
    publishes ``sensor/encoders/<name>`` and ``sensor/odometry/<name>``.

    ``direction``: ``commanded`` takes each wheel's sign from the motors' command (the
    thesis), ``phase`` decodes it from the A/B phase order. A backend that knows the lines'
    present states (``current_states()``) gives the decoders their start state.
    ``effective_track_m``: the track odometry integrates the heading with — the skid-steer
    robot's effective one, fitted by ``python -m components.encoders.calibrate`` (default: the
    body's ``effective_track_m``, for the simulated Mini-WHEGS ``EFFECTIVE_TRACK_M``; the
    physical 6 cm would read skid turns ≈7× too large). ``body`` (the robot file's, injected):
    the wheels' radius and the encoders' counts the odometry reads.
    ``origin_*``: the pose odometry starts from (unset: the origin — odometry in the robot's
    start frame); a fleet's world sets each robot's start pose in the world where the robot
    file leaves them unset, so the fleet's odometry shares one frame.
    """
    initial = backend.current_states()
    mode = DirectionMode.COMMANDED if direction == "commanded" else DirectionMode.PHASE
    track = body.odometry_track_m if effective_track_m is None else effective_track_m
    return EncodersComponent(bus=bus, backend=backend, name=name, period_s=period_s, mode=mode,
                             geometry=MiniWhegsGeometry.of(body),
                             initial_states=initial, effective_track_m=track,
                             origin=OdometryPose(x_m=origin_x_m or 0.0, y_m=origin_y_m or 0.0,
                                           heading_rad=math.radians(origin_heading_deg or 0.0)))


build_device.publishes_also = (ODOMETRY,)  # type: ignore[attr-defined]
"""Besides ``sensor/encoders/<name>``: the odometry (a secure set-up grants it)."""
