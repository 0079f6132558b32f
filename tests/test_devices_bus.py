"""Device components on the bus beyond motion: radio, seek-colour commands, real footage."""

from __future__ import annotations

import asyncio
import threading
from pathlib import Path

import cv2
import numpy as np
import pytest

from components.camera.backend import CameraBackend
from components.camera.component import CameraComponent
from components.camera.videocapture import VideoCaptureBackend
from components.radio.component import RadioComponent
from components.sim.backends.devices import SimRadioBackend
from components.sim.world.config import Arena, BallConfig, WorldConfig
from tests.conftest import SimRobot, eventually
from ubf_async import Action, FunctionBehavior
from ubf_async.runtime.aggregator import StateAggregator
from ubf_async.runtime.bus import Bus
from ubf_async.runtime.controller import Controller


@pytest.mark.asyncio
async def test_radio_messages_in_to_state_and_out_from_action(robot_bus: Bus) -> None:
    link = SimRadioBackend()
    radio = RadioComponent(bus=robot_bus, backend=link, period_s=0.01)
    agg = StateAggregator(bus=robot_bus)
    said = FunctionBehavior(
        lambda s: Action(message=f"heard {s.value('radio/link', 'text')}")
        if s.value("radio/link", "text") else None, name="echo")
    ctl = Controller(bus=robot_bus, aggregator=agg, root=said, rate_hz=100)
    async with radio, agg, ctl:
        await agg.running.wait()
        link.inject("hello robot")
        await eventually(lambda: agg.snapshot().value("radio/link", "text") == "hello robot",
                         what="incoming message in the state")
        await eventually(lambda: "heard hello robot" in link.outbox, what="outgoing message")
        assert link.outbox.count("heard hello robot") == 1  # sent on change, not every tick
        assert radio.sent == 1


@pytest.mark.asyncio
async def test_seek_color_from_an_action_changes_what_the_camera_counts(robot_bus: Bus) -> None:
    green = ((0, 100, 0), (90, 255, 90))
    agg = StateAggregator(bus=robot_bus)
    config = WorldConfig(arena=Arena(), ball=BallConfig(x_m=0.5, y_m=0.0))
    async with SimRobot(robot_bus, config, speed=3, devices=("camera",)) as robot, agg:
        camera = robot.device("camera")
        await eventually(lambda: agg.snapshot().value("camera/front", "total", 0) > 50,
                         timeout_s=10, what="pink ball seen")
        ctl = Controller(bus=robot_bus, aggregator=agg,
                         root=FunctionBehavior(lambda s: Action(seek_color=green), name="look"))
        async with ctl:
            await eventually(lambda: camera.color.lo == (0, 100, 0), what="colour range applied")
            changed_at = robot.clock.now_ns()
            await eventually(
                lambda: agg.entries["camera/front"].message.stamp_ns > changed_at
                and agg.snapshot().value("camera/front", "total") == 0,
                timeout_s=10, what="no green in the scene")


@pytest.mark.asyncio
async def test_camera_component_on_real_footage_through_videocapture(
    robot_bus: Bus, tmp_path: Path
) -> None:
    video = tmp_path / "pink.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 10, (320, 256))
    assert writer.isOpened()
    for i in range(10):
        frame = np.full((256, 320, 3), 128, np.uint8)
        cv2.circle(frame, (40 + 24 * i, 128), 30, (150, 60, 230), -1)  # BGR pink
        writer.write(frame)
    writer.release()
    agg = StateAggregator(bus=robot_bus)
    camera = CameraComponent(bus=robot_bus, backend=VideoCaptureBackend(str(video)),
                             latency_s=0.0)
    async with agg, camera:
        await eventually(lambda: camera.frames >= 10, what="ten frames")
        # The latest frame held, fresh or not: on a busy machine decoding and resizing the
        # next one can outlast the frame period, which makes the held one stale meanwhile.
        reading = agg.snapshot().get("camera/front")
        assert reading is not None
        bins = reading.value["bins"]
        assert bins is not None and sum(bins) > 0
        assert camera.last_frame_shape == (1024, 1280, 3)  # resized to the OV9655's frame


class BlockingCamera(CameraBackend):
    """A camera backend whose capture waits until released, and which notes whether it was
    closed while a capture was inside it (what crashes a real OpenCV capture)."""

    def __init__(self) -> None:
        self.release = threading.Event()
        self.capturing = threading.Event()
        self.closed_mid_capture: bool | None = None

    def prepare(self) -> None:
        pass

    def expose(self) -> None:
        pass

    def capture(self) -> np.ndarray:
        self.capturing.set()
        try:
            assert self.release.wait(30.0), "never released"
            return np.zeros((32, 40, 3), dtype=np.uint8)
        finally:
            self.capturing.clear()

    def close(self) -> None:
        self.closed_mid_capture = self.capturing.is_set()


@pytest.mark.asyncio
async def test_a_closing_camera_lets_its_capture_finish_before_closing_the_backend(
        robot_bus: Bus) -> None:
    backend = BlockingCamera()
    camera = CameraComponent(bus=robot_bus, backend=backend, latency_s=0.0)
    camera.close_on_exit(backend.aclose)  # as the device factory does
    await camera.start()
    await asyncio.to_thread(backend.capturing.wait, 30.0)
    run_task = camera._tasks[0]
    closing = asyncio.create_task(camera.aclose())
    # Released only once the stop has reached the run: a camera that did not wait would
    # have closed its backend under the capture by then.
    await eventually(lambda: run_task.cancelling() > 0 or run_task.done(), what="the stop")
    backend.release.set()
    await closing
    assert backend.closed_mid_capture is False
