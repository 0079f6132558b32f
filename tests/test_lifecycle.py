"""Lifecycles a plug-in author can trust: setup/reset/shutdown order, validation when the tree
changes (never on a tick), refused changes that leave the tree untouched, and no import cycle
between the tree and the arbiters."""

from __future__ import annotations

import ast
import asyncio
import logging
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path

import pytest

from ubf_async.core.action import Action
from ubf_async.core.arbiters import (
    Conditional,
    HighestActivation,
    HighestPriority,
    PriorityMerge,
)
from ubf_async.core.behavior import (
    Arbiter,
    Behavior,
    Candidate,
    Child,
    Composite,
    Decision,
    FunctionBehavior,
    Trace,
)
from ubf_async.core.state import State
from ubf_async.errors import ConfigurationError
from ubf_async.runtime.aggregator import StateAggregator
from ubf_async.runtime.bus import Bus
from ubf_async.runtime.controller import Controller

ROOT = Path(__file__).resolve().parent.parent
STATE = State.of(now_ns=0)


class Recorder(Behavior):
    """Appends ``"<hook> <name>"`` to a shared log for every hook; can be told to raise."""

    def __init__(self, name: str, log: list[str], *, fail_setup: bool = False,
                 fail_shutdown: bool = False, action: Action | None = None) -> None:
        super().__init__(name=name)
        self.log = log
        self.fail_setup = fail_setup
        self.fail_shutdown = fail_shutdown
        self.action = action
        self.acquired = False

    def setup(self) -> None:
        self.log.append(f"setup {self.name}")
        if self.fail_setup:
            raise ConfigurationError(f"{self.name}: no such device")
        self.acquired = True

    def shutdown(self) -> None:
        self.log.append(f"shutdown {self.name}")
        self.acquired = False
        if self.fail_shutdown:
            raise RuntimeError(f"{self.name} failed to release")

    def reset(self) -> None:
        self.log.append(f"reset {self.name}")

    def act(self, state: State) -> Action | None:
        self.log.append(f"act {self.name}")
        return self.action


class SpyArbiter(HighestActivation):
    """HighestActivation that records every validate() call and refuses more than
    ``max_children`` children or a priority above ``max_priority``."""

    def __init__(self, *, max_children: int = 99, max_priority: int = 99) -> None:
        self.max_children = max_children
        self.max_priority = max_priority
        self.validated: list[tuple[str, ...]] = []
        self.resets = 0

    def validate(self, children: Sequence[Child]) -> None:
        self.validated.append(tuple(c.behavior.name for c in children))
        if len(children) > self.max_children:
            raise ConfigurationError(f"at most {self.max_children} children")
        if any(c.priority > self.max_priority for c in children):
            raise ConfigurationError(f"priorities up to {self.max_priority}")

    def reset(self) -> None:
        self.resets += 1


def tree(log: list[str], **fail: set[str]) -> Composite:
    """root(a, inner(b, c), d) of Recorders; ``fail_setup``/``fail_shutdown`` name leaves."""

    def leaf(name: str) -> Recorder:
        return Recorder(name, log, fail_setup=name in fail.get("fail_setup", set()),
                        fail_shutdown=name in fail.get("fail_shutdown", set()))

    inner = Composite(name="inner", arbiter=PriorityMerge(), children=[leaf("b"), leaf("c")])
    return Composite(name="root", arbiter=PriorityMerge(),
                     children=[leaf("a"), inner, leaf("d")])


def snapshot(c: Composite) -> tuple[Arbiter, tuple[Child, ...]]:
    return c.arbiter, c.children


# -- setup / shutdown ------------------------------------------------------------------------


def test_setup_runs_depth_first_in_child_order_and_shutdown_in_reverse() -> None:
    log: list[str] = []
    root = tree(log)
    log.clear()  # construction resets the children; not what this test is about
    root.setup()
    assert log == ["setup a", "setup b", "setup c", "setup d"]
    log.clear()
    root.shutdown()
    assert log == ["shutdown d", "shutdown c", "shutdown b", "shutdown a"]


def test_shutdown_is_idempotent_and_harmless_without_setup() -> None:
    log: list[str] = []
    root = tree(log)
    log.clear()
    root.shutdown()  # never set up: nothing to release
    assert log == []
    root.setup()
    root.shutdown()
    log.clear()
    root.shutdown()
    assert log == []
    # A plain leaf's default hooks are harmless in any order, any number of times.
    leaf = FunctionBehavior(lambda s: None, name="plain")
    leaf.shutdown()
    leaf.setup()
    leaf.shutdown()
    leaf.shutdown()


def test_shutdown_continues_past_a_child_that_raises_and_logs_it(
    caplog: pytest.LogCaptureFixture,
) -> None:
    log: list[str] = []
    root = tree(log, fail_shutdown={"c", "d"})
    root.setup()
    log.clear()
    with caplog.at_level(logging.ERROR, logger="ubf_async.core.behavior"):
        root.shutdown()  # does not raise
    assert log == ["shutdown d", "shutdown c", "shutdown b", "shutdown a"]
    failed = [r for r in caplog.records if r.levelno == logging.ERROR]
    assert [r.getMessage() for r in failed] == [
        "shutdown of 'd' in composite 'root' raised; continuing",
        "shutdown of 'c' in composite 'inner' raised; continuing",
    ]
    assert all(r.exc_info is not None for r in failed)


def test_a_failing_setup_propagates_and_shutdown_releases_what_was_acquired() -> None:
    log: list[str] = []
    root = tree(log, fail_setup={"c"})
    log.clear()
    with pytest.raises(ConfigurationError, match="c: no such device"):
        root.setup()
    assert log == ["setup a", "setup b", "setup c"]  # d was never reached
    log.clear()
    root.shutdown()
    assert log == ["shutdown d", "shutdown c", "shutdown b", "shutdown a"]
    leaves = {b.name: b for b in (root.find(n) for n in "abcd") if isinstance(b, Recorder)}
    assert not any(b.acquired for b in leaves.values())


def test_setup_of_a_live_composite_does_nothing() -> None:
    log: list[str] = []
    root = tree(log)
    root.setup()
    log.clear()
    root.setup()
    assert log == []
    assert root.live


# -- live changes: behaviours that join are set up, those that leave are shut down -----------


def test_a_behaviour_added_to_a_live_composite_is_set_up_and_reset_before_it_ticks() -> None:
    log: list[str] = []
    root = tree(log)
    root.setup()
    log.clear()
    root.add(Recorder("e", log, action=Action(speed=1)), priority=5)
    assert log == ["setup e", "reset e"]
    log.clear()
    root.act(STATE)
    assert log[-1] == "act e"


def test_a_behaviour_added_to_an_idle_composite_is_only_reset() -> None:
    log: list[str] = []
    root = tree(log)
    log.clear()
    root.add(Recorder("e", log))
    assert log == ["reset e"]


def test_a_behaviour_whose_setup_fails_does_not_join_and_is_released() -> None:
    log: list[str] = []
    root = tree(log)
    root.setup()
    before = snapshot(root)
    log.clear()
    with pytest.raises(ConfigurationError, match="e: no such device"):
        root.add(Recorder("e", log, fail_setup=True))
    assert snapshot(root) == before
    assert log == ["setup e", "shutdown e"]


def test_a_behaviour_removed_from_a_live_composite_is_shut_down_after_it_left() -> None:
    log: list[str] = []
    root = tree(log)
    root.setup()
    log.clear()
    seen_children: list[tuple[str, ...]] = []

    class Watcher(Recorder):
        def shutdown(self) -> None:
            seen_children.append(tuple(c.behavior.name for c in root.children))
            super().shutdown()

    root.add(Watcher("w", log))
    root.remove("w")
    assert log == ["setup w", "reset w", "shutdown w"]
    assert seen_children == [("a", "inner", "d")]  # it had already left
    log.clear()
    root.shutdown()
    assert "shutdown w" not in log  # not shut down twice by its former composite


def test_replace_children_on_a_live_composite() -> None:
    log: list[str] = []
    a, b = Recorder("a", log), Recorder("b", log)
    root = Composite(name="root", arbiter=PriorityMerge(), children=[a, b])
    root.setup()
    log.clear()
    root.replace_children([b, Recorder("c", log)])
    # c joins (set up, then reset), b stays (and keeps its memory), a leaves (shut down).
    assert log == ["setup c", "reset c", "shutdown a"]


# -- validation ------------------------------------------------------------------------------


def test_construction_validates_the_complete_set_once() -> None:
    spy = SpyArbiter()
    Composite(name="c", arbiter=spy, children=[FunctionBehavior(lambda s: None, name=n)
                                               for n in "xyz"])
    assert spy.validated == [("x", "y", "z")]


def test_validate_on_attach_replace_move_remove_and_arbiter_swap_never_on_a_tick() -> None:
    spy = SpyArbiter()
    leaf = lambda n: FunctionBehavior(lambda s: Action(speed=1), name=n)  # noqa: E731
    c = Composite(name="c", arbiter=spy, children=[leaf("x")])
    c.add(leaf("y"))
    c.set_child("y", priority=3)
    c.remove("x")
    c.replace_children([leaf("p"), leaf("q")])
    for _ in range(10):
        c.act(STATE)
        c.evaluate(STATE)
    assert spy.validated == [("x",), ("x", "y"), ("x", "y"), ("y",), ("p", "q")]
    other = SpyArbiter()
    c.arbiter = other
    assert other.validated == [("p", "q")]
    assert other.resets == 1  # an arbiter that takes over starts afresh
    assert c.arbiter is other


def test_refused_changes_leave_the_composite_unchanged() -> None:
    log: list[str] = []
    spy = SpyArbiter(max_children=2, max_priority=5)
    x, y = Recorder("x", log), Recorder("y", log)
    c = Composite(name="pair", arbiter=spy, children=[x, Child(y, priority=1)])
    c.setup()
    before = snapshot(c)
    log.clear()
    z = Recorder("z", log)
    with pytest.raises(ConfigurationError, match=r"composite 'pair'.*at most 2 children"):
        c.add(z)
    with pytest.raises(ConfigurationError, match=r"composite 'pair'.*at most 2 children"):
        c.replace_children([x, y, z])
    with pytest.raises(ConfigurationError, match=r"composite 'pair'.*priorities up to 5"):
        c.set_child("y", priority=6)
    with pytest.raises(ConfigurationError, match="already has a child named 'x'"):
        c.add(Recorder("x", log))
    with pytest.raises(ConfigurationError, match="weight"):
        c.set_child("y", weight=-1.0)
    with pytest.raises(KeyError):
        c.set_child("nope", priority=1)
    with pytest.raises(ConfigurationError, match=r"composite 'pair'.*at most 1 children"):
        c.arbiter = SpyArbiter(max_children=1)
    assert snapshot(c) == before
    assert log == []  # nobody refused was set up, reset or shut down


def test_set_child_moves_a_child_and_keeps_its_behaviour_and_memory() -> None:
    log: list[str] = []
    x = Recorder("x", log, action=Action(speed=10))
    y = Recorder("y", log, action=Action(speed=-10))
    c = Composite(name="c", arbiter=HighestPriority(), children=[Child(x, 1), Child(y, 2)])
    assert c.act(STATE).speed == -10
    log.clear()
    moved = c.set_child("x", priority=3, weight=0.5)
    assert moved == Child(x, 3, 0.5)
    assert c.children == (Child(x, 3, 0.5), Child(y, 2, 1.0))
    assert log == []  # not reset, not set up: the same behaviour in a new place
    assert c.act(STATE).speed == 10
    assert c.set_child("x").priority == 3  # nothing given: nothing changes


def test_conditional_refuses_any_other_number_of_children() -> None:
    def leaf(n: str) -> Behavior:
        return FunctionBehavior(lambda s: None, name=n)

    for count in (0, 1, 3):
        with pytest.raises(ConfigurationError, match=r"composite 'if'.*exactly two children"):
            Composite(name="if", arbiter=Conditional(lambda s: True),
                      children=[leaf(f"c{i}") for i in range(count)])
    c = Composite(name="if", arbiter=Conditional(lambda s: True),
                  children=[leaf("yes"), leaf("no")])
    before = snapshot(c)
    with pytest.raises(ConfigurationError, match="exactly two"):
        c.remove("no")
    with pytest.raises(ConfigurationError, match="exactly two"):
        c.add(leaf("maybe"))
    assert snapshot(c) == before
    c.replace_children([leaf("no"), leaf("yes")])  # two again: accepted
    three = Composite(name="three", arbiter=PriorityMerge(),
                      children=[leaf("a"), leaf("b"), leaf("c")])
    with pytest.raises(ConfigurationError, match="composite 'three'"):
        three.arbiter = Conditional(lambda s: True)
    assert isinstance(three.arbiter, PriorityMerge)


def test_a_composite_refuses_what_is_not_a_behaviour_or_an_arbiter() -> None:
    with pytest.raises(ConfigurationError, match="must be a Behavior"):
        Composite(name="c", arbiter=PriorityMerge(), children=["oops"])  # type: ignore[list-item]
    with pytest.raises(ConfigurationError, match="must be an Arbiter"):
        Composite(name="c", arbiter=object())  # type: ignore[arg-type]
    c = Composite(name="c", arbiter=PriorityMerge())
    with pytest.raises(ConfigurationError, match="must be an Arbiter"):
        c.arbiter = PriorityMerge  # type: ignore[assignment]


# -- abstract bases and the internal tick ----------------------------------------------------


def test_behavior_and_arbiter_are_abstract() -> None:
    class NoAct(Behavior):
        pass

    class NoArbitrate(Arbiter):
        pass

    with pytest.raises(TypeError, match="act"):
        NoAct()  # type: ignore[abstract]
    with pytest.raises(TypeError, match="arbitrate"):
        NoArbitrate()  # type: ignore[abstract]


def test_overriding_the_internal_tick_is_refused_when_the_class_is_defined() -> None:
    with pytest.raises(TypeError, match="overrides run"):
        class Runner(Behavior):
            def act(self, state: State) -> Action | None:
                return None

            def run(self, state: State) -> tuple[Action | None, Trace | None]:
                return None, None

    with pytest.raises(TypeError, match="overrides evaluate"):
        class Evaluator(Composite):
            def evaluate(self, state: State) -> Trace:  # type: ignore[misc]
                return Trace(self.name, None)


def test_an_arbiter_subclass_is_named_after_its_class() -> None:
    class FirstWins(Arbiter):
        def arbitrate(self, candidates: Sequence[Candidate], state: State) -> Decision:
            return Decision(candidates[0].action, (candidates[0].index,)) if candidates \
                else Decision(None)

    c = Composite(name="c", arbiter=FirstWins(), children=[
        FunctionBehavior(lambda s: Action(speed=5), name="a")])
    assert c.evaluate(STATE).arbiter == "FirstWins"
    assert FirstWins().describe() == "FirstWins"


def test_evaluate_of_a_leaf_and_of_a_composite() -> None:
    leaf = FunctionBehavior(lambda s: Action(speed=3), name="leaf")
    trace = leaf.evaluate(STATE)
    assert (trace.name, trace.action, trace.children) == ("leaf", Action(speed=3), [])
    c = Composite(name="c", arbiter=PriorityMerge(), children=[leaf])
    trace = c.evaluate(STATE)
    assert trace.arbiter == "PriorityMerge" and trace.winning_leaves() == ["leaf"]


# -- no import cycle ---------------------------------------------------------------------------


def test_arbiters_import_first_in_a_fresh_interpreter() -> None:
    for code in (
        "import ubf_async.core.arbiters",
        "import ubf_async.core.behavior",
        "import ubf_async.behaviors.predicates",
        "from ubf_async.core.arbiters import Arbiter; "
        "from ubf_async.core.behavior import Arbiter as A; assert Arbiter is A",
        "from ubf_async.core.behavior import "
        "Behavior, Composite, Child, Candidate, Decision, Trace",
    ):
        done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                              text=True, timeout=60)
        assert done.returncode == 0, f"{code}\n{done.stderr}"


def test_behavior_module_never_imports_arbiters() -> None:
    source = (ROOT / "ubf_async" / "core" / "behavior.py").read_text()
    imported: list[str] = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            imported.extend(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            imported.append(node.module or "")
            imported.extend(f"{node.module}.{alias.name}" for alias in node.names)
    assert imported  # the walk did see the imports
    assert not [m for m in imported if "arbiters" in m], imported
    assert "TYPE_CHECKING" not in source


# -- the controller drives the lifecycle -------------------------------------------------------


@pytest.mark.asyncio
async def test_controller_sets_up_before_the_first_tick_and_shuts_down_when_closed(
    robot_bus: Bus,
) -> None:
    log: list[str] = []
    root = Composite(name="root", arbiter=PriorityMerge(),
                     children=[Recorder("a", log, action=Action(speed=20))])
    log.clear()
    agg = StateAggregator(bus=robot_bus)
    ctl = Controller(bus=robot_bus, aggregator=agg, root=root, rate_hz=100)
    await ctl.start()
    try:
        await asyncio.wait_for(ctl.ticked.wait(), 5)
        assert log[:3] == ["setup a", "reset a", "act a"]
        assert root.live
    finally:
        await ctl.aclose()
    assert log[-1] == "shutdown a"
    assert log.count("setup a") == 1 and log.count("shutdown a") == 1
    assert not root.live


@pytest.mark.asyncio
async def test_a_failing_setup_fails_the_controller_run_and_no_tick_happens(
    robot_bus: Bus,
) -> None:
    log: list[str] = []
    released = asyncio.Event()

    class Broken(Recorder):
        def shutdown(self) -> None:
            super().shutdown()
            released.set()

    root = Composite(name="root", arbiter=PriorityMerge(),
                     children=[Broken("camera_user", log, fail_setup=True)])
    agg = StateAggregator(bus=robot_bus)
    ctl = Controller(bus=robot_bus, aggregator=agg, root=root, rate_hz=100,
                     restart_backoff_s=60.0)
    await ctl.start()
    try:
        await asyncio.wait_for(released.wait(), 5)
        # Counted in the same step of the run's task that released the tree.
        assert ctl.restarts == 1
        assert isinstance(ctl.last_error, ConfigurationError)
        assert "no such device" in str(ctl.last_error)
        assert ctl.stats.ticks == 0
        assert log == ["reset camera_user", "setup camera_user", "shutdown camera_user"]
    finally:
        await ctl.aclose()


@pytest.mark.asyncio
async def test_sync_mode_ticks_on_its_sync_source(robot_bus: Bus, peer_bus: Bus) -> None:
    agg = StateAggregator(bus=robot_bus)
    ctl = Controller(bus=robot_bus, aggregator=agg, mode="sync", sync_source="range/front",
                     root=FunctionBehavior(lambda s: Action(speed=10), name="go"))
    assert ctl.sync_source == "range/front"
    ranging = peer_bus.publisher(peer_bus.keys.sensor("range", "front"), "range")
    await agg.start()
    await ctl.start()
    try:
        await asyncio.wait_for(ctl.running.wait(), 5)
        await asyncio.wait_for(agg.running.wait(), 5)
        await ranging.wait_for_subscribers()
        ranging.publish({"range_mm": 500, "status": "ok"})
        await asyncio.wait_for(ctl.ticked.wait(), 5)
        assert ctl.stats.ticks == 1 and ctl.stats.triggered == 1
    finally:
        await ctl.aclose()
        await agg.aclose()
