"""The camera component: capture, subsample, seekcolor, publish — off the event loop.

Before the first frame it lets the backend :meth:`~components.camera.backend.CameraBackend.prepare`
(in a worker thread; a simulated clock is held meanwhile). Each cycle stamps the capture time
on the robot clock, tells the backend that instant
(:meth:`~components.camera.backend.CameraBackend.expose`), captures the frame and runs
:func:`~components.camera.seekcolor.seekcolor` in a worker thread (OpenCV and numpy release
the GIL, and the event loop never waits on them), then holds the result until the device's
capture latency has passed (``latency_s``, ≈0.11 s for the OV9655, on the robot clock, so a
simulation running K× faster shortens it K×) and publishes it on ``sensor/camera/<name>``
(schema ``camera.seekcolor``) with ``stamp_ns`` = capture time. The next capture starts right
after, so the camera delivers a frame every ``latency_s``. While anyone subscribes to
``view/camera/<name>`` (a live view, a recorder), the worker thread also draws the frame
(:mod:`components.camera.view`) and it is published there as JPEG, with the same stamp.

With a simulator in the same process, simulated time does not reach the end of the latency
before the frame is ready, and the wake-up at that deadline is booked at the stamp: the
sample comes out exactly at its deadline, in the same order among that instant's events,
however long rendering took — a run is repeatable at any speed.

The colour range counted is the robot file's ``seek_color`` (:class:`SeekColorRange`, written
by ``python -m components.camera.calibrate``), the thesis's pink without one;
``cmd/seek_color`` changes it while the robot runs, the ordering rule (R > B > G) staying as
configured.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import functools
import logging
from typing import Annotated

import msgspec

from components.camera.backend import DEFAULT_MOUNT, CameraBackend, CameraMount
from components.camera.seekcolor import (
    BIN_COUNT,
    DEFAULT_HFOV_DEG,
    MAX_HFOV_DEG,
    MIN_HFOV_DEG,
    PINK,
    ColorRange,
    SeekResult,
    seekcolor,
)
from components.camera.view import DEFAULT_VIEW_SCALE, draw_view, encode_jpeg
from ubf_async.cli import ending
from ubf_async.runtime.bus import Bus, Publisher
from ubf_async.runtime.component import Component
from ubf_async.wire.protocol import Message
from ubf_async.wire.topics import CAMERA, CAMERA_VIEW, SEEK_COLOR, CameraView, SeekColor

__all__ = ["CAPTURE_DRAIN_S", "OV9655_LATENCY_S", "CameraComponent", "CaptureOutcome",
           "SeekColorRange", "build_device"]

OV9655_LATENCY_S = 0.11
CAPTURE_DRAIN_S = 2.0
"""How long a closing camera waits, at most, for a capture in progress to leave its backend."""

CaptureOutcome = tuple[SeekResult, tuple[int, ...], CameraView | None]
"""What one capture gives: the seekcolor result, the frame's shape, the drawn view (if asked)."""

log = logging.getLogger(__name__)


_RENDERS = ending.CallThread(name="ubf-render")
"""Where backends whose capture is CPU work in Python (a simulated camera rendering:
``renders_in_python = True``) capture: one thread for the process, started with the first such
camera and ended with the last, on which their captures take turns. Several renders in
parallel threads only contend for the GIL, and the event loop waits for it too: a fleet's
world with 8 cameras stalled its steps by up to 30 ms (tick jitter p99 30 ms), with one render
thread 5 ms (docs/fleet.md); and a thread per frame costs more than the frame's seekcolor. A
simulated camera may render in a render process (:mod:`components.sim.render.process`) and its
capture here then mostly waits on it; one at a time still suits it: the render process
renders one frame at a time too. A real camera's capture waits on its device and keeps a
thread of its own."""


class CameraComponent(Component):
    def __init__(
        self,
        *,
        bus: Bus,
        backend: CameraBackend,
        name: str = "front",
        latency_s: float = OV9655_LATENCY_S,
        color: ColorRange = PINK,
        hfov_deg: float = DEFAULT_HFOV_DEG,
        view_scale: int = DEFAULT_VIEW_SCALE,
        **component_options: float,
    ) -> None:
        super().__init__(bus=bus, name=f"camera-{name}", **component_options)
        if latency_s < 0:
            raise ValueError(f"latency_s must be ≥ 0, got {latency_s}")
        self.source_name = name
        self.backend = backend
        self._renders = _RENDERS if backend.renders_in_python else None
        self.latency_s = latency_s
        self.color = color
        self.hfov_deg = hfov_deg
        if not 1 <= view_scale <= 8:
            raise ValueError(f"view_scale must be 1..8, got {view_scale}")
        self.view_scale = view_scale
        self.malformed: dict[str, int] = {}
        self.frames = 0
        self.last_frame_shape: tuple[int, ...] | None = None

    def _capture(self, color: ColorRange, *,
                 with_view: bool) -> CaptureOutcome:
        """Runs in a worker thread: capture, seekcolor and, when asked, the drawn view."""
        frame = self.backend.capture()
        result = seekcolor(frame, color, hfov_deg=self.hfov_deg)
        if not with_view:
            return result, frame.shape, None
        image = draw_view(frame, result, color=color, scale=self.view_scale)
        view = CameraView(format="jpeg", data=encode_jpeg(image), width=image.shape[1],
                          height=image.shape[0], bins=result.bins)
        return result, frame.shape, view

    async def run(self) -> None:
        keys = self.bus.keys
        pub = self.publisher(CAMERA, self.source_name,
                             period_s=max(self.latency_s, 0.01))
        view_pub = self.publisher(CAMERA_VIEW, self.source_name,
                                  period_s=max(self.latency_s, 0.01))
        self.subscribe_topic(SEEK_COLOR.key(keys), SEEK_COLOR, self._on_seek_color, self.malformed)
        clock = self.bus.clock
        # Simulated time waits while the backend gets ready, whatever the simulation's speed.
        hold = clock.hold(clock.now_ns())
        try:
            await asyncio.to_thread(self.backend.prepare)
        finally:
            hold.release()
        executor = self._renders.enter() if self._renders is not None else None
        try:
            await self._capture_forever(pub, view_pub, executor)
        finally:
            if self._renders is not None:  # joins its thread when it was the last camera
                await asyncio.to_thread(self._renders.leave)

    async def _capture_forever(self, pub: Publisher, view_pub: Publisher,
                               executor: concurrent.futures.Executor | None) -> None:
        clock = self.bus.clock
        latency_ns = int(self.latency_s * 1e9)
        while True:
            stamp = clock.now_ns()
            deadline = stamp + latency_ns
            # On a simulated clock the frame is taken at the stamp (expose), time does not
            # reach the deadline while it is still being rendered, and the wake-up at the
            # deadline is booked now: so the sample comes out at the deadline, in the same
            # order among that instant's events, however long rendering took. On wall time
            # the hold is a no-op.
            hold = clock.hold(deadline - 1)
            wake = asyncio.ensure_future(clock.sleep_until_ns(deadline))
            self.backend.expose()
            # Drawing and compressing the view costs ≈1 ms: only while someone looks.
            with_view = view_pub.has_subscribers()
            try:
                capture = asyncio.get_running_loop().run_in_executor(
                    executor, functools.partial(self._capture, self.color,
                                                      with_view=with_view))
                result, shape, view = await self._captured(capture)
                hold.release()
                await wake
            finally:
                hold.release()
                wake.cancel()
            self.frames += 1
            self.last_frame_shape = shape
            pub.publish({
                "bins": list(result.bins), "total": result.total,
                "bearing_rad": result.bearing_rad, "latency_s": self.latency_s,
                "width": shape[1], "height": shape[0],
            }, stamp_ns=stamp)
            if view is not None:
                view_pub.publish(view, stamp_ns=stamp)
            if latency_ns == 0:
                await asyncio.sleep(0)  # a zero-latency device must still let others run

    async def _captured(self, capture: asyncio.Future[CaptureOutcome]) -> CaptureOutcome:
        """The capture's outcome. Cancelled meanwhile (the component closing), it first lets
        the capture's thread leave the backend (at most :data:`CAPTURE_DRAIN_S`): the backend
        is closed next, and releasing an OpenCV capture in the middle of its ``read`` crashes
        the process."""
        try:
            return await asyncio.shield(capture)
        except asyncio.CancelledError:
            done, _ = await asyncio.wait([capture], timeout=CAPTURE_DRAIN_S)
            if not done:
                log.warning("%s: a capture still running %g s after the stop; closing its "
                            "backend anyway", self.name, CAPTURE_DRAIN_S)
            elif not capture.cancelled():
                capture.exception()  # retrieved: its failure does not matter any more
            raise

    def _on_seek_color(self, key: str, message: Message[SeekColor], received_ns: int) -> None:
        lo, hi = message.data.lo, message.data.hi
        try:
            self.color = ColorRange(lo=lo, hi=hi,
                                    require_r_gt_b_gt_g=self.color.require_r_gt_b_gt_g)
        except ValueError as exc:  # lo > hi: well-formed but unusable
            self.malformed[key] = self.malformed.get(key, 0) + 1
            log.warning("refused seek colour on %s: %s", key, exc)


Level = Annotated[int, msgspec.Meta(ge=0, le=255)]


class SeekColorRange(msgspec.Struct, kw_only=True, forbid_unknown_fields=True):
    """The colour the camera counts, as a robot file gives it (``seek_color``): R, G and B
    each within ``lo``…``hi``, and the thesis's ordering rule R > B > G on top unless
    ``require_r_gt_b_gt_g`` is false. A range whose ``lo`` exceeds its ``hi`` is refused when
    the robot file loads."""

    lo: tuple[Level, Level, Level]
    hi: tuple[Level, Level, Level]
    require_r_gt_b_gt_g: bool = True

    def __post_init__(self) -> None:
        self.color_range()

    def color_range(self) -> ColorRange:
        return ColorRange(lo=self.lo, hi=self.hi, require_r_gt_b_gt_g=self.require_r_gt_b_gt_g)


Metres = Annotated[float, msgspec.Meta(ge=-10, le=10)]


def build_device(
    *,
    bus: Bus,
    name: str,
    backend: CameraBackend,
    latency_s: Annotated[float, msgspec.Meta(ge=0)] = OV9655_LATENCY_S,
    hfov_deg: Annotated[float, msgspec.Meta(ge=MIN_HFOV_DEG, le=MAX_HFOV_DEG)] = DEFAULT_HFOV_DEG,
    view_scale: Annotated[int, msgspec.Meta(ge=1, le=8)] = DEFAULT_VIEW_SCALE,
    seek_color: SeekColorRange | None = None,
    x_m: Metres = DEFAULT_MOUNT.x_m,
    y_m: Metres = DEFAULT_MOUNT.y_m,
    z_m: Annotated[float, msgspec.Meta(gt=0, le=10)] = DEFAULT_MOUNT.z_m,
    yaw_deg: Annotated[float, msgspec.Meta(ge=-180, le=180)] = DEFAULT_MOUNT.yaw_deg,
    pitch_deg: Annotated[float, msgspec.Meta(ge=-60, le=60)] = DEFAULT_MOUNT.pitch_deg,
    width_px: Annotated[int, msgspec.Meta(ge=8 * BIN_COUNT, le=8192)] = DEFAULT_MOUNT.width_px,
    height_px: Annotated[int, msgspec.Meta(ge=8, le=8192)] = DEFAULT_MOUNT.height_px,
) -> CameraComponent:
    """The ``camera`` device kind: captures from ``backend``, publishes
    ``sensor/camera/<name>``.

    ``latency_s``: capture latency on the robot clock (the thesis's OV9655: 0.11 s; a real
    camera whose driver has its own latency: 0). ``hfov_deg``: the lens's horizontal field of
    view (a pinhole, 20–120°), which the bearing is computed with and a simulated camera
    renders. ``view_scale``: how much the 160×128 view published on ``view/camera/<name>``
    is enlarged. ``seek_color``: the colour counted (:class:`SeekColorRange`; default: the
    thesis's pink). The mount (body frame, checked against the body's footprint): ``x_m``
    ahead of the centre, ``y_m`` to the left, ``z_m`` above the floor, ``yaw_deg`` (+ left)
    and ``pitch_deg`` (+ up); ``width_px`` × ``height_px``: the frame. The backend is told
    them all (:meth:`~components.camera.backend.CameraBackend.mount`).
    """
    color = seek_color.color_range() if seek_color is not None else PINK
    backend.mount(CameraMount(name=name, x_m=x_m, y_m=y_m, z_m=z_m, yaw_deg=yaw_deg,
                              pitch_deg=pitch_deg, hfov_deg=hfov_deg, width_px=width_px,
                              height_px=height_px))
    return CameraComponent(bus=bus, backend=backend, name=name, latency_s=latency_s,
                           color=color, hfov_deg=hfov_deg, view_scale=view_scale)


build_device.publishes_also = (CAMERA_VIEW,)  # type: ignore[attr-defined]
"""Besides ``sensor/camera/<name>``: its view for people (a secure set-up grants it)."""
