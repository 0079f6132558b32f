"""Replaying a recording: a fresh controller with the same tree, fed the recorded inputs on
the recorded simulated time, commands exactly what the original run commanded; the thesis's
synchronous loop and the periodic controller compared on the same inputs; the replay tool
feeding a launched controller in another process over zenoh; and a replay with nobody to take
it failing clearly instead of reporting success."""

from __future__ import annotations

import asyncio
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import msgpack
import pytest
from mcap.reader import make_reader

from ubf_async.aggregator import StateAggregator
from ubf_async.bus import Bus, ConnectionOptions, NoRobotError
from ubf_async.clock import SimClock
from ubf_async.controller import Controller, TickMode
from ubf_async.errors import ConfigurationError
from ubf_async.replay import Recording, replay, wait_for_listeners
from ubf_async.robotfile import load_robot
from ubf_async.transport import InProcessTransport

ROOT = Path(__file__).resolve().parent.parent
ENV = {**os.environ, "PYTHONUNBUFFERED": "1"}
Command = tuple[int, int, tuple[str, ...], float, float]
"""(tick time ns, tick number, winners, speed, turn)."""


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, int]:
    """A recorded run of the thesis's first experiment (the ball ahead): file and seed."""
    out = tmp_path_factory.mktemp("recorded")
    subprocess.run([sys.executable, "-m", "ubf_async.launch", "--scenario", "ball-in-sight",
                    "--speed", "5", "--duration", "4", "--quiet", "--listen", "tcp/127.0.0.1:0",
                    "--record", str(out), "--summary", str(out / "summary.json")],
                   cwd=ROOT, env=ENV, check=True, capture_output=True, timeout=120)
    return out / "mini.mcap", json.loads((out / "summary.json").read_text())["seed"]


def recorded_drives(path: Path) -> list[Command]:
    drives = []
    with path.open("rb") as f:
        for _, _, message in make_reader(f).iter_messages(topics=["ubf/mini/cmd/drive"]):
            envelope = msgpack.unpackb(message.data)
            data = envelope["data"]
            drives.append((envelope["stamp_ns"], data["tick"], tuple(data["winners"]),
                           data["speed"], data["turn"]))
    return drives


async def rerun(path: Path, seed: int, **controller: Any) -> list[Command]:
    """The recorded inputs into a fresh controller with the robot file's tree, in process,
    on the recorded simulated time."""
    robot = load_robot(seed=seed)
    net, clock = InProcessTransport(), SimClock(0)
    robot_bus = Bus(transport=net, robot="mini", clock=clock)
    player = Bus(transport=net, robot="mini", clock=clock)
    aggregator = StateAggregator(bus=robot_bus)
    ctl = Controller(bus=robot_bus, aggregator=aggregator, root=robot.root, rate_hz=50,
                     **controller)
    commands: list[Command] = []
    ctl.on_tick(lambda state, trace, command: commands.append(
        (state.now_ns, command.tick, tuple(command.winners), command.speed, command.turn)))
    await aggregator.start()
    await ctl.start()
    await net.settle()
    stats = await replay(Recording(path), bus=player, speed=None, clock=clock,
                         settle=net.settle)
    assert stats.published > 1000
    await ctl.aclose()
    await aggregator.aclose()
    await robot_bus.aclose()
    await player.aclose()
    return commands


@pytest.mark.asyncio
async def test_a_replayed_run_commands_what_the_original_commanded(
        recorded: tuple[Path, int]) -> None:
    path, seed = recorded
    original = recorded_drives(path)
    again = await rerun(path, seed, reflex_sources=("range/",))
    assert len(original) > 250
    assert any("chase" in winners for _, _, winners, _, _ in original)  # it saw the ball
    assert again == original  # every tick: same time, number, winners, speed and turn


@pytest.mark.asyncio
async def test_the_thesis_loop_and_the_periodic_controller_on_the_same_inputs(
        recorded: tuple[Path, int]) -> None:
    path, seed = recorded
    periodic = await rerun(path, seed)
    sync = await rerun(path, seed, mode=TickMode.SYNC, sync_source="camera/front")
    frames = sum(1 for m in Recording(path, only=["sensor/camera/front"]))
    # The thesis's loop decides once per camera frame; the controller 50 times a second.
    assert len(sync) == frames and 190 <= len(periodic) <= 210
    # The sync loop decides the moment a frame arrives; the periodic controller at its next
    # tick, at most one period (20 ms) later.
    first_chase = {name: next(t for t, _, winners, _, _ in run if "chase" in winners)
                   for name, run in (("sync", sync), ("periodic", periodic))}
    assert 0 <= first_chase["periodic"] - first_chase["sync"] <= 20_000_000
    # On the same frame they decide alike (this tree reads only the camera): the periodic
    # controller's first tick after the frame arrived (a tick due at that very instant runs
    # before the frame is delivered, on the previous one).
    alike = 0
    for t, _, winners, speed, turn in sync:
        after = next((c for c in periodic if c[0] > t), None)
        alike += after is not None and after[2:] == (winners, speed, turn)
    assert alike >= 0.9 * len(sync)


def test_recording_refuses_a_file_that_is_not_a_recording(tmp_path: Path) -> None:
    bogus = tmp_path / "x.mcap"
    bogus.write_bytes(b"not mcap")
    with pytest.raises(ConfigurationError, match="not a readable MCAP recording"):
        Recording(bogus)


def test_the_replay_tool_feeds_a_launched_controller_over_zenoh(
        recorded: tuple[Path, int], endpoint: str, tmp_path: Path) -> None:
    path, _ = recorded
    original = recorded_drives(path)
    # The re-run records its own bus (in its process: no subscriber of ours to race with).
    robot = subprocess.Popen(
        [sys.executable, "-m", "ubf_async.launch", "--no-sim", "--sim-time", "--listen",
         endpoint, "--quiet", "--record", str(tmp_path)], cwd=ROOT, env=ENV,
        stdout=subprocess.DEVNULL)
    try:
        # Started with the robot, not after it: the replay waits for the robot and for its
        # subscriptions before its first message, so none of the recording is lost.
        result = subprocess.run(
            [sys.executable, "-m", "ubf_async.replay", str(path), "--speed", "2", "--connect",
             endpoint, "--wait-for-robot-s", "60"], cwd=ROOT, env=ENV, capture_output=True,
            text=True, timeout=120)
        assert result.returncode == 0, result.stdout + result.stderr
        assert "7 keys)" in result.stdout  # every replayed key had a subscriber
        assert "messages replayed" in result.stdout
    finally:
        robot.terminate()  # SIGTERM: the robot stops and finishes its recording
        robot.wait(timeout=30)
    assert robot.returncode == 0
    rerun = recorded_drives(tmp_path / "mini.mcap")
    # On the recorded simulated time: ticks stamped within the run, chasing from about when the
    # original did (across processes the exact tick phase is not reproduced), and from the
    # recording's start (a replay that began before the robot listened would have lost it).
    stamps = [t for t, *_ in rerun if t > 0]
    assert stamps and max(stamps) <= original[-1][0] + 0.1e9
    assert min(stamps) <= original[0][0] + 0.1e9
    first = next(t for t, _, winners, _, _ in rerun if "chase" in winners)
    first_original = next(t for t, _, winners, _, _ in original if "chase" in winners)
    assert abs(first - first_original) <= 0.25e9


def run_replay(path: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "ubf_async.replay", str(path),
                           "--wait-for-robot-s", "1", *args],
                          cwd=ROOT, env=ENV, capture_output=True, text=True, timeout=60)


def test_a_replay_with_nobody_at_the_endpoint_fails_clearly(
        recorded: tuple[Path, int], endpoint: str) -> None:
    result = run_replay(recorded[0], "--connect", endpoint)
    assert result.returncode == 2, result.stdout + result.stderr
    assert result.stdout == ""  # nothing replayed, no success claimed
    (line,) = result.stderr.splitlines()
    assert f"no robot to connect to: nothing answered at {endpoint} within 1s" in line


def test_a_replay_nobody_subscribes_to_fails_clearly(recorded: tuple[Path, int]) -> None:
    # Listening only (what a replay without --connect did): nobody comes, nothing is sent.
    result = run_replay(recorded[0], "--listen", "tcp/127.0.0.1:0")
    assert result.returncode == 2, result.stdout + result.stderr
    assert result.stdout == ""
    (line,) = result.stderr.splitlines()
    assert "nobody subscribes to what this would replay (7 keys under ubf/mini/: clock, " \
           "sensor/camera/front, sensor/encoders/wheels and 4 more) within 1s" in line


@pytest.mark.asyncio
async def test_a_robot_alive_but_taking_nothing_is_no_one_to_replay_to(
        recorded: tuple[Path, int], endpoint: str) -> None:
    # A robot's component is alive (its liveliness token), but nothing subscribes to what the
    # replay publishes: refused, as nobody would receive it.
    bus = await Bus.open(ConnectionOptions(robot="mini", listen=[endpoint]))
    token = bus.declare_token(bus.keys.alive("lonely"))
    bus.subscribe(bus.keys.prefix + "/cmd/**", lambda k, p, t: None)  # not what is replayed
    try:
        result = await asyncio.to_thread(run_replay, recorded[0], "--connect", endpoint)
    finally:
        token.undeclare()
        await bus.aclose()
    assert result.returncode == 2, result.stdout + result.stderr
    assert result.stdout == "" and "nobody subscribes" in result.stderr


def test_a_replay_of_nothing_is_refused(recorded: tuple[Path, int]) -> None:
    result = run_replay(recorded[0], "--only", "sensor/sonar/*", "--connect",
                        "tcp/127.0.0.1:1")
    assert result.returncode == 2, result.stdout + result.stderr
    assert "nothing to replay: no message of robot 'mini' on sensor/sonar/*" in result.stderr


@pytest.mark.asyncio
async def test_waiting_for_listeners_returns_when_they_are_there() -> None:
    net = InProcessTransport()
    player, robot = Bus(transport=net, robot="r"), Bus(transport=net, robot="r")
    keys = ["ubf/r/clock", "ubf/r/sensor/range/front"]
    with pytest.raises(NoRobotError, match=r"nobody subscribes .* within 0\.05s"):
        await wait_for_listeners(player, keys, timeout_s=0.05)
    robot.subscribe("ubf/r/clock", lambda k, p, t: None)
    # One key taken: the other gets its settling time, then is reported.
    assert await wait_for_listeners(player, keys, timeout_s=5,
                                    settle_s=0.05) == ["ubf/r/sensor/range/front"]
    robot.subscribe("ubf/r/sensor/**", lambda k, p, t: None)
    started = asyncio.get_running_loop().time()
    assert await wait_for_listeners(player, keys, timeout_s=5, settle_s=5) == []
    assert asyncio.get_running_loop().time() - started < 1  # all there: no settling wait
    await player.aclose()
    await robot.aclose()
