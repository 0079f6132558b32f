"""Remote behaviours: votes from other processes join the robot's behaviour tree.

In-process tests drive :class:`RemoteBehaviors` directly (deterministic, on a SimClock) and
over real zenoh sessions; the subprocess tests run the robot, the examples and the observer
in separate OS processes on loopback.
"""

from __future__ import annotations

import argparse
import asyncio
import importlib.util
import math
import os
import re
import signal
import subprocess
import sys
import time
from types import ModuleType, SimpleNamespace
from typing import Any

import msgpack
import pytest

from tests.conftest import eventually
from tests.remote_robot import ROOT, Process, start_robot
from ubf_async import Action, Composite, Conditional, FunctionBehavior, PriorityMerge, State
from ubf_async.behaviors.pink_ball import seek_pink_ball
from ubf_async.clocks.clock import SimClock, WallClock
from ubf_async.errors import ProtocolError
from ubf_async.net.options import ConnectionOptions
from ubf_async.runtime.aggregator import StateAggregator
from ubf_async.runtime.bus import Bus
from ubf_async.runtime.controller import Controller
from ubf_async.services.remote import (
    DEFAULT_TTL_S,
    ReceivedVote,
    RemoteBehavior,
    RemoteBehaviorHost,
    RemoteBehaviors,
    parse_remote_spec,
    remote_spec,
    vote_data,
    vote_key,
)
from ubf_async.tools.remote_host import choose_clock
from ubf_async.wire.keys import Keys
from ubf_async.wire.protocol import decode, encode

EXAMPLES = ROOT / "examples"
PINK = {"bins": [0, 0, 60, 0, 0], "total": 60}  # chase: speed +40, turn 0
CHASE = (40.0, 0.0, ["chase"])
T0 = 10_000_000_000


def load_example(name: str) -> ModuleType:
    spec = importlib.util.spec_from_file_location(f"example_{name}", EXAMPLES / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


# ---------------------------------------------------------------------------------------------
# The vote schema


def test_vote_round_trip_keeps_every_action_field() -> None:
    action = Action(speed=-30, turn=50, vote=2.5, seek_color=((90, 20, 40), (255, 120, 160)),
                    message="hi", leds=5)
    data = vote_data(action, ttl_s=0.3, priority=10, weight=0.5)
    payload = encode("vote", data, stamp_ns=123, seq=7)
    vote = ReceivedVote.decode(Keys("r"), "ubf/r/vote/seek_pink_ball/teleop", payload)
    assert (vote.composite, vote.behavior, vote.stamp_ns, vote.seq) == (
        "seek_pink_ball", "teleop", 123, 7)
    assert vote.action == action
    assert (vote.ttl_s, vote.priority, vote.weight) == (0.3, 10, 0.5)
    abstain = ReceivedVote.decode(Keys("r"), "ubf/r/vote/c/b", encode("vote", vote_data(None),
                                                                 stamp_ns=1, seq=1))
    assert abstain.action == Action(vote=0) and abstain.action.abstains
    assert (abstain.ttl_s, abstain.priority, abstain.weight) == (None, None, None)


def test_vote_key_validates_names() -> None:
    assert vote_key(Keys("r"), "seek_pink_ball", "teleop") == "ubf/r/vote/seek_pink_ball/teleop"
    for composite, name in (("a/b", "x"), ("c", "*"), ("", "x")):
        with pytest.raises(ProtocolError):
            vote_key(Keys("r"), composite, name)


def test_remote_spec_parsing() -> None:
    assert parse_remote_spec("teleop=10") == ("teleop", (10, 1.0))
    assert parse_remote_spec("seek_pink_ball/avoid=3:0.5") == ("seek_pink_ball/avoid", (3, 0.5))
    assert parse_remote_spec("x=-2") == ("x", (-2, 1.0))
    for bad in ("teleop", "=3", "teleop=", "teleop=high", "a/b/c=1", "t=1:-1", "t=1:nan",
                "t*=1"):
        with pytest.raises(ValueError):
            parse_remote_spec(bad)
        with pytest.raises(argparse.ArgumentTypeError):
            remote_spec(bad)


# ---------------------------------------------------------------------------------------------
# RemoteBehaviors, driven directly (no bus traffic) on a simulated clock


class Robot:
    """A seek_pink_ball tree with RemoteBehaviors fed by hand; the clock is simulated."""

    def __init__(self, **options: Any) -> None:
        self.keys = Keys("r")
        self.clock = SimClock(start_ns=T0)
        bus = SimpleNamespace(keys=self.keys, clock=self.clock)
        self.root = options.pop("root", None) or seek_pink_ball()
        # These tests are about attaching, TTLs and tokens, with an unconfigured teleop asking
        # for priority 10; the stranger cap has its own tests (test_remote_rules.py).
        options.setdefault("max_stranger_priority", 100)
        self.remotes = RemoteBehaviors(bus=bus, root=self.root, **options)  # type: ignore[arg-type]
        self.seq = 0

    def token(self, name: str, alive: bool = True) -> None:
        self.remotes.on_liveliness(self.keys.alive(name), alive)

    def vote(self, name: str = "teleop", composite: str = "seek_pink_ball", *,
             stamp_ns: int | None = None, seq: int | None = None, **data: Any) -> str:
        data.setdefault("vote", 1.0)
        self.seq += 1
        key = vote_key(self.keys, composite, name)
        stamp = self.clock.now_ns() if stamp_ns is None else stamp_ns
        self.remotes.on_vote(key, encode("vote", data, stamp_ns=stamp,
                                         seq=self.seq if seq is None else seq))
        return key

    def at(self, seconds: float) -> State:
        """Move the clock to T0 + seconds; the state the controller would snapshot then."""
        self.clock.advance_to(T0 + int(seconds * 1e9))
        return State.of(now_ns=self.clock.now_ns(), camera__front=PINK)

    def drive(self, seconds: float) -> tuple[float | None, float | None, list[str]]:
        trace = self.root.evaluate(self.at(seconds))
        action = trace.action
        assert action is not None
        return action.speed, action.turn, trace.winning_leaves()

    def child(self, name: str) -> Any:
        return next((c for c in self.root.children if c.behavior.name == name), None)


def test_first_vote_with_live_token_attaches_and_outranks_seek_pink_ball() -> None:
    robot = Robot()
    assert robot.drive(0) == CHASE
    robot.token("teleop")
    robot.vote(speed=-30, turn=50, priority=10)
    child = robot.child("teleop")
    assert child is not None and isinstance(child.behavior, RemoteBehavior)
    assert (child.priority, child.weight) == (10, 1.0)
    assert robot.remotes.attached() == ["seek_pink_ball/teleop"]
    assert robot.drive(0.01) == (-30.0, 50.0, ["teleop"])
    assert "teleop [p=10 w=1]: speed=-30 turn=+50" in robot.root.evaluate(robot.at(0.02)).render()


def test_vote_before_token_waits_for_it() -> None:
    robot = Robot()
    robot.vote(speed=-30, turn=50, priority=10)
    assert robot.child("teleop") is None  # no token yet: not attached
    assert robot.drive(0.01) == CHASE
    robot.token("teleop")
    assert robot.child("teleop") is not None
    assert robot.drive(0.02) == (-30.0, 50.0, ["teleop"])


def test_vote_expires_after_its_ttl_on_the_robot_clock() -> None:
    robot = Robot()
    robot.token("teleop")
    robot.vote(speed=-30, turn=50, priority=10, ttl_s=0.3)
    assert robot.drive(0.299) == (-30.0, 50.0, ["teleop"])
    assert robot.drive(0.300) == (-30.0, 50.0, ["teleop"])  # age == TTL still holds
    assert robot.drive(0.301) == CHASE  # expired: seek-the-pink-ball is back
    assert robot.child("teleop") is not None  # still attached, just abstaining
    robot.vote(speed=-10, turn=0, priority=10, ttl_s=0.3)  # stamped now (0.301)
    assert robot.drive(0.5) == (-10.0, 0.0, ["teleop"])
    assert robot.drive(0.602) == CHASE


def test_default_ttl_and_the_robots_cap() -> None:
    robot = Robot(default_ttl_s=0.2, max_ttl_s=1.0)
    robot.token("teleop")
    robot.vote(speed=-30, priority=10)  # no ttl_s: the robot's default
    remote = robot.remotes.get("seek_pink_ball", "teleop")
    assert remote is not None and remote.ttl_s == pytest.approx(0.2)
    assert robot.drive(0.2)[2] == ["teleop"]
    assert robot.drive(0.21) == CHASE
    robot.vote(speed=-30, priority=10, ttl_s=30.0)  # asks for more than the cap
    assert remote.ttl_s == pytest.approx(1.0)
    assert robot.drive(1.21) == (-30.0, None, ["teleop"])
    assert robot.drive(1.22) == CHASE
    assert RemoteBehaviors(bus=SimpleNamespace(keys=Keys("r"), clock=SimClock()),  # type: ignore[arg-type]
                           root=seek_pink_ball()).default_ttl_s == DEFAULT_TTL_S


def test_vote_from_the_future_is_refused_and_counted() -> None:
    robot = Robot()
    robot.token("teleop")
    # e.g. a remote stamping with its host's wall clock while the robot runs on sim time
    key = robot.vote(speed=-30, priority=10, ttl_s=0.5, stamp_ns=T0 + 2_000_000_000)
    assert robot.remotes.future == {key: 1} and robot.child("teleop") is None
    assert robot.drive(0) == CHASE
    assert robot.drive(1.5) == CHASE  # never held, not even once the clock gets there
    assert robot.remotes.status()["future"] == 1


def test_out_of_order_vote_is_ignored_and_vote_zero_abstains() -> None:
    robot = Robot()
    robot.token("teleop")
    robot.at(1.0)
    robot.vote(speed=-30, priority=10, seq=5)
    robot.vote(speed=99, priority=10, seq=4)  # out of order (same publisher, older seq)
    assert robot.drive(1.01) == (-30.0, None, ["teleop"])
    # A restarted plain publisher (its seq starts again) is taken once its stamp is newer.
    robot.vote(speed=-20, priority=10, seq=1, stamp_ns=T0 + 1_005_000_000)
    assert robot.drive(1.01) == (-20.0, None, ["teleop"])
    robot.vote(vote=0.0, speed=-30, priority=10, seq=2)  # abstain, explicitly
    assert robot.drive(1.02) == CHASE
    assert robot.child("teleop") is not None


def test_token_loss_detaches_and_a_comeback_reattaches() -> None:
    robot = Robot()
    robot.token("teleop")
    robot.vote(speed=-30, turn=50, priority=10, ttl_s=5.0)
    assert robot.drive(0.01)[2] == ["teleop"]
    robot.remotes.changed.clear()
    robot.token("teleop", alive=False)
    assert robot.remotes.changed.is_set()
    assert robot.child("teleop") is None  # detached at once, long before the TTL
    assert robot.drive(0.02) == CHASE
    assert robot.remotes.attached() == []
    robot.token("teleop")  # token back, but its old vote was forgotten
    assert robot.child("teleop") is None
    robot.vote(speed=-20, turn=10, priority=10)
    assert robot.drive(0.03) == (-20.0, 10.0, ["teleop"])
    # Other components' tokens coming and going change nothing.
    robot.token("camera-front", alive=False)
    assert robot.child("teleop") is not None


def test_unknown_composite_leaf_and_name_clash_are_rejected() -> None:
    robot = Robot()
    for name in ("teleop", "search"):
        robot.token(name)
    nope = robot.vote(composite="nope", speed=-30, priority=10)
    leaf = robot.vote(composite="chase", speed=-30, priority=10)
    clash = robot.vote("search", speed=-30, priority=10)  # a local child's name
    for _ in range(3):
        robot.vote(composite="nope", speed=-30, priority=10)
    assert robot.remotes.rejected == {nope: 4, leaf: 1, clash: 1}
    assert [c.behavior.name for c in robot.root.children] == ["search", "chase", "flee"]
    assert robot.drive(0) == CHASE


def test_nested_composite_found_by_name() -> None:
    inner = Composite(name="reflexes", arbiter=PriorityMerge())
    root = Composite(name="root", arbiter=PriorityMerge(),
                     children=[seek_pink_ball(), inner])
    robot = Robot(root=root)
    robot.token("avoid")
    robot.vote("avoid", composite="reflexes", speed=-30, turn=60, priority=3)
    assert [c.behavior.name for c in inner.children] == ["avoid"]
    assert root.evaluate(robot.at(0.01)).winning_leaves() == ["chase", "avoid"]  # same prio


def test_set_root_moves_remote_children_to_the_composite_of_the_same_name() -> None:
    robot = Robot()
    robot.token("teleop")
    robot.vote(speed=-30, turn=50, priority=10)
    same = seek_pink_ball()
    assert robot.remotes.set_root(same, config={"seek_pink_ball/teleop": (7, 2.0)}) == []
    moved = next(c for c in same.children if c.behavior.name == "teleop")
    assert (moved.priority, moved.weight) == (7, 2.0)
    assert all(c.behavior.name != "teleop" for c in robot.root.children)  # left the old tree
    elsewhere = Composite(name="other", arbiter=PriorityMerge())
    assert robot.remotes.set_root(elsewhere) == ["seek_pink_ball/teleop"]
    assert robot.remotes.attached() == [] and not same.find("teleop")


def test_vote_into_a_composite_whose_arbiter_refuses_a_third_child_is_rejected() -> None:
    gate = Composite(name="gate", arbiter=Conditional(lambda state: True),
                     children=[FunctionBehavior(lambda s: None, name="a"),
                               FunctionBehavior(lambda s: None, name="b")])
    root = Composite(name="root", arbiter=PriorityMerge(), children=[seek_pink_ball(), gate])
    robot = Robot(root=root)
    robot.token("intruder")
    key = robot.vote("intruder", composite="gate", speed=-30, priority=3)
    assert robot.remotes.rejected == {key: 1}
    assert [c.behavior.name for c in gate.children] == ["a", "b"]
    assert robot.drive(0) == CHASE  # the tree keeps working


@pytest.mark.parametrize("case", [
    "speed 150", "nan turn", "negative vote", "no vote", "inf vote", "seek lo > hi",
    "seek too short", "leds 300", "float priority", "bool priority", "negative weight",
    "ttl 0", "long message", "wrong schema", "garbage", "key too short", "key too long",
])
def test_malformed_votes_are_counted_and_change_nothing(case: str) -> None:
    robot = Robot()
    robot.token("teleop")
    good = {"vote": 1.0, "speed": -30, "priority": 10}
    key = vote_key(robot.keys, "seek_pink_ball", "teleop")
    bad_data = {
        "speed 150": {**good, "speed": 150}, "nan turn": {**good, "turn": math.nan},
        "negative vote": {**good, "vote": -1}, "no vote": {"speed": -30},
        "inf vote": {**good, "vote": math.inf},
        "seek lo > hi": {**good, "seek_color": {"lo": [200, 0, 0], "hi": [100, 0, 0]}},
        "seek too short": {**good, "seek_color": {"lo": [0, 0], "hi": [1, 1, 1]}},
        "leds 300": {**good, "leds": 300}, "float priority": {**good, "priority": 1.5},
        "bool priority": {**good, "priority": True}, "negative weight": {**good, "weight": -1},
        "ttl 0": {**good, "ttl_s": 0}, "long message": {**good, "message": "x" * 300},
    }
    if case in bad_data:
        payload = msgpack.packb({"schema": "vote", "v": 1, "stamp_ns": T0, "seq": 1,
                                 "data": bad_data[case]})
    elif case == "wrong schema":
        payload = encode("range", {"range_mm": 1, "status": "ok"}, stamp_ns=T0, seq=1)
    elif case == "garbage":
        payload = b"\xc1\xff\x00garbage"
    else:
        payload = encode("vote", good, stamp_ns=T0, seq=1)
        key = "ubf/r/vote/teleop" if case == "key too short" else key + "/extra"
    robot.remotes.on_vote(key, payload)
    assert robot.remotes.malformed == {key: 1}
    assert robot.child("teleop") is None
    assert robot.drive(0) == CHASE
    robot.vote(speed=-30, priority=10)  # a good vote afterwards still works
    assert robot.drive(0.01)[2] == ["teleop"]


def test_configured_priority_overrides_the_requested_one() -> None:
    robot = Robot(config={"teleop": (0, 1.0), "seek_pink_ball/avoid": (3, 2.0)})
    robot.token("teleop")
    robot.vote(speed=-30, turn=50, priority=10, weight=9.0)  # asks for 10, gets 0
    assert (robot.child("teleop").priority, robot.child("teleop").weight) == (0, 1.0)
    assert robot.drive(0.01) == CHASE  # chase (p1) outranks it now
    robot.token("avoid")
    robot.vote("avoid", speed=-30, priority=-5)
    assert (robot.child("avoid").priority, robot.child("avoid").weight) == (3, 2.0)
    assert robot.drive(0.02)[2] == ["avoid"]


def test_changed_request_reattaches_with_the_new_priority() -> None:
    robot = Robot()
    robot.token("teleop")
    robot.vote(speed=-30, priority=0)
    assert robot.drive(0.01) == CHASE
    robot.vote(speed=-30, priority=10)
    assert robot.child("teleop").priority == 10
    assert robot.drive(0.02)[2] == ["teleop"]
    assert [c.behavior.name for c in robot.root.children].count("teleop") == 1


def test_votes_without_a_token_are_forgotten_after_max_ttl() -> None:
    robot = Robot(max_ttl_s=1.0)
    robot.vote("ghost", speed=1)  # a publisher that never declares its token
    assert robot.remotes.get("seek_pink_ball", "ghost") is not None
    robot.at(0.9)
    robot.remotes.prune()
    assert robot.remotes.get("seek_pink_ball", "ghost") is not None
    robot.at(1.1)
    robot.remotes.prune()
    assert robot.remotes.get("seek_pink_ball", "ghost") is None
    assert robot.remotes.status() == {"remotes": [], "malformed": 0, "rejected": 0,
                                     "future": 0}


def test_only_configured_and_max_remotes() -> None:
    robot = Robot(config={"teleop": (10, 1.0)}, only_configured=True, max_remotes=2)
    for name in ("teleop", "intruder", "second", "third"):
        robot.token(name)
    robot.vote(speed=-30)
    intruder = robot.vote("intruder", speed=99, priority=100)
    assert robot.remotes.attached() == ["seek_pink_ball/teleop"]
    assert robot.remotes.rejected == {intruder: 1}
    robot.remotes.only_configured = False
    robot.vote("second", speed=1)
    third = robot.vote("third", speed=2)
    assert robot.remotes.rejected[third] == 1
    assert robot.remotes.attached() == ["seek_pink_ball/second", "seek_pink_ball/teleop"]


# ---------------------------------------------------------------------------------------------
# Both sides over real zenoh sessions in this process


@pytest.mark.asyncio
async def test_host_runs_a_plain_behaviour_remotely(robot_bus: Bus, peer_bus: Bus) -> None:
    seen: list[State] = []

    def backer(state: State) -> Action | None:
        seen.append(state)
        if state.value("range/front", "range_mm", 9999) < 200:
            return Action(speed=-25, turn=-40, vote=1)
        return None

    root = seek_pink_ball()
    agg = StateAggregator(bus=robot_bus)
    ctl = Controller(bus=robot_bus, aggregator=agg, root=root, rate_hz=50)
    remotes = RemoteBehaviors(bus=robot_bus, root=root, config={"backer": (5, 1.0)})
    host = RemoteBehaviorHost(bus=peer_bus, behavior=FunctionBehavior(backer, name="backer"),
                              composite="seek_pink_ball", rate_hz=50, priority=5, ttl_s=0.3)
    camera = peer_bus.publisher(peer_bus.keys.sensor("camera", "front"), "camera.seekcolor")
    ranger = peer_bus.publisher(peer_bus.keys.sensor("range", "front"), "range")
    try:
        for c in (agg, ctl, remotes):
            await c.start()
        await camera.wait_for_subscribers()
        camera.publish(PINK)
        await eventually(lambda: ctl.last_trace is not None
                         and ctl.last_trace.winning_leaves() == ["chase"])
        await host.start()
        # Abstaining (vote 0) still attaches it, visibly abstaining.
        await eventually(lambda: remotes.attached() == ["seek_pink_ball/backer"],
                         what="remote attached")
        await eventually(lambda: "backer [p=5 w=1]: abstain" in ctl.last_trace.render(),
                         what="the remote in the controller's explanation")
        camera.publish(PINK)  # again: the host's own aggregator subscribed after the first
        await ranger.wait_for_subscribers()
        ranger.publish({"range_mm": 120, "status": "ok"})
        await eventually(lambda: ctl.last_action == Action(speed=-25, turn=-40),
                         what="drive to follow the remote behaviour")
        assert ctl.last_trace.winning_leaves() == ["backer"]
        # It received the state: the sensors and the robot's previous drive command.
        await eventually(lambda: "camera/front" in seen[-1] and "range/front" in seen[-1])
        await eventually(lambda: seen[-1].previous_action == Action(speed=-25, turn=-40))
        await host.aclose()  # token gone: detached
        await eventually(lambda: remotes.attached() == [], what="detach on token loss")
        assert root.find("backer") is None
        await eventually(lambda: ctl.last_action == Action(speed=40, turn=0))
    finally:
        await host.aclose()
        for c in (remotes, ctl, agg):
            await c.aclose()


@pytest.mark.asyncio
async def test_host_survives_a_raising_behaviour(robot_bus: Bus, peer_bus: Bus) -> None:
    calls = [0]

    def flaky(state: State) -> Action:
        calls[0] += 1
        if calls[0] % 2:
            raise RuntimeError("boom")
        return Action(speed=10)

    host = RemoteBehaviorHost(bus=peer_bus, behavior=FunctionBehavior(flaky, name="flaky"),
                              composite="seek_pink_ball", rate_hz=100)
    votes: list[float] = []
    robot_bus.subscribe(vote_key(robot_bus.keys, "seek_pink_ball", "flaky"),
                        lambda k, p, t: votes.append(decode(p, schema="vote").data.vote),
                        latest=False)
    async with host:
        await eventually(lambda: host.errors >= 3 and len(votes) >= 6, what="votes")
        assert host.restarts == 0
    assert set(votes) == {0.0, 1.0}  # raising ticks abstain, the others vote


@pytest.mark.asyncio
async def test_clock_choice_follows_a_simulator(robot_bus: Bus, peer_bus: Bus) -> None:
    assert isinstance(await choose_clock(peer_bus, "auto", wait_s=0.05), WallClock)
    pub = robot_bus.publisher(robot_bus.keys.clock, "clock", period_s=0.01)

    async def tick() -> None:
        for n in range(1, 1000):
            pub.publish({}, stamp_ns=n * 10_000_000)
            await asyncio.sleep(0.01)

    ticker = asyncio.create_task(tick())
    try:
        clock = await choose_clock(peer_bus, "auto", wait_s=5)
        assert isinstance(clock, SimClock) and peer_bus.clock is clock
        assert 0 < clock.now_ns() < 10_000_000_000  # simulation time, not the host's
    finally:
        ticker.cancel()


# ---------------------------------------------------------------------------------------------
# The examples' behaviours


def test_avoid_obstacles_behaviour() -> None:
    avoid = load_example("avoid_obstacles").AvoidObstacles(near_mm=250)
    far = {"range_mm": 600, "status": "ok"}
    assert avoid.act(State.of(range__front=far, camera__front=PINK)) is None
    assert avoid.act(State.of(range__front={"range_mm": None, "status": "too_far"})) is None
    near = avoid.act(State.of(range__front={"range_mm": 125, "status": "ok"}))
    assert (near.speed, near.turn, near.vote) == (-30, 60, 1.5)
    touching = avoid.act(State.of(range__front={"range_mm": None, "status": "too_close"}))
    assert touching.vote == 2.0
    left = avoid.act(State.of(range__left={"range_mm": 100, "status": "ok"},
                              range__right={"range_mm": 200, "status": "ok"}))
    assert left.turn == -60  # nearest on the left: turn right
    only_front = load_example("avoid_obstacles").AvoidObstacles(sources=["range/front"])
    assert only_front.act(State.of(range__left={"range_mm": 10, "status": "ok"})) is None


def test_scripted_teleop_behaviour() -> None:
    teleop = load_example("teleop_override")
    steps = teleop.parse_script("1:40:0, 0.5:0:80")
    once = teleop.ScriptedTeleop(steps=steps, loop=False)
    looped = teleop.ScriptedTeleop(steps=steps)
    for b in (once, looped):
        assert b.act(State(now_ns=T0)) == Action(speed=40, turn=0)
        assert b.act(State(now_ns=T0 + 1_200_000_000)) == Action(speed=0, turn=80)
    assert once.act(State(now_ns=T0 + 1_600_000_000)) is None
    assert looped.act(State(now_ns=T0 + 1_600_000_000)) == Action(speed=40, turn=0)
    for bad in ("1:40", "0:1:1", "1:101:0", "a:b:c"):
        with pytest.raises(argparse.ArgumentTypeError):
            teleop.parse_script(bad)


@pytest.mark.parametrize("example", ["teleop_override", "avoid_obstacles"])
def test_examples_help(example: str) -> None:
    out = subprocess.run([sys.executable, str(EXAMPLES / f"{example}.py"), "--help"],
                         cwd=ROOT, capture_output=True, text=True, check=True).stdout
    for flag in ("--connect", "--listen", "--mode", "--config", "--robot", "--priority",
                 "--composite", "--ttl-s", "--rate-hz"):
        assert flag in out


# ---------------------------------------------------------------------------------------------
# Separate OS processes: robot, remote behaviours, observer (this process)


class DriveLog:
    """Every drive command the robot publishes, as (stamp_ns, speed, turn, winners)."""

    def __init__(self, bus: Bus) -> None:
        self.drives: list[tuple[int, float, float, list[str]]] = []
        bus.subscribe(bus.keys.cmd("drive"), self._on_drive, latest=False)

    def _on_drive(self, key: str, payload: bytes, received_ns: int) -> None:
        m = decode(payload, schema="drive")
        self.drives.append((m.stamp_ns, m.data.speed, m.data.turn, list(m.data.winners)))

    def now(self) -> tuple[float, float, list[str]] | None:
        return self.drives[-1][1:] if self.drives else None

    def first_since(self, since_ns: int, output: tuple[float, float, list[str]]) -> int | None:
        """Stamp of the first drive at/after ``since_ns`` with ``output``."""
        return next((d[0] for d in self.drives if d[0] >= since_ns and d[1:] == output), None)

    def outputs_since(self, since_ns: int) -> set[tuple[float, float, tuple[str, ...]]]:
        return {(d[1], d[2], tuple(d[3])) for d in self.drives if d[0] >= since_ns}


@pytest.mark.asyncio
async def test_remote_override_takes_control_and_gives_it_back_within_its_ttl(
    endpoint: str, robot: str
) -> None:
    ttl_s, tick_s = 0.5, 1 / 50
    teleop_output = (-30.0, 50.0, ["teleop"])
    robot_proc = start_robot(endpoint, robot, "--remote", "teleop=10")
    teleop: Process | None = None
    bus = await Bus.open(ConnectionOptions(robot=robot, connect=[endpoint]))
    try:
        log = DriveLog(bus)
        votes: list[int] = []  # the teleop's vote stamps, on the host's clock like the robot's
        bus.subscribe(vote_key(bus.keys, "seek_pink_ball", "teleop"),
                      lambda k, p, t: votes.append(decode(p, schema="vote").stamp_ns),
                      latest=False)
        await eventually(lambda: log.now() == CHASE, timeout_s=10, what="seek-the-pink-ball")
        teleop = Process(str(EXAMPLES / "teleop_override.py"), "--connect", endpoint,
                         "--robot", robot, "--speed", "-30", "--turn", "50", "--clock", "wall",
                         "--ttl-s", str(ttl_s), "--quiet")
        await eventually(lambda: log.now() == teleop_output, timeout_s=15,
                         what="the override to take control")
        # Its votes reach this session only once the teleop and this session have found each
        # other (zenoh peers link by gossip, and the robot forwards nothing): the last vote
        # before the freeze must be among those seen here.
        await eventually(lambda: bool(votes), timeout_s=15, what="the teleop's votes here too")

        # Frozen (SIGSTOP): its session and token live on, its votes stop — the TTL decides.
        stopped_ns = time.monotonic_ns()
        os.kill(teleop.pid, signal.SIGSTOP)
        await eventually(lambda: log.first_since(stopped_ns, CHASE) is not None,
                         what="control back after the TTL")
        back_ns = log.first_since(stopped_ns, CHASE)
        assert back_ns is not None
        # Timed from the last vote, not from the SIGSTOP: a busy machine may have let the
        # teleop send it well before. The TTL is judged on the robot's clock, so control
        # comes back only once that vote is older than the TTL (exact, on any machine) and at
        # the robot's next tick after that (its period, and a busy machine's lateness).
        last_vote_ns = max(v for v in votes if v <= back_ns)
        back_s = (back_ns - last_vote_ns) / 1e9
        assert ttl_s < back_s <= ttl_s + tick_s + 0.08, back_s
        os.kill(teleop.pid, signal.SIGCONT)
        await eventually(lambda: log.now() == teleop_output, what="override again")

        # Killed: control returns within the TTL (here at once: the token goes with it).
        killed_ns = time.monotonic_ns()
        teleop.kill()
        await eventually(lambda: log.first_since(killed_ns, CHASE) is not None,
                         what="control back after kill -9")
        back_s = (log.first_since(killed_ns, CHASE) - killed_ns) / 1e9
        assert back_s <= ttl_s + tick_s, back_s
        # ... and stays there: the only outputs since were the override's last and chase's.
        settled_ns = time.monotonic_ns()
        await eventually(lambda: len([d for d in log.drives if d[0] > settled_ns]) >= 10)
        assert log.outputs_since(settled_ns) == {(40.0, 0.0, ("chase",))}
        assert log.outputs_since(killed_ns) <= {(40.0, 0.0, ("chase",)),
                                                (-30.0, 50.0, ("teleop",))}
    finally:
        if teleop is not None:
            teleop.kill()  # SIGKILL ends a stopped process too
        await bus.aclose()
        robot_proc.kill()


@pytest.mark.asyncio
async def test_avoid_obstacles_process_backs_away_from_a_near_reading(
    endpoint: str, robot: str
) -> None:
    robot_proc = start_robot(endpoint, robot, "--remote", "avoid_obstacles=3")
    procs: list[Process] = []
    bus = await Bus.open(ConnectionOptions(robot=robot, connect=[endpoint]))
    try:
        log = DriveLog(bus)
        procs.append(Process(str(EXAMPLES / "plain_range_sensor.py"), "--connect", endpoint,
                             "--robot", robot, "--name", "front", "--range-mm", "150"))
        procs.append(Process(str(EXAMPLES / "avoid_obstacles.py"), "--connect", endpoint,
                             "--robot", robot, "--clock", "wall", "--quiet"))
        await eventually(lambda: log.now() is not None and log.now()[2] == ["avoid_obstacles"],
                         timeout_s=15, what="avoid_obstacles to take over")
        assert log.now()[:2] == (-30.0, 60.0)
        procs[1].terminate()  # clean exit: its final vote of 0 and its token both go
        await eventually(lambda: log.now() == CHASE, what="seek-the-pink-ball back")
        assert re.search(r"votes in 'seek_pink_ball' .* \(priority 3", procs[1].output())
    finally:
        for p in procs:
            p.kill()
        await bus.aclose()
        robot_proc.kill()


@pytest.mark.asyncio
async def test_the_documented_plain_python_remote_behaviour_works(
    endpoint: str, robot: str
) -> None:
    """The snippet in docs/protocol.md ("Remote behaviours"), run as written."""
    doc = (ROOT / "docs" / "protocol.md").read_text()
    section = doc[doc.index("## Remote behaviours"):]
    code = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    code = code.replace("tcp/127.0.0.1:7447", endpoint).replace('"mini"', repr(robot))
    robot_proc = start_robot(endpoint, robot, "--remote", "teleop=10")
    script: Process | None = None
    bus = await Bus.open(ConnectionOptions(robot=robot, connect=[endpoint]))
    try:
        log = DriveLog(bus)
        script = Process("-c", code)
        await eventually(lambda: log.now() == (-30.0, 50.0, ["teleop"]), timeout_s=15,
                         what="the documented snippet to take control")
    finally:
        if script is not None:
            script.kill()
        await bus.aclose()
        robot_proc.kill()


def test_robot_helper_rejects_bad_remote_spec() -> None:
    proc = subprocess.run([sys.executable, "-m", "tests.remote_robot", "--remote", "x"],
                          cwd=ROOT, capture_output=True, text=True, timeout=30)
    assert proc.returncode == 2 and "NAME=PRIORITY" in proc.stderr
