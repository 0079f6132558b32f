"""Time you can trust: only the robot's simulator moves simulated time, a new run is
recognised by everyone, and safety deadlines hold in wall time when simulated time stops.

The policy (:class:`~ubf_async.clocks.timesource.ClockFollower`) and the deadline rule
(:class:`~ubf_async.clocks.clock.SilenceLimit`) are unit-tested; the rest runs real processes on
loopback zenoh: a simulator in this process, devices and a controller in their own, and an
outsider publishing plain zenoh + msgpack.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from components.motors.component import DEFAULT_TIMEOUT_S
from components.sim.world.config import Arena, WorldConfig
from tests.conftest import SimRobot, eventually, free_port, read_until, spawn, stop, zenoh_session
from ubf_async.clocks import clock as clock_module
from ubf_async.clocks import follow
from ubf_async.clocks.clock import MIN_SILENCE_S, SilenceLimit, SimClock, every, sleep_until
from ubf_async.clocks.simclock import follow_sim_clock
from ubf_async.clocks.timesource import ClockAction, ClockFollower
from ubf_async.runtime.bus import Bus
from ubf_async.wire.protocol import decode
from ubf_async.wire.topics import CLOCK, SIM_WORLD

ROOT = Path(__file__).resolve().parent.parent
ENV = {**os.environ, "PYTHONUNBUFFERED": "1"}
S = 1_000_000_000  # one second in ns


def floor() -> WorldConfig:
    return WorldConfig(arena=Arena(x_min_m=-5, x_max_m=5, y_min_m=-5, y_max_m=5))


# ---------------------------------------------------------------------------------------------
# The follower's policy, without a bus


def test_follower_locks_the_first_epoch_and_never_goes_back() -> None:
    f = ClockFollower()
    assert f.offer(stamp_ns=5 * S, epoch="a", wall_ns=0).action is ClockAction.ADVANCE
    assert f.epoch == "a" and f.runs == 1
    assert f.offer(stamp_ns=5 * S + 10, epoch="a", wall_ns=1).action is ClockAction.ADVANCE
    assert f.offer(stamp_ns=5 * S + 10, epoch="a", wall_ns=2).action is ClockAction.ADVANCE
    verdict = f.offer(stamp_ns=4 * S, epoch="a", wall_ns=3)
    assert verdict.action is ClockAction.REFUSE and verdict.reason == "backwards"
    assert f.last_stamp_ns == 5 * S + 10 and f.refused == {"backwards": 1}


def test_follower_refuses_implausible_jumps_but_not_a_fast_simulator() -> None:
    f = ClockFollower(max_speed=100.0, slack_s=0.5)
    f.offer(stamp_ns=0, epoch="a", wall_ns=0)
    # 100x for 10 ms of wall time is 1 s, plus 0.5 s slack: 1.4 s goes, 1.6 s does not.
    assert f.offer(stamp_ns=2**62, epoch="a", wall_ns=10_000_000).reason == "implausible jump"
    assert f.offer(stamp_ns=1_600_000_000, epoch="a",
                   wall_ns=10_000_000).reason == "implausible jump"
    assert f.offer(stamp_ns=1_400_000_000, epoch="a",
                   wall_ns=10_000_000).action is ClockAction.ADVANCE
    # After a long silence of the simulator itself, a matching jump is plausible.
    assert f.offer(stamp_ns=101 * S, epoch="a", wall_ns=1_010_000_000).action is ClockAction.ADVANCE


def test_another_epoch_takes_over_only_after_the_current_one_fell_silent() -> None:
    f = ClockFollower(takeover_s=1.0)
    f.offer(stamp_ns=100 * S, epoch="old", wall_ns=0)
    f.offer(stamp_ns=100 * S + 1, epoch="old", wall_ns=S // 2)
    for epoch in ("new", None):  # a sample without an epoch is just another epoch
        verdict = f.offer(stamp_ns=S, epoch=epoch, wall_ns=S)  # old heard 0.5 s ago
        assert verdict.action is ClockAction.REFUSE and verdict.reason == "other epoch"
    assert f.epoch == "old"
    # The old run silent for 1 s (wall): the new one is a new run, and time may go back.
    assert f.offer(stamp_ns=S, epoch="new", wall_ns=S // 2 + S).action is ClockAction.RESET
    assert (f.epoch, f.runs, f.last_stamp_ns) == ("new", 2, S)
    assert f.offer(stamp_ns=200 * S, epoch="old", wall_ns=2 * S).reason == "other epoch"
    assert f.offer(stamp_ns=S + 5, epoch="new", wall_ns=2 * S).action is ClockAction.ADVANCE


def test_a_pinned_epoch_is_the_only_one_ever_followed() -> None:
    f = ClockFollower(epoch="mine")
    assert f.offer(stamp_ns=S, epoch="other", wall_ns=0).reason == "other epoch"
    assert not f.locked
    assert f.offer(stamp_ns=2 * S, epoch="mine", wall_ns=1).action is ClockAction.ADVANCE
    assert f.offer(stamp_ns=S, epoch="other", wall_ns=100 * S).reason == "other epoch"


def test_refusals_are_counted_and_logged_first_and_every_100th(
    caplog: pytest.LogCaptureFixture,
) -> None:
    f = ClockFollower()
    f.offer(stamp_ns=S, epoch="a", wall_ns=0)
    with caplog.at_level(logging.WARNING, logger="ubf_async.clocks.timesource"):
        for i in range(250):
            f.offer(stamp_ns=0, epoch="a" if i % 2 else "b", wall_ns=1)
    assert f.refused == {"backwards": 125, "other epoch": 125} and f.refused_total == 250
    assert len([r for r in caplog.records if "refused clock sample" in r.message]) == 3


def test_the_robots_run_is_locked_onto_before_another_heard_first() -> None:
    """Another simulator of this robot name reached through gossip speaks first: its run waits
    while the robot connected to may still speak; the robot's run, once heard, is locked."""
    f = ClockFollower(robot_sessions=frozenset({"robot"}), prefer_s=2.0)
    verdict = f.offer(stamp_ns=100 * S, epoch="other", wall_ns=0, zid="elsewhere")
    assert verdict.action is ClockAction.REFUSE and verdict.reason == "not the robot's"
    assert f.offer(stamp_ns=100 * S, epoch="old", wall_ns=S, zid=None).reason == "not the robot's"
    assert not f.locked
    assert f.offer(stamp_ns=12 * S, epoch="mine", wall_ns=S, zid="robot").action \
        is ClockAction.ADVANCE
    assert (f.epoch, f.last_stamp_ns) == ("mine", 12 * S)
    assert f.offer(stamp_ns=101 * S, epoch="other", wall_ns=S + S // 2,
                   zid="elsewhere").reason == "other epoch"
    # Reached through a router, or with the simulator in another process than the robot: the
    # robot's session publishes no time, and the run heard is followed after prefer_s.
    g = ClockFollower(robot_sessions=frozenset({"router"}), prefer_s=2.0)
    assert g.offer(stamp_ns=S, epoch="e", wall_ns=0, zid="sim").reason == "not the robot's"
    assert g.offer(stamp_ns=S, epoch="e", wall_ns=S, zid="sim").reason == "not the robot's"
    assert g.offer(stamp_ns=2 * S, epoch="e", wall_ns=2 * S, zid="sim").action \
        is ClockAction.ADVANCE
    # Knowing no session of the robot (it connected to us): the first run heard, at once.
    assert ClockFollower().offer(stamp_ns=S, epoch="e", wall_ns=0, zid="sim").action \
        is ClockAction.ADVANCE


def test_follower_rejects_nonsense_settings() -> None:
    for bad in ({"takeover_s": 0}, {"max_speed": -1}, {"slack_s": -0.1}, {"prefer_s": -1}):
        with pytest.raises(ValueError):
            ClockFollower(**bad)  # type: ignore[arg-type]


# ---------------------------------------------------------------------------------------------
# The clock: resets wake sleepers and re-anchor periodic loops; the deadline rule


@pytest.mark.asyncio
async def test_a_reset_wakes_sleepers_and_reanchors_every() -> None:
    clock = SimClock(start_ns=1000 * S)
    ticks: list[int] = []

    async def loop() -> None:
        async for stamp in every(clock, 0.1):
            ticks.append(stamp)

    task = asyncio.create_task(loop())
    await eventually(lambda: ticks == [1000 * S])
    sleeper = asyncio.create_task(clock.sleep_until_ns(2000 * S))
    await asyncio.sleep(0)
    clock.reset_to(3 * S)  # a new run, far earlier
    await asyncio.wait_for(sleeper, 1)
    await eventually(lambda: len(ticks) == 2)
    assert ticks[1] == 3 * S and clock.resets == 1
    clock.advance_to(3 * S + 99_000_000)
    for _ in range(5):
        await asyncio.sleep(0)
    assert len(ticks) == 2  # the next tick is due 0.1 s after the new run's start, not before
    clock.advance_to(3 * S + 100_000_000)
    await eventually(lambda: len(ticks) == 3)
    assert ticks[2] == 3 * S + 100_000_000
    task.cancel()


@pytest.mark.asyncio
async def test_a_sleep_cancelled_as_its_robot_time_comes_is_cancelled() -> None:
    """A watchdog's sleep (robot time or wall time, whichever comes first) cancelled in the
    instants after its robot time came, before it resumed, ends cancelled: Python 3.11's
    ``asyncio.wait_for`` returned normally then, and the motors' watchdog closed in that
    instant went on guarding, and then waited for a command for ever (its close with it)."""
    clock = SimClock(start_ns=S)
    far = time.monotonic_ns() + 3600 * S  # the wall deadline plays no part
    for rounds in range(6):  # how many rounds of the loop between the wake-up and the cancel
        sleeping = asyncio.create_task(sleep_until(clock, clock.now_ns() + S,
                                                   wall_deadline_ns=far))
        for _ in range(3):  # (rounds of the loop: the sleep started and asleep)
            await asyncio.sleep(0)
        assert clock.next_wakeup_ns() == clock.now_ns() + S
        clock.advance_to(clock.now_ns() + S)  # its robot time comes
        for _ in range(rounds):
            await asyncio.sleep(0)
        asked = sleeping.cancel()
        await asyncio.wait({sleeping})
        # Cancelled if it was still going when asked; ended normally only if it had already.
        assert sleeping.cancelled() == asked, (rounds, asked)


@pytest.mark.asyncio
async def test_motors_closed_after_their_session_end_when_cancelled(robot_bus: Bus) -> None:
    """An event loop's teardown cancels what is left after the fixtures closed the session:
    the motors' stop pulse cannot be published any more (zenoh: session closed), and that
    ends their task — it does not count as a failure to restart from, again and again, for
    ever."""
    from components.motors.component import MotorsComponent
    from components.sim.backends.devices import SimMotorBackend
    from components.sim.world.physics import World

    robot_bus.clock = SimClock(start_ns=S)
    motors = MotorsComponent(bus=robot_bus, backend=SimMotorBackend(World(floor())))
    await motors.start()
    try:
        await eventually(lambda: motors.applied is not None, what="the init pulse")
        run = motors._tasks[0]
        await robot_bus.aclose()
        run.cancel()
        done, _ = await asyncio.wait({run}, timeout=30)
        assert done and run.cancelled() and motors.restarts == 0, (run, motors.last_error)
    finally:
        await motors.aclose()


@pytest.mark.asyncio
async def test_the_controllers_periodic_ticks_reanchor_on_a_new_run(robot_bus: Bus) -> None:
    from ubf_async.core.behavior import FunctionBehavior
    from ubf_async.runtime.aggregator import StateAggregator
    from ubf_async.runtime.controller import Controller

    clock = SimClock(start_ns=1000 * S)
    robot_bus.clock = clock
    agg = StateAggregator(bus=robot_bus)
    ctl = Controller(bus=robot_bus, aggregator=agg, root=FunctionBehavior(lambda s: None),
                     rate_hz=50)
    async with agg, ctl:
        await eventually(lambda: ctl.stats.ticks == 1, what="the first tick")
        clock.reset_to(5 * S)  # the old run's next tick was due at 1000.02 s
        await eventually(lambda: ctl.stats.ticks == 2, what="a tick at the new run's start")
        for step in range(1, 6):
            clock.advance_to(5 * S + step * 20_000_000)
            await eventually(lambda step=step: ctl.stats.ticks == 2 + step,
                             what=f"tick {step} of the new run")
    # The old run's tick is forgotten: a rate across the reset would measure the jump.
    assert list(ctl.stats.tick_starts_ns) == [5 * S + i * 20_000_000 for i in range(6)]
    assert ctl.stats.rate_hz() == pytest.approx(50)


class FakeClock:
    """A clock whose robot time and stall are set by the test."""

    resets = 0

    def __init__(self) -> None:
        self.now = 0
        self.stalled = 0.0

    def now_ns(self) -> int:
        return self.now

    def stalled_s(self, wall_now_ns: int | None = None) -> float:
        return self.stalled


def test_silence_limit_robot_time_or_a_silent_time_source() -> None:
    limit = SilenceLimit(limit_s=0.15)
    clock = FakeClock()

    def expired(robot_s: float, wall_s: float, stalled_s: float) -> bool:
        clock.now, clock.stalled = round(robot_s * S), stalled_s
        return limit.expired(clock, since_ns=0, since_wall_ns=0,  # type: ignore[arg-type]
                             wall_now_ns=round(wall_s * S))

    assert limit.silence_s == MIN_SILENCE_S  # the floor, above the 0.15 s limit
    assert expired(0.15, 0.15, 0.0)  # (a) robot time
    assert not expired(0.14, 0.14, 0.0)
    # A live simulator crawling at 0.01x real time (a lockstep barrier waiting on a slow
    # machine): judged in simulated time only, however much wall time passes.
    assert not expired(0.14, 14.0, 0.0)
    assert not expired(0.0, 60.0, 0.0)
    # (b) the time source silent for the silence limit (a dead simulator)
    assert expired(0.0, MIN_SILENCE_S, MIN_SILENCE_S)
    assert not expired(0.0, MIN_SILENCE_S, MIN_SILENCE_S - 0.01)
    assert not expired(0.0, MIN_SILENCE_S - 0.01, 5.0)  # heard from it more recently
    assert SilenceLimit(limit_s=2.0).silence_s == 2.0  # a longer limit is its own floor
    # When to re-check: once the source has been silent for the silence limit.
    clock.stalled = 0.05
    assert limit.wall_deadline_ns(clock, since_wall_ns=0,  # type: ignore[arg-type]
                                  wall_now_ns=S // 10) == S // 20 + round(MIN_SILENCE_S * S)
    with pytest.raises(ValueError):
        SilenceLimit(limit_s=0)


def test_a_driven_or_held_sim_clock_is_never_stalled_and_a_dead_one_is() -> None:
    clock = SimClock()
    clock.advance_to(S)
    t = time.monotonic_ns()
    assert clock.stalled_s(t + 2 * S) >= 2.0  # nobody has moved it for 2 s
    hold = clock.hold(2 * S)
    assert clock.stalled_s(t + 2 * S) == 0.0  # held on purpose by this process: no stall
    hold.release()
    with clock.driven():  # a simulator of this process runs: alive, however long it waits
        assert clock.stalled_s(t + 60 * S) == 0.0
        before = time.monotonic_ns()
    after = time.monotonic_ns()
    # The simulator stopped (or crashed) between the two readings: silence from then on.
    # (Bounds from the readings, not a tolerance: a busy machine may pause between them.)
    assert 1.0 <= clock.stalled_s(after + S) <= 1.0 + (after - before) / 1e9


def test_a_followed_clock_is_kept_alive_by_its_simulators_samples_of_the_same_time(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """A simulator in another process that holds time still sends its time again
    (``lockstep.RESEND_S``): the same stamp is a sign of life, not a stall."""
    wall = [10 * S]
    monkeypatch.setattr(clock_module.time, "monotonic_ns", lambda: wall[0])
    clock = SimClock()
    clock.advance_to(S)
    wall[0] += 3 * S
    assert clock.stalled_s() == 3.0  # silent for 3 s
    clock.advance_to(S)  # the heartbeat: the same time again
    assert clock.now_ns() == S and clock.stalled_s() == 0.0
    wall[0] += S // 2
    clock.advance_to(S // 2)  # an older time moves nothing, but it too was heard
    assert clock.now_ns() == S and clock.stalled_s() == 0.0


# ---------------------------------------------------------------------------------------------
# Separate processes: an outsider's clock messages move nothing

OUTSIDER = r"""
import json, sys, time
import msgpack, zenoh
endpoint, key, messages = sys.argv[1], sys.argv[2], json.loads(sys.argv[3])
conf = zenoh.Config()
conf.insert_json5("mode", '"peer"')
conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
conf.insert_json5("scouting/multicast/enabled", "false")
session = zenoh.open(conf)
pub = session.declare_publisher(key)
deadline = time.monotonic() + 10
while not pub.matching_status.matching and time.monotonic() < deadline:
    time.sleep(0.01)
for _ in range(5):
    for m in messages:
        pub.put(msgpack.packb(m))
        time.sleep(0.01)
print("sent", flush=True)
session.close()
"""


def clock_message(stamp_ns: int, data: dict[str, object]) -> dict[str, object]:
    return {"schema": "clock", "v": 1, "stamp_ns": stamp_ns, "seq": 1, "data": data}


async def outsider(endpoint: str, key: str, messages: list[dict[str, object]]) -> None:
    """Publish ``messages`` on ``key`` from another process (plain zenoh + msgpack)."""
    import json

    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-c", OUTSIDER, endpoint, key, json.dumps(messages), cwd=ROOT, env=ENV,
        stdout=asyncio.subprocess.PIPE)
    out, _ = await asyncio.wait_for(proc.communicate(), 30)
    assert proc.returncode == 0 and b"sent" in out


def attacks(epoch: str) -> list[dict[str, object]]:
    huge = 2**62
    return [
        clock_message(huge, {"epoch": "not-the-simulator"}),
        clock_message(huge, {}),  # no epoch at all
        clock_message(huge, {"epoch": epoch, "real_time_factor": 1.0}),  # right epoch, jump
    ]


async def witness_refusals(peer_bus: Bus, endpoint: str, epoch: str) -> ClockFollower:
    """Send the attacks while a follower in this process watches: it proves they were
    delivered on the bus (and refused) — the same samples the process under test received."""
    witness = ClockFollower(name="witness")
    follow_sim_clock(peer_bus, SimClock(), {}, follower=witness)
    await eventually(lambda: witness.locked, what="the witness to lock onto the simulator")
    await outsider(endpoint, peer_bus.keys.clock, attacks(epoch))
    await eventually(lambda: witness.refused["other epoch"] >= 2
                     and witness.refused["implausible jump"] >= 1,
                     what="the witness to see the outsider's samples")
    assert witness.epoch == epoch
    return witness


def start(*args: str) -> subprocess.Popen[bytes]:
    return subprocess.Popen([sys.executable, *args], cwd=ROOT, env=ENV,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def finish(proc: subprocess.Popen[bytes]) -> None:
    proc.kill()
    proc.wait(timeout=20)


async def drive_then_stop(peer_bus: Bus, seconds: float) -> float:
    """Publish drive commands at 50 Hz (wall) for ``seconds``; return when the last was sent
    (host monotonic seconds)."""
    pub = peer_bus.publisher(peer_bus.keys.cmd("drive"), "drive")
    await pub.wait_for_subscribers()
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        pub.publish({"speed": 40.0, "turn": 0.0})
        await asyncio.sleep(0.02)
    pub.publish({"speed": 40.0, "turn": 0.0})
    last = time.monotonic()
    pub.close()
    return last


@pytest.mark.asyncio
async def test_outsider_clock_cannot_disable_a_standalone_motors_watchdog(
    robot_bus: Bus, peer_bus: Bus, endpoint: str, robot: str
) -> None:
    applied: list[tuple[int, str]] = []
    robot_bus.subscribe(robot_bus.keys.sensor("motors", "main"),
                        lambda k, p, t: applied.append((decode(p).stamp_ns,
                                                        decode(p).data.reason)),
                        latest=False)
    async with SimRobot(robot_bus, floor(), speed=1, devices=()) as sim:
        motors = start("-m", "components.motors", "--connect", endpoint, "--robot", robot)
        try:
            await eventually(lambda: any(r == "init" for _, r in applied), timeout_s=30,
                             what="the motors process to attach")
            await drive_then_stop(peer_bus, 0.2)
            await eventually(lambda: applied[-1][1] == "timeout", what="a first watchdog stop")
            await witness_refusals(peer_bus, endpoint, sim.sim.epoch)
            before = len(applied)
            await drive_then_stop(peer_bus, 0.3)
            await eventually(lambda: len(applied) > before and applied[-1][1] == "timeout",
                             what="the watchdog to stop the wheels after the attack")
        finally:
            finish(motors)
        # The motors' clock followed the simulator throughout, never the outsider's time.
        now = sim.clock.now_ns()
        assert all(stamp <= now for stamp, _ in applied), applied[-3:]
        commands = [stamp for stamp, reason in applied[before:] if reason == "command"]
        gap_s = (applied[-1][0] - commands[-1]) / 1e9
        assert DEFAULT_TIMEOUT_S - 0.01 <= gap_s <= DEFAULT_TIMEOUT_S + 0.2, gap_s


@pytest.mark.asyncio
async def test_outsider_clock_cannot_freeze_a_sim_time_controller(
    robot_bus: Bus, peer_bus: Bus, endpoint: str, robot: str
) -> None:
    drives: list[int] = []
    async with SimRobot(robot_bus, floor(), speed=1, devices=("motors",)) as sim:
        robot_bus.subscribe(robot_bus.keys.cmd("drive"),
                            lambda k, p, t: drives.append(decode(p).stamp_ns), latest=False)
        controller = start("-m", "ubf_async.launch", "--no-sim", "--sim-time", "--connect",
                           endpoint, "--robot", robot, "--quiet", "--listen",
                           "tcp/127.0.0.1:0")
        try:
            await eventually(lambda: len(drives) >= 10, timeout_s=30,
                             what="the controller to tick on simulated time")
            await witness_refusals(peer_bus, endpoint, sim.sim.epoch)
            after_attack = len(drives)
            # Still ticking at 50 Hz of simulated time: 25 more ticks take 0.5 s.
            await eventually(lambda: len(drives) >= after_attack + 25, timeout_s=10,
                             what="the controller to keep ticking after the attack")
        finally:
            finish(controller)
        now = sim.clock.now_ns()
        assert all(stamp <= now for stamp in drives)
        assert drives[-1] > drives[after_attack - 1]


@pytest.mark.asyncio
async def test_a_restarted_simulator_is_followed_and_sensors_resume(
    robot_bus: Bus, endpoint: str, robot: str
) -> None:
    """A range finder in its own process keeps publishing when the simulator is replaced by
    a new run whose time starts again at 0 (before: silent for the old run's whole time)."""
    samples: list[int] = []
    robot_bus.subscribe(robot_bus.keys.sensor("range", "front"),
                        lambda k, p, t: samples.append(decode(p).stamp_ns), latest=False)
    async with SimRobot(robot_bus, floor(), speed=20, devices=()) as first:
        sensor = start("-m", "components.range", "--connect", endpoint, "--robot", robot)
        try:
            await eventually(lambda: len(samples) >= 3, timeout_s=30,
                             what="the range finder to publish on the first run's time")
            await eventually(lambda: first.clock.now_ns() >= 20 * S, timeout_s=10,
                             what="20 s of simulated time")
            old_end = first.clock.now_ns()
        except BaseException:
            finish(sensor)
            raise
    try:
        async with SimRobot(robot_bus, floor(), speed=1, devices=()) as second:
            assert second.sim.epoch != first.sim.epoch
            await eventually(lambda: any(stamp < old_end / 2 for stamp in samples[-3:]),
                             timeout_s=10,
                             what="samples stamped with the new run's time")
            n = len(samples)
            await eventually(lambda: len(samples) >= n + 3, timeout_s=5,
                             what="the range finder to keep publishing on the new run")
            assert samples[-1] <= second.clock.now_ns()
    finally:
        finish(sensor)


class WithheldClock:
    """A simulator as a sim-backed device in another process sees it, with its clock
    withheld: the world snapshot goes out every 20 ms from the start, the clock only once
    :meth:`release` is called (then every 5 ms, advancing from 12 s) — the order in which a
    running robot answers a device that has just subscribed (the simulator publishes its
    world whenever a process listens, its clock once it has noticed a follower, up to 20
    steps later), made as long as the test needs."""

    def __init__(self, bus: Bus, *, epoch: str, start_ns: int = 12 * S) -> None:
        from components.sim.world.physics import World
        from components.sim.world.snapshot_data import snapshot_to_data

        self.token = bus.declare_token(bus.keys.alive("sim"))  # the robot, to attach to
        self.world = bus.publisher(SIM_WORLD, period_s=0.02)
        self.clock = bus.publisher(CLOCK, period_s=0.005)
        self.snapshot = snapshot_to_data(World(floor()).snapshot_for(0))
        self.epoch = epoch
        self.zid = bus.session_id  # named in its samples, as the simulator does
        self.now_ns = start_ns
        self.released = asyncio.Event()
        self.task = asyncio.create_task(self._run())

    def release(self) -> None:
        self.released.set()

    async def _run(self) -> None:
        steps = 0
        while True:  # the simulator's pace, not a wait for anything
            if steps % 4 == 0:
                self.world.publish(self.snapshot, stamp_ns=self.now_ns)
            if self.released.is_set():
                self.clock.publish({"epoch": self.epoch, "zid": self.zid},
                                   stamp_ns=self.now_ns)
                self.now_ns += 5_000_000
            steps += 1
            await asyncio.sleep(0.005)

    async def aclose(self) -> None:
        self.task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await self.task
        self.token.undeclare()


@pytest.mark.asyncio
async def test_an_attached_device_stamps_nothing_before_it_hears_the_robots_time(
    robot_bus: Bus, endpoint: str, robot: str
) -> None:
    """Issue 35: a range finder attached to a robot that had run for 12 s stamped its first
    sample 0 — its clock's start, before any of the robot's time had reached it — and the
    robot took it for another clock. With the world there and the clock withheld, the
    device waits, says so, and its first sample is stamped on the robot's time."""
    stamps: list[int] = []
    robot_bus.subscribe(robot_bus.keys.sensor("range", "left"),
                        lambda k, p, t: stamps.append(decode(p).stamp_ns), latest=False)
    sim = WithheldClock(robot_bus, epoch="robot")
    device = await spawn("-m", "components.range", "--connect", endpoint, "--robot", robot,
                         "--name", "left")
    waiting = asyncio.create_task(read_until(device, "waiting for the simulation time"))
    try:
        await eventually(lambda: waiting.done() or bool(stamps), timeout_s=30,
                         what="the device to wait for the clock, or to publish")
        assert not stamps, f"published before hearing the robot's time: stamped {stamps}"
        await waiting  # (its error, if it ended otherwise)
        sim.release()
        await read_until(device, "attached")
        await eventually(lambda: bool(stamps), timeout_s=10, what="the first sample")
        assert stamps[0] >= 12 * S, stamps[:3]
    finally:
        waiting.cancel()
        await stop(device)
        await sim.aclose()


@pytest.mark.asyncio
async def test_the_robots_time_is_followed_when_another_run_of_its_name_speaks_first(
    robot_bus: Bus, endpoint: str, robot: str, caplog: pytest.LogCaptureFixture
) -> None:
    """Another simulator of this robot name, connected to the robot, reaches a process that
    attaches to the robot through zenoh's gossip, and its time arrives first. The process
    follows the robot's run all the same (before: the first heard, 88 s ahead)."""
    from ubf_async.net.options import ConnectionOptions

    other_endpoint = f"tcp/127.0.0.1:{free_port()}"
    other = await Bus.open(ConnectionOptions(robot=robot, listen=[other_endpoint],
                                             connect=[endpoint]))
    follower = None
    sims: list[WithheldClock] = []
    try:
        robot_session = zenoh_session(robot_bus)
        await eventually(lambda: other.session_id in map(str, robot_session.info.peers_zid()),
                         what="the other simulator to connect to the robot")
        follower = await Bus.open(ConnectionOptions(robot=robot, connect=[endpoint]))
        reached = {robot_bus.session_id, other.session_id}
        follower_session = zenoh_session(follower)
        await eventually(lambda: reached <= set(map(str, follower_session.info.peers_zid())),
                         what="the follower to reach both (gossip)")
        sims.append(WithheldClock(other, epoch="other", start_ns=100 * S))
        sims[-1].release()
        mine = WithheldClock(robot_bus, epoch="mine")
        sims.append(mine)
        with caplog.at_level(logging.WARNING, logger="ubf_async.clocks.timesource"):
            choosing = asyncio.create_task(follow.follow_robot_clock(follower, mode="sim"))
            await eventually(lambda: choosing.done() or "(not the robot's)" in caplog.text,
                             timeout_s=15, what="the other run to be heard")
            if choosing.done():
                raise AssertionError(f"followed the run heard first, at "
                                     f"{choosing.result().now_ns() / S:g} s")
            mine.release()
            clock = await asyncio.wait_for(choosing, 15)
        assert 12 * S <= clock.now_ns() < 50 * S, clock.now_ns() / S
    finally:
        for sim in sims:
            await sim.aclose()
        if follower is not None:
            await follower.aclose()
        await other.aclose()


@pytest.mark.asyncio
async def test_a_router_at_the_endpoint_is_not_taken_for_the_robot(robot: str) -> None:
    """Reached through a router (a fleet), the robot's session is behind the endpoint: the
    follower knows no session of the robot and takes the run it hears — no 2 s wait, no
    warning — while a peer connected straight to the robot knows it."""
    from ubf_async.net.options import ConnectionOptions

    router_endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = await Bus.open(ConnectionOptions(robot=robot, mode="router",
                                              listen=[router_endpoint]))
    client = None
    try:
        client = await Bus.open(ConnectionOptions(robot=robot, mode="client",
                                                  connect=[router_endpoint]))
        await eventually(lambda: bool(list(zenoh_session(client).info.routers_zid())),
                         what="the client to reach the router")
        assert await client.connected_sessions() == frozenset()
        peer = await Bus.open(ConnectionOptions(robot=robot, connect=[router_endpoint]))
        try:
            await eventually(lambda: bool(list(zenoh_session(peer).info.routers_zid())),
                             what="the peer to reach the router")
            assert await peer.connected_sessions() == frozenset()
        finally:
            await peer.aclose()
    finally:
        if client is not None:
            await client.aclose()
        await router.aclose()


@pytest.mark.asyncio
async def test_the_simulator_names_its_session_in_its_clock(robot_bus: Bus,
                                                            peer_bus: Bus) -> None:
    zids: list[str | None] = []
    peer_bus.subscribe(peer_bus.keys.clock, lambda k, p, t: zids.append(decode(p).data.zid))
    async with SimRobot(robot_bus, floor(), speed=1, devices=()):
        await eventually(lambda: bool(zids), what="a clock sample")
    assert zids[0] == robot_bus.session_id and zids[0]


@pytest.mark.asyncio
async def test_motors_stop_in_wall_time_when_simulated_time_stops(
    robot_bus: Bus, peer_bus: Bus, endpoint: str, robot: str
) -> None:
    applied: list[tuple[float, str]] = []
    robot_bus.subscribe(robot_bus.keys.sensor("motors", "main"),
                        lambda k, p, t: applied.append((time.monotonic(),
                                                        decode(p).data.reason)),
                        latest=False)
    sim = SimRobot(robot_bus, floor(), speed=1, devices=())
    await sim.__aenter__()
    sim_running = True
    motors = start("-m", "components.motors", "--connect", endpoint, "--robot", robot)
    try:
        await eventually(lambda: any(r == "init" for _, r in applied), timeout_s=30,
                         what="the motors process to attach")
        pub = peer_bus.publisher(peer_bus.keys.cmd("drive"), "drive")
        await pub.wait_for_subscribers()
        for _ in range(10):
            pub.publish({"speed": 40.0, "turn": 0.0})
            await asyncio.sleep(0.02)
        await eventually(lambda: applied[-1][1] == "command", what="the wheels to turn")
        sim_running = False
        await sim.__aexit__(None, None, None)  # simulated time stops here, for good
        pub.publish({"speed": 40.0, "turn": 0.0})
        last_s = time.monotonic()
        limit = SilenceLimit(limit_s=DEFAULT_TIMEOUT_S)
        await eventually(lambda: applied[-1][1] == "timeout", timeout_s=limit.silence_s + 5,
                         what="the watchdog to stop the wheels in wall time")
        stopped_after_s = applied[-1][0] - last_s
        # Rule (b): no command and no clock for the silence limit of wall time; not before
        # (the bound above it is a sanity bound for a busy machine).
        assert limit.silence_s - 0.05 <= stopped_after_s <= limit.silence_s + 3, stopped_after_s
    finally:
        finish(motors)
        if sim_running:
            await sim.__aexit__(None, None, None)
