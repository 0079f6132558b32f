"""Unit tests of the aggregator, the controller and remote votes on the in-process transport:
real buses, real msgpack, a :class:`SimClock` the test advances, and
``await net.settle()`` instead of waiting — no zenoh session, no sleeps.

Each test wires what would be separate processes as separate buses on one
:class:`InProcessTransport` (the device's, the robot's, a remote behaviour's host)."""

from __future__ import annotations

import contextlib
from collections.abc import AsyncIterator
from typing import Any

import msgpack
import pytest
import pytest_asyncio

from tests.conftest import as_dict
from ubf_async.behaviors.basic import ConstantDrive
from ubf_async.clocks.clock import SimClock
from ubf_async.core.action import Action
from ubf_async.core.arbiters import HighestPriority
from ubf_async.core.behavior import Behavior, Composite
from ubf_async.core.state import State
from ubf_async.net.inprocess import InProcessTransport
from ubf_async.runtime.aggregator import StateAggregator
from ubf_async.runtime.bus import Bus
from ubf_async.runtime.component import Component
from ubf_async.runtime.controller import Controller
from ubf_async.runtime.ordering import Refusal
from ubf_async.services.remote import RemoteBehavior, RemoteBehaviorHost, RemoteBehaviors
from ubf_async.wire.protocol import Message, decode
from ubf_async.wire.topics import DRIVE, TRACE, Drive, TickTrace

START_NS = 10**9
RANGE_PERIOD_S = 0.2
"""The device's period: the aggregator calls its samples stale after 1.5 periods (0.3 s)."""


class RangeSpeed(Behavior):
    """Drives at a tenth of the front range while the range is fresh; abstains otherwise."""

    def act(self, state: State) -> Action | None:
        range_mm = state.value("range/front", "range_mm")
        return None if range_mm is None else Action(speed=range_mm / 10, turn=0.0)


class Rig:
    """One in-process network: the robot's bus, a device's bus and a watcher's bus, all on
    one simulated clock (as processes following the simulator's clock would be)."""

    def __init__(self) -> None:
        self.net = InProcessTransport()
        self.clock = SimClock(START_NS)
        # The test is this clock's simulator: however much wall time a busy machine lets pass
        # between two advances, its time source is alive, so the wall-time safety rule
        # (SilenceLimit's silent source) never decides anything here — only the test's time.
        self._driving = contextlib.ExitStack()
        self._driving.enter_context(self.clock.driven())
        self.robot = Bus(transport=self.net, robot="unit", clock=self.clock)
        self.device = Bus(transport=self.net, robot="unit", clock=self.clock)
        self.watcher = Bus(transport=self.net, robot="unit", clock=self.clock)
        self.range = self.device.publisher(self.device.keys.sensor("range", "front"), "range",
                                           period_s=RANGE_PERIOD_S)
        self.drives: list[dict[str, Any]] = []
        self.watcher.subscribe(self.watcher.keys.cmd("drive"), self._on_drive, latest=False)
        self.components: list[Component] = []

    def _on_drive(self, key: str, payload: bytes, received_ns: int) -> None:
        self.drives.append(as_dict(decode(payload, schema="drive").data))

    async def start(self, *components: Component) -> None:
        for component in components:
            await component.start()
            self.components.append(component)
        await self.net.settle()

    async def advance_s(self, seconds: float) -> None:
        self.clock.advance_to(self.clock.now_ns() + round(seconds * 1e9))
        await self.net.settle()

    async def publish_range(self, range_mm: int) -> None:
        self.range.publish({"range_mm": range_mm, "status": "ok"})
        await self.net.settle()

    async def close(self) -> None:
        for component in reversed(self.components):
            await component.aclose()
        for bus in (self.watcher, self.device, self.robot):
            await bus.aclose()
        self._driving.close()


@pytest_asyncio.fixture
async def rig() -> AsyncIterator[Rig]:
    rig = Rig()
    yield rig
    await rig.close()


# ---------------------------------------------------------------------------------------------
# The aggregator


@pytest.mark.asyncio
async def test_aggregator_keeps_the_newest_sample_and_ages_it_on_the_robot_clock(
    rig: Rig,
) -> None:
    agg = StateAggregator(bus=rig.robot)
    await rig.start(agg)
    assert len(agg.snapshot()) == 0
    await rig.publish_range(420)
    await rig.publish_range(380)
    reading = agg.snapshot()["range/front"]
    assert (reading.value["range_mm"], reading.seq, reading.age_s, reading.stale) == (
        380, 2, 0.0, False)
    await rig.advance_s(0.25)  # within 1.5 periods
    reading = agg.snapshot()["range/front"]
    assert reading.age_s == pytest.approx(0.25) and not reading.stale
    await rig.advance_s(0.1)  # 0.35 s quiet: past 0.3 s
    state = agg.snapshot()
    assert state["range/front"].stale and state.fresh("range/front") is None
    await rig.publish_range(300)  # a new sample is fresh again
    assert agg.snapshot().value("range/front", "range_mm") == 300


@pytest.mark.asyncio
async def test_aggregator_refuses_future_stamps_and_counts_malformed_samples(rig: Rig) -> None:
    agg = StateAggregator(bus=rig.robot, future_tolerance_s=0.5)
    await rig.start(agg)
    rig.range.publish({"range_mm": 100, "status": "ok"}, stamp_ns=START_NS + 2 * 10**9)
    raw = rig.device._connection.declare_publisher(rig.device.keys.sensor("range", "left"))
    raw.put(b"\xc1 not msgpack")
    await rig.net.settle()  # (one key: without it, latest mode would coalesce the two)
    raw.put(msgpack.packb({"schema": "range", "v": 1, "stamp_ns": START_NS, "seq": 1,
                           "data": {"range_mm": -5, "status": "ok"}}))  # out of range
    await rig.net.settle()
    assert agg.refused[Refusal.FUTURE] == 1
    assert agg.malformed == {"ubf/unit/sensor/range/left": 2}
    assert "range/front" not in agg.snapshot() and "range/left" not in agg.snapshot()
    await rig.publish_range(200)  # it keeps going
    assert agg.snapshot().value("range/front", "range_mm") == 200


@pytest.mark.asyncio
async def test_garbage_on_a_sensors_key_never_displaces_its_newest_valid_sample(
    rig: Rig,
) -> None:
    agg = StateAggregator(bus=rig.robot)
    await rig.start(agg)
    key = rig.device.keys.sensor("range", "front")
    junk = rig.device.raw_publisher(key)
    for mm in (300, 400):  # no drain in between: only the valid samples coalesce
        rig.range.publish({"range_mm": mm, "status": "ok"})
        for _ in range(1000):
            junk.put(b"\xc1 not msgpack")
    await rig.net.settle()
    assert agg.entries["range/front"].message.data.range_mm == 400
    assert agg.malformed == {key: 2000}  # every refusal counted, though reported once
    assert agg.subscription is not None
    assert (agg.subscription.stats.refused, agg.subscription.stats.coalesced) == (2000, 1)


@pytest.mark.parametrize("latest", [True, False])
@pytest.mark.asyncio
async def test_a_topics_subscriber_gets_its_valid_samples_decoded_whatever_garbage_follows(
    rig: Rig, latest: bool,
) -> None:
    """The drive key as the motors read it: in latest mode the newest valid command wins; in
    every mode garbage takes no place in the queue (16 here), so no valid command is pushed
    out of it."""
    got: list[Message[Drive]] = []
    malformed: dict[str, int] = {}
    rig.robot.subscribe_topic(DRIVE.key(rig.robot.keys), DRIVE,
                              lambda key, message, received_ns: got.append(message),
                              malformed, latest=latest, max_queue=16)
    drive = rig.device.publisher(DRIVE)
    junk = rig.device.raw_publisher(DRIVE.key(rig.device.keys))
    for speed in (10, 20, 30):
        drive.publish({"speed": speed, "turn": 0})
        for _ in range(100):
            junk.put(msgpack.packb({"schema": "drive", "v": 1, "seq": 1, "stamp_ns": 1,
                                    "data": {"speed": 1e9, "turn": 0}}))  # out of range
    await rig.net.settle()
    assert [m.data.speed for m in got] == ([30] if latest else [10, 20, 30])
    assert malformed == {DRIVE.key(rig.robot.keys): 300}


# ---------------------------------------------------------------------------------------------
# The controller


def tree() -> Composite:
    return Composite(name="root", arbiter=HighestPriority(), children=[RangeSpeed(name="range")])


@pytest.mark.asyncio
async def test_controller_publishes_each_ticks_trace_only_while_someone_listens(
    rig: Rig,
) -> None:
    agg = StateAggregator(bus=rig.robot)
    ctl = Controller(bus=rig.robot, aggregator=agg, root=tree(), rate_hz=10)
    await rig.start(agg, ctl)
    await rig.publish_range(420)
    await rig.advance_s(0.1)
    assert ctl._trace.seq == 0  # nobody listens: no trace is built or sent
    traces: list[TickTrace] = []
    sub = rig.watcher.subscribe(TRACE.key(rig.watcher.keys),
                                lambda k, p, t: traces.append(decode(p, topic=TRACE).data),
                                latest=False)
    await rig.advance_s(0.1)
    tick = traces[-1]
    assert tick.tick == rig.drives[-1]["tick"]  # the trace of the command just sent
    root, *children = tick.nodes
    assert (root.name, root.depth, root.arbiter, root.speed) == ("root", 0, "HighestPriority",
                                                                 42.0)
    assert [(c.name, c.depth, c.won, c.speed) for c in children] == [("range", 1, True, 42.0)]
    sub.close()
    await rig.net.settle()
    sent = ctl._trace.seq
    await rig.advance_s(0.2)
    assert ctl._trace.seq == sent  # nobody listens again


@pytest.mark.asyncio
async def test_periodic_controller_ticks_on_the_sim_clock_and_commands_what_it_decided(
    rig: Rig,
) -> None:
    agg = StateAggregator(bus=rig.robot)
    ctl = Controller(bus=rig.robot, aggregator=agg, root=tree(), rate_hz=10)
    await rig.start(agg, ctl)
    assert [d["tick"] for d in rig.drives] == [1]  # the schedule starts with a tick
    assert rig.drives[0]["speed"] == 0.0  # nothing known yet: the tree abstains, a stop
    await rig.publish_range(420)
    assert len(rig.drives) == 1  # a sample alone does not tick a periodic controller
    await rig.advance_s(0.05)
    assert len(rig.drives) == 1  # half a period
    await rig.advance_s(0.05)
    assert [d["tick"] for d in rig.drives] == [1, 2]
    command = rig.drives[-1]
    assert command["speed"] == 42.0 and command["winners"] == ["range"]
    assert command["based_on"]["source"] == "range/front" and command["based_on"]["seq"] == 1
    for _ in range(3):
        await rig.advance_s(0.1)
    assert [d["tick"] for d in rig.drives] == [1, 2, 3, 4, 5]
    assert rig.drives[-1]["speed"] == 0.0  # the range went stale: the tree abstains
    assert ctl.stats.periodic == 5 and ctl.stats.triggered == 0


@pytest.mark.asyncio
async def test_a_late_wakeup_skips_missed_ticks_and_counts_an_overrun(rig: Rig) -> None:
    agg = StateAggregator(bus=rig.robot)
    ctl = Controller(bus=rig.robot, aggregator=agg, root=tree(), rate_hz=10)
    await rig.start(agg, ctl)
    await rig.advance_s(0.35)  # three deadlines passed at once
    assert [d["tick"] for d in rig.drives] == [1, 2]
    assert ctl.stats.overruns == 1
    await rig.advance_s(0.05)  # the phase is kept: the next slot is at 0.4 s
    assert [d["tick"] for d in rig.drives] == [1, 2, 3]


@pytest.mark.asyncio
async def test_event_controller_ticks_per_trigger_sample_and_holds_between(rig: Rig) -> None:
    agg = StateAggregator(bus=rig.robot)
    ctl = Controller(bus=rig.robot, aggregator=agg, root=tree(), rate_hz=10, mode="event",
                     trigger="range/front")
    await rig.start(agg, ctl)
    assert rig.drives == []
    for range_mm in (100, 200, 300):
        await rig.publish_range(range_mm)
    assert [(d["speed"], d["based_on"]["seq"]) for d in rig.drives] == [
        (10.0, 1), (20.0, 2), (30.0, 3)]
    assert not any(d.get("hold") for d in rig.drives)
    await rig.advance_s(0.1)  # a period without a trigger: the last decision is held
    hold = rig.drives[-1]
    assert hold["hold"] is True and hold["speed"] == 30.0 and hold["tick"] == 3
    await rig.advance_s(0.3)  # the trigger went stale: a hold is now a stop
    assert rig.drives[-1]["hold"] is True and rig.drives[-1]["speed"] == 0.0


@pytest.mark.asyncio
@pytest.mark.parametrize("mode", ["event", "periodic"])
async def test_a_tick_that_fails_outside_the_tree_is_contained_and_never_held(
        rig: Rig, monkeypatch: pytest.MonkeyPatch, mode: str) -> None:
    """A tick whose snapshot raises once (a fault outside the behaviour tree, which the tree's
    own guard does not see): it is counted and commands a stop, what a hold then repeats is
    that stop, not the decision before the fault, and the next sample — or the next period —
    ticks as before (issue 53, item 1: the tick a sample runs was an observer the aggregator
    dropped when it raised, after which holds repeated the old decision while the trigger
    stayed fresh)."""
    agg = StateAggregator(bus=rig.robot)
    ctl = (Controller(bus=rig.robot, aggregator=agg, root=tree(), rate_hz=10, mode="event",
                      trigger="range/front") if mode == "event"
           else Controller(bus=rig.robot, aggregator=agg, root=tree(), rate_hz=10))
    await rig.start(agg, ctl)
    await rig.publish_range(300)
    if mode == "periodic":
        await rig.advance_s(0.1)
    assert rig.drives[-1]["speed"] == 30.0
    real_snapshot = agg.snapshot
    faults = iter([RuntimeError("a bookkeeping step raised")])

    def snapshot_failing_once(**kwargs: Any) -> Any:
        fault = next(faults, None)
        if fault is not None:
            raise fault
        return real_snapshot(**kwargs)

    monkeypatch.setattr(agg, "snapshot", snapshot_failing_once)
    if mode == "event":
        await rig.publish_range(400)  # its tick fails
    else:
        await rig.advance_s(0.1)
    assert ctl.stats.tick_faults == 1 and ctl.stats.errors == 0
    assert (rig.drives[-1]["speed"], rig.drives[-1]["turn"]) == (0.0, 0.0)
    await rig.advance_s(0.1)  # a hold (event) or a tick on stale-free data (periodic)
    if mode == "event":
        assert rig.drives[-1]["hold"] is True and rig.drives[-1]["speed"] == 0.0
        await rig.publish_range(500)  # the controller still ticks on samples
        assert (rig.drives[-1]["speed"], rig.drives[-1]["based_on"]["seq"]) == (50.0, 3)
    else:
        await rig.publish_range(500)
        await rig.advance_s(0.1)
        assert rig.drives[-1]["speed"] == 50.0
    assert ctl.stats.tick_faults == 1
    assert ctl.status()["tick_faults"] == 1


@pytest.mark.asyncio
async def test_reflex_samples_tick_at_once_within_their_token_bucket(rig: Rig) -> None:
    agg = StateAggregator(bus=rig.robot)
    ctl = Controller(bus=rig.robot, aggregator=agg, root=tree(), rate_hz=10,
                     reflex_sources=("range/",), reflex_burst=2)
    await rig.start(agg, ctl)
    assert len(rig.drives) == 1
    await rig.publish_range(500)  # no clock advance: the reflex ticks on the sample
    await rig.publish_range(600)
    await rig.publish_range(700)  # the bucket (burst 2) is empty at this instant
    assert [d["speed"] for d in rig.drives] == [0.0, 50.0, 60.0]
    assert (ctl.stats.triggered, ctl.stats.reflex_limited) == (2, 1)
    assert rig.drives[-1]["based_on"]["seq"] == 2


# ---------------------------------------------------------------------------------------------
# Remote votes


@pytest.mark.asyncio
async def test_a_remote_vote_from_another_bus_attaches_drives_and_detaches_with_its_token(
    rig: Rig,
) -> None:
    root = tree()
    agg = StateAggregator(bus=rig.robot)
    remotes = RemoteBehaviors(bus=rig.robot, root=root)
    ctl = Controller(bus=rig.robot, aggregator=agg, root=root, rate_hz=10)
    await rig.start(agg, remotes, ctl)
    host_bus = Bus(transport=rig.net, robot="unit", clock=rig.clock)
    host = RemoteBehaviorHost(bus=host_bus, behavior=ConstantDrive(name="cruise", speed=30.0),
                              composite="root", rate_hz=10, ttl_s=1.0)
    await host.start()
    await rig.net.settle()
    assert host.votes == 1
    attached = root.find("cruise")
    assert isinstance(attached, RemoteBehavior) and attached.alive
    assert remotes.alive >= {"cruise"}
    await rig.advance_s(0.1)
    command = rig.drives[-1]
    assert command["speed"] == 30.0 and command["winners"] == ["cruise"]
    # A local child that votes outranks the stranger (its priority is capped below it).
    await rig.publish_range(800)
    await rig.advance_s(0.1)
    assert rig.drives[-1]["speed"] == 80.0 and rig.drives[-1]["winners"] == ["range"]
    # The host goes away: its token with it, and the robot detaches the child.
    await host.aclose()
    await host_bus.aclose()
    await rig.net.settle()
    assert root.find("cruise") is None
    assert "cruise" not in remotes.alive
    await rig.advance_s(0.5)  # the range is stale and nobody else votes: a stop
    assert rig.drives[-1]["speed"] == 0.0 and rig.drives[-1].get("winners", []) == []


@pytest.mark.asyncio
async def test_a_vote_without_a_live_token_waits_and_an_expired_vote_abstains(
    rig: Rig,
) -> None:
    root = tree()
    remotes = RemoteBehaviors(bus=rig.robot, root=root)
    await rig.start(remotes)
    voter = rig.device.publisher(f"{rig.device.keys.prefix}/vote/root/ghost", "vote")
    voter.publish({"vote": 1.0, "speed": 20.0, "ttl_s": 0.2})
    await rig.net.settle()
    assert root.find("ghost") is None  # no token: not attached
    token = rig.device.declare_token(rig.device.keys.alive("ghost"))
    await rig.net.settle()
    ghost = root.find("ghost")
    assert isinstance(ghost, RemoteBehavior)
    state = State(now_ns=rig.clock.now_ns())
    assert ghost.act(state) == Action(speed=20.0, vote=1.0)
    await rig.advance_s(0.3)  # older than its ttl on the robot clock
    assert ghost.act(State(now_ns=rig.clock.now_ns())) is None
    token.undeclare()
    await rig.net.settle()
    assert root.find("ghost") is None
