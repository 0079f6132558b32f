"""Devices as separate OS processes attached to a running simulated robot."""

from __future__ import annotations

import asyncio
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from components.sim.world.config import Arena, WorldConfig, WorldPose
from tests.conftest import SimRobot, as_dict, eventually
from ubf_async.net.options import ConnectionOptions
from ubf_async.runtime.bus import Bus
from ubf_async.wire.protocol import decode

ROOT = Path(__file__).resolve().parent.parent
ENV = {**os.environ, "PYTHONUNBUFFERED": "1"}


def start(*args: str) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, *args], cwd=ROOT, env=ENV, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT)


def stop(proc: subprocess.Popen[str], sig: int = signal.SIGTERM) -> str:
    if proc.poll() is None:
        proc.send_signal(sig)
    out, _ = proc.communicate(timeout=20)
    return out


@pytest.mark.asyncio
async def test_range_finder_attached_from_another_process_and_detached(
    endpoint: str, robot: str
) -> None:
    robot_proc = start("-m", "ubf_async.launch", "--listen", endpoint, "--robot", robot,
                       "--quiet", "--devices", "motors,camera")
    bus = await Bus.open(ConnectionOptions(robot=robot, connect=[endpoint]))
    statuses: list[dict] = []
    alive: dict[str, bool] = {}
    sensor = None
    try:
        bus.subscribe(bus.keys.status("controller"),
                      lambda k, p, t: statuses.append(as_dict(decode(p).data)))
        bus.watch_liveliness(bus.keys.all_alive,
                             lambda key, up: alive.__setitem__(key.rsplit("/", 1)[-1], up))
        await eventually(lambda: len(statuses) > 0, timeout_s=20, what="the robot to run")

        def source(name: str) -> dict | None:
            if not statuses:
                return None
            return next((s for s in statuses[-1]["sources"] if s["source"] == name), None)

        assert source("range/left") is None
        # A second IR finder, mounted 45° to the left, added to the running robot.
        sensor = start("-m", "components.range", "--connect", endpoint, "--robot", robot,
                       "--name", "left", "--yaw-deg", "45", "--model", "ir-20-150")
        assert sensor.stdout is not None
        line = await asyncio.to_thread(sensor.stdout.readline)
        assert "attached" in line, line
        attached = time.monotonic()
        await eventually(lambda: source("range/left") is not None, timeout_s=5,
                         what="range/left in the controller's state")
        # Status samples come every 0.5 s: the source was in the state within a second.
        assert time.monotonic() - attached < 1.5
        reading = source("range/left")
        assert reading is not None and not reading["stale"]
        assert alive.get("range-left") is True
        # Detach it (kill -9): the source goes stale, its token vanishes, the robot goes on.
        sensor.send_signal(signal.SIGKILL)
        await asyncio.to_thread(sensor.wait)
        await eventually(lambda: alive.get("range-left") is False, what="token to vanish")
        await eventually(lambda: (source("range/left") or {}).get("stale") is True,
                         timeout_s=5, what="range/left to go stale")
        ticks = statuses[-1]["ticks"]
        await eventually(lambda: statuses[-1]["ticks"] > ticks + 10, what="robot still ticking")
        assert robot_proc.poll() is None
    finally:
        await bus.aclose()
        if sensor is not None:
            stop(sensor, signal.SIGKILL)
        out = stop(robot_proc)
    assert "ubf_async: stopped" in out, out


def test_device_without_a_simulator_says_so(endpoint: str, robot: str) -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "components.range", "--listen", endpoint, "--robot", robot,
         "--wait-for-sim-s", "1"],
        cwd=ROOT, capture_output=True, text=True, timeout=30,
    )
    assert proc.returncode == 2
    assert "no simulator is publishing" in proc.stderr


@pytest.mark.parametrize("device", ["camera", "motors", "encoders", "radio", "range"])
def test_every_device_has_help(device: str) -> None:
    out = subprocess.run([sys.executable, "-m", f"components.{device}", "--help"], cwd=ROOT,
                         capture_output=True, text=True, check=True).stdout
    for flag in ("--connect", "--listen", "--mode", "--config", "--robot", "--duration"):
        assert flag in out, (device, flag)


@pytest.mark.asyncio
async def test_attached_ir_finder_drives_a_remote_avoidance_behaviour(
    endpoint: str, robot: str, tmp_path: Path
) -> None:
    """Robot 15 cm from a wall, no IR finder of its own: an IR finder and the obstacle-
    avoidance behaviour, each in its own process, join it; the drive commands follow avoid."""
    scenario = tmp_path / "wall.json"
    scenario.write_text(
        '{"name": "wall", "robot": {"x_m": 1.30, "y_m": 0.0, "heading_deg": 0},'
        ' "arena": {"x_min_m": -1.5, "y_min_m": -1.5, "x_max_m": 1.5, "y_max_m": 1.5},'
        ' "duration_s": 1000}'
    )
    robot_proc = start("-m", "ubf_async.launch", "--listen", endpoint, "--robot", robot,
                       "--quiet", "--devices", "motors,camera", "--scenario", str(scenario))
    bus = await Bus.open(ConnectionOptions(robot=robot, connect=[endpoint]))
    drives: list[dict] = []
    helpers: list[subprocess.Popen[str]] = []
    try:
        bus.subscribe(bus.keys.cmd("drive"), lambda k, p, t: drives.append(as_dict(decode(p).data)),
                      latest=False)
        await eventually(lambda: len(drives) > 10, timeout_s=20, what="the robot to drive")
        assert all("avoid_obstacles" not in d["winners"] for d in drives)
        helpers.append(start("examples/avoid_obstacles.py", "--connect", endpoint,
                             "--robot", robot))
        helpers.append(start("-m", "components.range", "--connect", endpoint, "--robot", robot,
                             "--name", "front", "--model", "ir-10-80"))
        await eventually(lambda: any("avoid_obstacles" in d["winners"] for d in drives),
                         timeout_s=15, what="avoid to take over the drive")
        reacting = [d for d in drives if "avoid_obstacles" in d["winners"]]
        assert all(d["speed"] < 0 for d in reacting), reacting
    finally:
        await bus.aclose()
        for proc in helpers:
            stop(proc, signal.SIGKILL)
        stop(robot_proc)


@pytest.mark.asyncio
async def test_devices_in_their_own_processes_use_the_simulator_in_this_one(
    robot_bus: Bus, endpoint: str, robot: str
) -> None:
    """No launch: the simulator runs in this process; an IR finder and the motors started
    with ``python -m components.<device>`` find it through the registry, follow its clock,
    measure its world and drive its wheels."""
    config = WorldConfig(arena=Arena(), robot_start=WorldPose(x_m=1.0, y_m=0.0, heading_rad=0.0))
    readings: list[tuple[int, dict]] = []
    applied: list[dict] = []
    procs: list[subprocess.Popen[str]] = []
    async with SimRobot(robot_bus, config, speed=2, devices=()) as sim:
        robot_bus.subscribe(robot_bus.keys.sensor("range", "ahead"),
                            lambda k, p, t: readings.append((sim.clock.now_ns(), decode(p))),
                            latest=False)
        robot_bus.subscribe(robot_bus.keys.sensors_of_kind("motors"),
                            lambda k, p, t: applied.append(as_dict(decode(p).data)), latest=False)
        try:
            for device, *flags in (("range", "--name", "ahead", "--model", "ir-20-150"),
                                   ("motors", "--timeout-s", "5")):
                procs.append(start("-m", f"components.{device}", "--connect", endpoint,
                                   "--robot", robot, *flags))
            for proc in procs:
                assert proc.stdout is not None
                line = await asyncio.to_thread(proc.stdout.readline)
                assert "attached" in line and "(simulated)" in line, line
            await eventually(lambda: len(readings) >= 5, timeout_s=10, what="IR readings")
            now_ns, message = readings[-1]
            # The wall is 0.5 m ahead of the robot's centre, 0.45 m from the sensor.
            assert message.data.model == "ir-20-150"
            assert message.data.range_mm == pytest.approx(450, rel=0.15)
            assert 0 < message.stamp_ns <= now_ns  # stamped on the simulated clock
            await eventually(lambda: len(applied) > 0, what="the motors to arm")
            drive = robot_bus.publisher(robot_bus.keys.cmd("drive"), "drive")
            await drive.wait_for_subscribers()
            drive.publish({"speed": 60.0, "turn": 0.0})
            await eventually(lambda: any(a["reason"] == "command" for a in applied),
                             what="the drive command to be applied")
            await eventually(lambda: sim.world.motor_pulses[0] > 1.6, timeout_s=5,
                             what="the pulses to reach the simulated wheels")
        finally:
            for proc in procs:
                out = stop(proc)
                assert "Traceback" not in out, out
