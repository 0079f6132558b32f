"""Replaying a recording: a fresh controller with the same tree, fed the recorded inputs on
the recorded simulated time, commands exactly what the original run commanded; the thesis's
synchronous loop and the periodic controller compared on the same inputs; the replay tool
feeding a launched controller in another process over zenoh; a replay with nobody to take
it failing clearly instead of reporting success; a recording of another robot, begun mid-run,
replayed onto its own robot without --robot into a controller that ticks at its rate; and a
replay held up saying what held it up."""

from __future__ import annotations

import asyncio
import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import msgpack
import pytest
from mcap.reader import make_reader
from mcap.writer import Writer

from tests.remote_robot import Process
from ubf_async.assembly.robotfile import load_robot
from ubf_async.clocks.clock import SimClock
from ubf_async.errors import ConfigurationError, NoRobotError
from ubf_async.net.inprocess import InProcessTransport
from ubf_async.net.options import ConnectionOptions
from ubf_async.runtime.aggregator import StateAggregator
from ubf_async.runtime.bus import Bus
from ubf_async.runtime.controller import Controller, TickMode
from ubf_async.tools.replay import (
    CONTROLLER,
    Recording,
    compare_commands,
    recorded_commands,
    replay,
    wait_for_controller,
    wait_for_listeners,
)

ROOT = Path(__file__).resolve().parent.parent
ENV = {**os.environ, "PYTHONUNBUFFERED": "1"}
REPLAY = "python -m ubf_async.replay"
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
    # replay --compare's comparison says so, from the file as the tool reads it.
    commands, period_ns = recorded_commands(path)
    assert period_ns == 20_000_000 and len(commands) == len(original)
    same = compare_commands(commands, [(t, s, r, w) for t, _, w, s, r in again],
                            within_ns=period_ns)
    assert (same.compared, same.identical, same.first) == (len(original), len(original), None)
    # ... and a re-run that stops 2 s in is told where, and what it did instead.
    stopped = [(t, 0.0 if t >= commands[0][0] + 2 * 10**9 else s, r, w)
               for t, _, w, s, r in again]
    told = compare_commands(commands, stopped, within_ns=period_ns)
    assert told.first is not None and told.identical < told.compared
    recorded_then, rerun_then = told.first
    # (the re-run's command in effect is the one up to a tick after: it may be the first stop)
    assert recorded_then[0] >= commands[0][0] + 2 * 10**9 - period_ns
    assert recorded_then[1] != 0.0
    assert rerun_then is not None and rerun_then[1] == 0.0
    assert told.lines()[1].startswith(
        f"  first divergence {(recorded_then[0] - commands[0][0]) / 1e9:.2f} s into the "
        f"recording: recorded speed ")


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
        # Started with the robot, not after it: the replay waits for the robot, for its
        # subscriptions and for its controller to tick before its first message, so none of
        # the recording is lost.
        # ... and compares the re-run's drive commands with the recorded ones.
        result = subprocess.run(
            [sys.executable, "-m", "ubf_async.replay", str(path), "--speed", "2", "--connect",
             endpoint, "--wait-for-robot-s", "60", "--compare", "--compare-plot",
             str(tmp_path / "compared.png")], cwd=ROOT, env=ENV, capture_output=True,
            text=True, timeout=120)
        assert result.returncode == 0, result.stdout + result.stderr
        assert "7 keys)" in result.stdout  # every replayed key had a subscriber
        assert "messages replayed" in result.stdout
        # (How many are identical depends on the pace the machine kept: see the in-process
        # re-run above, identical to the last command.)
        said = re.search(r"compared (\d+) recorded drive commands with the re-run's in effect "
                         r"at their time: [\d.]+% identical \(speed, turn and winners; a "
                         r"tick's phase, 20 ms, allowed\)", result.stdout)
        assert said is not None, result.stdout
        assert int(said[1]) == len(original), result.stdout
        assert (tmp_path / "compared.png").read_bytes().startswith(b"\x89PNG")
    finally:
        robot.terminate()  # SIGTERM: the robot stops and finishes its recording
        robot.wait(timeout=30)
    assert robot.returncode == 0
    rerun = recorded_drives(tmp_path / "mini.mcap")
    # On the recorded simulated time: ticks stamped within the run, and chasing from about when
    # the original did (across processes the exact tick phase is not reproduced).
    stamps = [t for t, *_ in rerun if t > 0]
    assert stamps and max(stamps) <= original[-1][0] + 0.1e9
    # From the recording's start: the robot took in its controller's first command and first
    # status before the replay's first message (its clock sample), so it ticked from the
    # recording's first instant on (a replay that began before its controller ran would have
    # re-run it from later on). Seen by the robot's own recording, in the order it took
    # messages in -- not by its first tick's stamp: a busy machine's robot takes the replayed
    # clock in late and in bursts, so that stamp says how late its loop ran, not when the
    # replay began.
    taken = arrival_order(tmp_path / "mini.mcap")
    assert max(taken.index("cmd/drive"), taken.index("status/controller")) < taken.index("clock")
    first = next(t for t, _, winners, _, _ in rerun if "chase" in winners)
    first_original = next(t for t, _, winners, _, _ in original if "chase" in winners)
    assert abs(first - first_original) <= 0.25e9


def arrival_order(path: Path) -> list[str]:
    """The keys (under ``ubf/mini/``) of a launch's recording, in the order its recorder took
    the messages in (their MCAP sequence numbers)."""
    with path.open("rb") as f:
        taken = sorted((message.sequence, channel.topic) for _, channel, message
                       in make_reader(f).iter_messages(log_time_order=False))
    return [topic.removeprefix("ubf/mini/") for _, topic in taken]


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


@pytest.mark.asyncio
async def test_waiting_for_the_controller_waits_for_its_status_if_it_has_one() -> None:
    """A controller's ticks start where the clock stands when its loop starts: the replay's
    clock waits for its first status (sent once its loop runs), and for no controller where
    there is none."""
    net = InProcessTransport()
    player, robot = Bus(transport=net, robot="r"), Bus(transport=net, robot="r")
    assert await wait_for_controller(player, timeout_s=5) is False  # devices alone: no wait
    token = robot.declare_token(robot.keys.alive(CONTROLLER))
    with pytest.raises(NoRobotError, match=r"'r'.s controller is alive but sent no status "
                                           r"within 0\.05s"):
        await wait_for_controller(player, timeout_s=0.05)
    waiting = asyncio.create_task(wait_for_controller(player, timeout_s=5))
    await net.settle()  # it has subscribed and waits: its chance to return (it must not)
    assert not waiting.done()
    robot.raw_publisher(robot.keys.status(CONTROLLER)).put(b"status")
    assert await waiting is True
    token.undeclare()
    await player.aclose()
    await robot.aclose()


# ---------------------------------------------------------------------------------------------
# The replay tool into a controller: the file's robot, a recording begun mid-run, a replay that
# falls behind


LATER_NS = 100 * 10**9


def recorded_later(path: Path, out: Path, robot: str, *, later_ns: int = LATER_NS) -> Path:
    """``path`` as a recorder attached ``later_ns`` into a run of robot ``robot`` would have
    written it: the robot's keys renamed, every stamp and log time ``later_ns`` later (the
    original msgpack channels only)."""
    with path.open("rb") as f, out.open("wb") as o:
        reader = make_reader(f)
        metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
        writer = Writer(o)
        writer.start()
        schemas: dict[int, int] = {}
        channels: dict[int, int] = {}
        for schema, channel, message in reader.iter_messages(log_time_order=True):
            if channel.message_encoding != "msgpack":
                continue
            if channel.id not in channels:
                assert schema is not None
                if schema.id not in schemas:
                    schemas[schema.id] = writer.register_schema(schema.name, schema.encoding,
                                                                schema.data)
                channels[channel.id] = writer.register_channel(
                    channel.topic.replace("ubf/mini/", f"ubf/{robot}/", 1), "msgpack",
                    schemas[schema.id])
            envelope = msgpack.unpackb(message.data)
            envelope["stamp_ns"] += later_ns
            writer.add_message(channels[channel.id], message.log_time + later_ns,
                               msgpack.packb(envelope), message.publish_time + later_ns)
        writer.add_metadata("ubf_async", {**metadata["ubf_async"], "robot": robot})
        writer.finish()
    return out


def status_lines(proc: Process, robot: str) -> list[str]:
    return [line for line in proc.lines if line.startswith(f"[{robot}]")]


def next_status(proc: Process, robot: str, after: int, *, timeout_s: float = 30) -> str:
    """The first status line of launch printed after the first ``after`` ones."""
    deadline = time.monotonic() + timeout_s
    while len(lines := status_lines(proc, robot)) <= after:
        assert proc.proc.poll() is None, proc.output()
        assert time.monotonic() < deadline, f"no new status line: {proc.output()}"
        time.sleep(0.05)
    return lines[after]


def test_a_replay_goes_to_the_recorded_robot_and_a_controller_joins_it_midway(
        recorded: tuple[Path, int], endpoint: str, tmp_path: Path, robot: str) -> None:
    # A recording of robot `robot` that starts 100 s into its run, as a recorder attached
    # late writes it; no --robot: the file's robot is the one fed.
    late = recorded_later(recorded[0], tmp_path / "late.mcap", robot)
    controller = Process("-m", "ubf_async.launch", "--no-sim", "--sim-time", "--listen",
                         endpoint, "--robot", robot)
    try:
        controller.wait_for_line("controller:", timeout_s=60)
        result = subprocess.run(
            [sys.executable, "-m", "ubf_async.replay", str(late), "--connect", endpoint,
             "--wait-for-robot-s", "60"], cwd=ROOT, env=ENV, capture_output=True, text=True,
            timeout=120)
        assert result.returncode == 0, result.stdout + result.stderr
        assert f"onto robot {robot!r}" in result.stdout and "7 keys)" in result.stdout
        # The controller's rates once the replay is over (its clock stands still since).
        last = next_status(controller, robot, len(status_lines(controller, robot)))
    finally:
        controller.terminate(timeout_s=30)
    # Its clock started at the recording's first instant: 50 Hz ticks from there, not a
    # rate over the 100 s its clock jumped from 0 (about 2 Hz), and no sample refused as
    # ahead of a clock that had no time yet.
    rate = re.search(r"tick (\d+\.\d)Hz", last)
    assert rate is not None and float(rate[1]) >= 25, last
    assert not any("refused" in line for line in controller.lines), controller.output()


def test_a_replay_held_up_says_what_held_it_up(
        recorded: tuple[Path, int], endpoint: str) -> None:
    controller = Process("-m", "ubf_async.launch", "--no-sim", "--sim-time", "--listen",
                         endpoint)
    replaying: subprocess.Popen[str] | None = None
    try:
        controller.wait_for_line("controller:", timeout_s=60)
        replaying = subprocess.Popen(
            [sys.executable, "-m", "ubf_async.replay", str(recorded[0]), "--connect", endpoint,
             "--wait-for-robot-s", "60"], cwd=ROOT, env=ENV, stdout=subprocess.PIPE,
            stderr=subprocess.PIPE, text=True)
        # Once the recording flows (the controller holds the camera's samples), the replay
        # is stopped for a second, as Ctrl-Z would: its schedule runs on.
        controller.wait_for_line("| camera/front ", timeout_s=60)  # a status field
        replaying.send_signal(signal.SIGSTOP)
        time.sleep(1.0)  # how long it is held up, not a wait for anything
        replaying.send_signal(signal.SIGCONT)
        out, err = replaying.communicate(timeout=120)
    finally:
        if replaying is not None and replaying.poll() is None:
            replaying.kill()
            replaying.wait()
        controller.terminate(timeout_s=30)
    assert replaying.returncode == 0, out + err
    # Said at once on stderr (after what a busy machine may have held it up before, as it
    # is twice as far behind), and again in the last line: how far behind, and why.
    assert any(line.startswith(f"{REPLAY}: falling behind: ") and "it was stopped" in line
               for line in err.splitlines()), err
    last = out.splitlines()[-1]
    behind = re.search(r"messages replayed, at worst (\d+) ms behind, [\d.]+ s into the "
                       r"recording: meanwhile this process ", last)
    assert behind is not None and int(behind[1]) >= 800, last
    assert "it was stopped" in last, last


def test_a_stop_is_named_even_when_it_fell_inside_a_put() -> None:
    """A SIGSTOP that lands while the replay is inside zenoh's put makes that put last the
    whole stop: measured, it looks like a slow network. The SIGCONT that continued the
    process says what it was (seen on a loaded machine: 1005 ms 'in zenoh's put')."""
    from ubf_async.tools.replay import Lag

    held = Lag(behind_s=1.0, at_s=0.2, elapsed_s=1.01, cpu_wait_s=0.0, computing_s=0.002,
               reading_s=0.0, publishing_s=1.005, stopped=True)
    cause = held.cause()
    assert cause.startswith("meanwhile this process was stopped and continued"), cause
    assert "it was stopped" in cause and "in zenoh's put" in cause
    slow = Lag(behind_s=1.0, at_s=0.2, elapsed_s=1.01, cpu_wait_s=0.0, computing_s=0.002,
               reading_s=0.0, publishing_s=1.005)
    assert "stopped" not in slow.cause().split(";")[0], slow.cause()


@pytest.mark.asyncio
async def test_a_replay_of_everything_shows_in_the_tree_monitor(
        recorded: tuple[Path, int]) -> None:
    """``replay FILE --only '**'`` with ``python -m ubf_async.monitor`` watching (docs/
    monitor.md): the recorded run's own traces, drives and sources reach the monitor as a live
    robot's would; with no tree service to ask, it draws the tree from the traces."""
    from ubf_async.services.monitor import MonitorServer

    path, _ = recorded
    net, clock = InProcessTransport(), SimClock(0)
    watcher = Bus(transport=net, robot="mini", clock=clock)
    player = Bus(transport=net, robot="mini", clock=clock)
    monitor = MonitorServer(bus=watcher, port=0)
    await monitor.start()
    winners: set[str] = set()
    traced = monitor.model.on_trace

    def on_trace(message: Any) -> None:
        traced(message)
        winners.update(monitor.model.ticks[-1][3])

    monitor.model.on_trace = on_trace  # type: ignore[method-assign]
    try:
        await net.settle()
        stats = await replay(Recording(path, only=["**"]), bus=player, speed=None, clock=clock,
                             settle=net.settle)
        assert stats.published > 1000
        recorded_winners = {w for _, _, ws, _, _ in recorded_drives(path) for w in ws}
        assert "chase" in winners and winners == recorded_winners
        model = monitor.model
        assert model.trace is not None and model.trace["nodes"][0]["name"] == "seek_pink_ball"
        assert model.drive is not None and model.status is not None
        assert {"camera/front", "range/front"} <= set(model.state)
        assert model.tree is None  # a recording has no tree service: the traces draw it
    finally:
        await monitor.aclose()
        await player.aclose()
        await watcher.aclose()
