"""The LED device: the bank's access functions, cmd/leds through the bus to the simulated
backend and back as sensor/leds samples, a behaviour lighting LED 0 while the robot sees pink
(on the recorded camera frames of a run in this process, and from a launch to another
process and on its status line), and the LEDs on the recorded camera frames."""

from __future__ import annotations

import asyncio
import dataclasses
from pathlib import Path

import cv2
import msgpack
import numpy as np
import pytest

from components.camera.seekcolor import seekcolor
from components.leds.bank import LedBank
from components.leds.component import LedsComponent
from components.sim.backends.devices import SimLedBackend
from components.sim.outputs.trajectory import (
    LED_DARK_BGR,
    LED_LIT_BGR,
    annotate_frame,
    read_trajectory_csv,
)
from tests.conftest import as_dict, eventually, free_port, spawn, stop
from ubf_async.errors import ProtocolError
from ubf_async.net.inprocess import InProcessTransport
from ubf_async.net.options import ConnectionOptions
from ubf_async.runs.inprocess import plan_run, run_plan
from ubf_async.runtime import lending
from ubf_async.runtime.bus import Bus
from ubf_async.wire.protocol import decode, encode
from ubf_async.wire.topics import LED_STATE, LEDS, LedState


def test_bank_access_functions() -> None:
    bank = LedBank(count=3)
    bank.on(0)
    bank.on(2)
    assert (bank.mask, bank.lit(), bank.is_on(1)) == (0b101, [0, 2], False)
    bank.toggle(2)
    bank.off(0)
    assert bank.mask == 0
    bank.set_all(0b110)
    assert bank.lit() == [1, 2]
    assert bank.fit(0b11111) == (0b111, 2)  # two bits beyond the bank, dropped
    with pytest.raises(ValueError, match="beyond the bank's 3"):
        bank.set_all(0b1000)
    with pytest.raises(IndexError, match=r"LEDs 0\.\.2"):
        bank.on(3)
    with pytest.raises(ValueError, match=r"0\.\.255"):
        bank.fit(256)
    with pytest.raises(ValueError, match="1 to 8"):
        LedBank(count=9)


def test_led_state_on_the_wire_is_checked() -> None:
    payload = encode(LED_STATE, {"mask": 1, "count": 2}, stamp_ns=1, seq=1)
    assert decode(payload, topic=LED_STATE).data == LedState(mask=1, count=2)
    with pytest.raises(ProtocolError, match="beyond the bank"):
        encode(LED_STATE, {"mask": 4, "count": 2}, stamp_ns=1, seq=1)


@pytest.mark.asyncio
async def test_cmd_leds_lights_the_backend_and_is_reported() -> None:
    net = InProcessTransport()
    robot, tool = Bus(transport=net, robot="r1"), Bus(transport=net, robot="r1")
    backend = SimLedBackend()
    leds = LedsComponent(bus=robot, backend=backend, name="panel", count=2, period_s=0.05)
    reported: list[tuple[int, int]] = []
    tool.subscribe(LED_STATE.key(tool.keys, "panel"),
                   lambda k, p, t: reported.append((decode(p).data.mask, decode(p).data.count)),
                   latest=False)
    await leds.start()
    await eventually(lambda: reported[-1:] == [(0, 2)], what="all off on start")
    command = tool.publisher(LEDS)
    command.publish({"mask": 0b01})
    await eventually(lambda: backend.mask == 1 and reported[-1] == (1, 2), what="LED 0 lit")
    command.publish({"mask": 0b110})  # LED 2 does not exist: dropped, counted, LED 1 lit
    await eventually(lambda: backend.mask == 0b10, what="LED 1 lit alone")
    assert leds.clamped == 1
    raw = tool._connection.declare_publisher(LEDS.key(tool.keys))
    raw.put(msgpack.packb({"schema": "leds", "v": 1, "stamp_ns": 1, "seq": 1,
                           "data": {"mask": "all"}}))  # malformed
    await eventually(lambda: sum(leds.malformed.values()) == 1, what="the malformed command")
    assert backend.mask == 0b10
    count = len(reported)
    await eventually(lambda: len(reported) >= count + 2, what="the state repeated")
    assert reported[-1] == (0b10, 2)
    await leds.aclose()
    assert backend.mask == 0 and reported[-1] == (0, 2)  # off when it closes
    await robot.aclose()
    await tool.aclose()


def test_recorded_frames_draw_the_leds() -> None:
    frame = np.full((1024, 1280, 3), 128, dtype=np.uint8)
    image = annotate_frame(frame, seekcolor(frame), t_s=1.0,
                           leds={"panel": LedState(mask=0b01, count=2)})
    h, w = image.shape[:2]
    led1, led0 = image[h - 17, w - 14], image[h - 17, w - 38]  # LED 0 is left of LED 1
    assert tuple(led0) == LED_LIT_BGR
    assert tuple(led1) == (0, 0, 0)  # dark: a ring around a black centre
    plain = annotate_frame(frame, seekcolor(frame), t_s=1.0)
    assert tuple(plain[h - 17, w - 38]) != LED_LIT_BGR


def test_chase_lights_led_0_while_the_robot_sees_pink(tmp_path: Path) -> None:
    """The shipped robot: chase lights LED 0, search turns it off. In ball-behind the robot
    searches (sits still, then turns) until it finds the ball, then chases it: the recorded
    frames show LED 0 dark while it searches and lit while it chases (where the renderer
    draws it: bottom right, LED 0 left of LED 1). A run in this process, recorded as launch's
    ``--record --record-every-s 0.5`` records it (the status line's LEDs: below)."""
    plan = plan_run("mini-whegs", "ball-behind", duration_s=12.0, out_dir=tmp_path,
                    pictures=True)
    assert plan.sim_options is not None
    plan.sim_options = dataclasses.replace(plan.sim_options, record_every_s=0.5)
    with asyncio.Runner(loop_factory=lending.new_idle_event_loop) as runner:
        result = runner.run(run_plan(plan))
    samples = read_trajectory_csv(tmp_path / "trajectory.csv")
    assert len(samples) == len(result.trajectory) == 241
    shown: dict[str, list[float]] = {"search": [], "chase": []}
    frames = sorted(tmp_path.glob("frame_*.png"))
    assert len(frames) == 12 / 0.5 + 1
    for path in frames:
        t_s = float(path.stem.removeprefix("frame_").removesuffix("s"))
        # Judged only where one behaviour has acted alone for the last half second: the LED
        # state reaches the recorder over the bus a tick or two after the command.
        recent = {s.winners for s in samples if t_s - 0.5 <= s.t_s <= t_s}
        if recent == {"search"} or (recent and all("chase" in w for w in recent)):
            image = cv2.imread(str(path))
            h, w = image.shape[:2]
            centre, ring = image[h - 17, w - 38], image[h - 17, w - 38 + 7]
            if recent == {"search"}:
                assert tuple(centre) == (0, 0, 0), path.name  # dark: a ring, black inside
                assert tuple(ring) == LED_DARK_BGR, path.name
                shown["search"].append(t_s)
            else:
                assert tuple(centre) == LED_LIT_BGR, path.name
                shown["chase"].append(t_s)
    # Searching first (from 0.5 s: the first LED state has arrived), chasing later.
    assert len(shown["search"]) >= 4 and len(shown["chase"]) >= 4, shown
    assert max(shown["search"]) < min(shown["chase"]), shown


@pytest.mark.asyncio
async def test_led_state_reaches_another_process_and_the_status_line(endpoint: str,
                                                                      robot: str) -> None:
    """One launch of ball-behind (12 simulated seconds at 4x real time, its status line every
    0.2 s): a session of this process, which the launch connects to, sees LED 0 off while the
    robot searches and lit once it sees pink; and launch's status line shows the LEDs, LED 0
    lit at the end (●○)."""
    bus = await Bus.open(ConnectionOptions(robot=robot, listen=[endpoint]))
    masks: list[int] = []
    try:
        bus.subscribe(LED_STATE.key(bus.keys, "panel"),
                      lambda k, p, t: masks.append(as_dict(decode(p).data)["mask"]),
                      latest=False)
        proc = await spawn("-m", "ubf_async.launch", "--scenario", "ball-behind", "--speed",
                           "4", "--duration", "12", "--connect", endpoint, "--listen",
                           f"tcp/127.0.0.1:{free_port()}", "--robot", robot,
                           "--status-period-s", "0.2")
        try:
            printed, _ = await asyncio.wait_for(proc.communicate(), 120)
        finally:
            await stop(proc)
        assert proc.returncode == 0, printed.decode()
        # The ball starts behind the robot: LED off while it searches, lit once it sees pink.
        await eventually(lambda: 0 in masks, what="the LED off while searching")
        await eventually(lambda: 1 in masks[masks.index(0):],
                         what="LED 0 lit once the ball is in sight")
    finally:
        await bus.aclose()
    status = [line for line in printed.decode().splitlines() if "leds/panel" in line]
    assert status and "leds/panel ●○ " in status[-1]
