"""The robot's rules for remote votes (open and secure mode alike), driven in-process.

Reserved and over-long names, the priority cap for unconfigured remotes (strangers), slots
strangers cannot exhaust, and votes stamped ahead of the robot clock. Every refusal is
counted; the tree keeps running what it ran.
"""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import pytest

from ubf_async import Composite, PriorityMerge, State
from ubf_async.behaviors.pink_ball import seek_pink_ball
from ubf_async.clocks.clock import SimClock
from ubf_async.errors import ConfigurationError
from ubf_async.services.remote import MAX_NAME_LEN, RemoteBehaviors
from ubf_async.wire.keys import Keys
from ubf_async.wire.protocol import encode

T0 = 10_000_000_000
PINK = {"bins": [0, 0, 60, 0, 0], "total": 60}
CHASE = (40.0, 0.0, ["chase"])


class Robot:
    """seek_pink_ball (search p2, chase p1, flee p1) with RemoteBehaviors fed by hand."""

    def __init__(self, **options: Any) -> None:
        self.keys = Keys("r")
        self.clock = SimClock(start_ns=T0)
        self.root = options.pop("root", None) or seek_pink_ball()
        bus = SimpleNamespace(keys=self.keys, clock=self.clock)
        self.remotes = RemoteBehaviors(bus=bus, root=self.root, **options)  # type: ignore[arg-type]
        self.seq = 0

    def token(self, name: str) -> None:
        self.remotes.on_liveliness(self.keys.alive(name), True)

    def vote(self, name: str = "teleop", composite: str = "seek_pink_ball", *,
             stamp_ns: int | None = None, **data: Any) -> str:
        data.setdefault("vote", 1.0)
        self.seq += 1
        key = f"{self.keys.prefix}/vote/{composite}/{name}"
        stamp = self.clock.now_ns() if stamp_ns is None else stamp_ns
        self.remotes.on_vote(key, encode("vote", data, stamp_ns=stamp, seq=self.seq))
        return key

    def drive(self, seconds: float) -> tuple[float | None, float | None, list[str]]:
        self.clock.advance_to(T0 + int(seconds * 1e9))
        trace = self.root.evaluate(State.of(now_ns=self.clock.now_ns(), camera__front=PINK))
        assert trace.action is not None
        return trace.action.speed, trace.action.turn, trace.winning_leaves()

    def priority_of(self, name: str) -> int | None:
        child = next((c for c in self.root.children if c.behavior.name == name), None)
        return None if child is None else child.priority


# -- names ------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["controller", "aggregator", "remotes", "tree",
                                  "motors-main", "search", "seek_pink_ball"])
def test_reserved_and_tree_names_cannot_be_taken(name: str) -> None:
    robot = Robot(reserved_names=["motors-main"])
    robot.token(name)
    key = robot.vote(name, speed=-30, priority=50)
    assert robot.remotes.rejected == {key: 1}
    assert robot.remotes.attached() == []
    assert robot.drive(0.01) == CHASE


def test_reserve_adds_names_later_and_a_configured_reserved_name_is_an_error() -> None:
    robot = Robot()
    robot.remotes.reserve(["camera-front"])
    robot.token("camera-front")
    key = robot.vote("camera-front", speed=1)
    assert robot.remotes.rejected == {key: 1}
    with pytest.raises(ConfigurationError, match="reserved"):
        Robot(config={"controller": (5, 1.0)})
    configured = Robot(config={"seek_pink_ball/teleop": (5, 1.0)})
    with pytest.raises(ConfigurationError, match="'teleop' is reserved"):
        configured.remotes.reserve(["teleop"])


def test_a_name_longer_than_the_drive_commands_winners_allow_is_refused() -> None:
    robot = Robot(max_stranger_priority=100)
    long_name, ok_name = "x" * (MAX_NAME_LEN + 1), "y" * MAX_NAME_LEN
    for name in (long_name, ok_name):
        robot.token(name)
    key = robot.vote(long_name, speed=-30, priority=10)
    robot.vote(ok_name, speed=-20, priority=10)
    assert robot.remotes.rejected == {key: 1}
    assert robot.remotes.attached() == [f"seek_pink_ball/{ok_name}"]
    assert robot.drive(0.01) == (-20.0, None, [ok_name])


# -- the priority cap -------------------------------------------------------------------------


def test_a_stranger_gets_at_most_one_below_the_composites_own_children() -> None:
    robot = Robot()
    robot.token("intruder")
    robot.vote("intruder", speed=-99, turn=99, priority=1_000_000, weight=1e6)
    assert robot.priority_of("intruder") == 0  # locals are 2, 1, 1
    assert robot.drive(0.01) == CHASE  # it never outranks nor merges with the tree
    robot.vote("intruder", speed=-99, priority=-7)  # asking for less is granted
    assert robot.priority_of("intruder") == -7


def test_the_stranger_cap_follows_the_tree_and_can_be_fixed() -> None:
    low = Composite(name="low", arbiter=PriorityMerge())
    root = Composite(name="root", arbiter=PriorityMerge(), children=[seek_pink_ball(), low])
    robot = Robot(root=root)
    robot.token("a")
    robot.vote("a", composite="low", speed=1, priority=10)
    assert [(c.behavior.name, c.priority) for c in low.children] == [("a", 0)]  # no locals
    fixed = Robot(max_stranger_priority=3)
    fixed.token("a")
    fixed.vote("a", speed=-30, priority=10)
    assert fixed.priority_of("a") == 3
    assert fixed.drive(0.01) == (-30.0, None, ["a"])  # the robot chose to let it outrank


def test_a_configured_remote_gets_exactly_its_configured_place() -> None:
    robot = Robot(config={"seek_pink_ball/teleop": (10, 2.0)})
    robot.token("teleop")
    robot.vote(speed=-30, turn=50, priority=1_000_000)
    assert robot.priority_of("teleop") == 10
    assert robot.drive(0.01) == (-30.0, 50.0, ["teleop"])


# -- slots ------------------------------------------------------------------------------------


def test_strangers_cannot_exhaust_the_slots_of_configured_remotes() -> None:
    robot = Robot(config={"teleop": (10, 1.0), "seek_pink_ball/avoid": (3, 1.0)},
                  max_remotes=5)
    assert robot.remotes.stranger_slots == 3
    flood = [robot.vote(f"s{n}", speed=1) for n in range(20)]  # no token needed to squat
    assert sum(robot.remotes.rejected.values()) == 17
    assert all(robot.remotes.rejected.get(k) == 1 for k in flood[3:])
    for name in ("teleop", "avoid"):
        robot.token(name)
    robot.vote("teleop", speed=-30, turn=50)
    robot.vote("avoid", speed=-10)
    assert {"seek_pink_ball/teleop", "seek_pink_ball/avoid"} <= set(robot.remotes.attached())
    assert robot.drive(0.01) == (-30.0, 50.0, ["teleop"])


def test_a_stranger_slot_frees_when_its_token_goes() -> None:
    robot = Robot(config={"teleop": (10, 1.0)}, max_remotes=2)
    robot.token("a")
    robot.vote("a", speed=1)
    robot.token("b")
    refused = robot.vote("b", speed=1)
    assert robot.remotes.rejected == {refused: 1}
    robot.remotes.on_liveliness(robot.keys.alive("a"), False)
    robot.vote("b", speed=1)
    assert robot.remotes.attached() == ["seek_pink_ball/b"]


# -- stamps from the future -------------------------------------------------------------------


def test_votes_ahead_of_the_robot_clock_beyond_the_tolerance_are_refused() -> None:
    robot = Robot(config={"teleop": (10, 1.0)}, max_future_s=0.1)
    robot.token("teleop")
    far = robot.vote(speed=99, stamp_ns=2**63 - 1)
    assert robot.remotes.future == {far: 1} and robot.remotes.attached() == []
    robot.vote(speed=-30, stamp_ns=T0 + 100_000_000)  # exactly at the tolerance: taken
    assert robot.drive(0.2) == (-30.0, None, ["teleop"])
    robot.vote(speed=99, stamp_ns=T0 + 10**12)  # a configured name is no exception
    assert robot.remotes.future[far] == 2
    assert robot.drive(0.21) == (-30.0, None, ["teleop"])
    robot.vote(speed=-10)  # a vote stamped now still replaces the held one
    assert robot.drive(0.22) == (-10.0, None, ["teleop"])


def test_invalid_options_are_refused() -> None:
    for options in ({"max_future_s": -1.0}, {"max_future_s": float("inf")},
                    {"max_stranger_priority": 1.5}, {"max_stranger_priority": True}):
        with pytest.raises(ValueError):
            Robot(**options)

