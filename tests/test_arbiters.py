"""Arbiter semantics, pinned down: ties, empty input, abstention, unset fields, nesting."""

from __future__ import annotations

import random

import pytest

from ubf_async import (
    Action,
    Behavior,
    Child,
    CommandFusion,
    Composite,
    Conditional,
    FunctionBehavior,
    HighestActivation,
    HighestPriority,
    MonteCarlo,
    PriorityFusion,
    PriorityMerge,
    State,
    UtilityFusion,
)
from ubf_async.errors import ConfigurationError

STATE = State.of(now_ns=0)


def const(name: str, action: Action | None) -> Behavior:
    return FunctionBehavior(lambda state: action, name=name)


def comp(arbiter, *children: tuple[str, Action | None, int, float]) -> Composite:
    return Composite(
        name="root",
        arbiter=arbiter,
        children=[Child(const(n, a), priority=p, weight=w) for n, a, p, w in children],
    )


ALL_ARBITERS = [
    HighestActivation,
    HighestPriority,
    PriorityMerge,
    PriorityFusion,
    UtilityFusion,
    CommandFusion,
    lambda: MonteCarlo(seed=1),
]


@pytest.mark.parametrize("make", ALL_ARBITERS)
def test_empty_composite_abstains(make) -> None:
    trace = Composite(name="empty", arbiter=make()).evaluate(STATE)
    assert trace.action is None
    assert trace.winning_leaves() == []


@pytest.mark.parametrize("make", ALL_ARBITERS)
def test_all_abstain_none_and_zero_vote(make) -> None:
    c = comp(make(), ("a", None, 1, 1.0), ("b", Action(speed=50, vote=0), 5, 1.0))
    assert c.act(STATE) is None


@pytest.mark.parametrize("make", ALL_ARBITERS)
def test_single_voter_passes_through(make) -> None:
    action = Action(speed=20, turn=-10, vote=3)
    c = comp(make(), ("a", None, 9, 1.0), ("b", action, 0, 1.0))
    result = c.act(STATE)
    assert result is not None
    assert (result.speed, result.turn) == (20, -10)


def test_highest_activation_uses_vote_times_weight_and_first_on_tie() -> None:
    c = comp(
        HighestActivation(),
        ("a", Action(speed=1, vote=2), 0, 1.0),
        ("b", Action(speed=2, vote=1), 0, 3.0),  # utility 3 beats 2
        ("c", Action(speed=3, vote=3), 0, 1.0),  # ties with b, comes later
    )
    trace = c.evaluate(STATE)
    assert trace.action.speed == 2
    assert trace.winning_leaves() == ["b"]


def test_highest_priority_ignores_vote_across_priorities_and_breaks_ties_by_utility() -> None:
    c = comp(
        HighestPriority(),
        ("low", Action(speed=1, vote=100), 1, 1.0),
        ("hi_a", Action(speed=2, vote=1), 5, 1.0),
        ("hi_b", Action(speed=3, vote=2), 5, 1.0),
        ("hi_c", Action(speed=4, vote=2), 5, 1.0),
    )
    assert c.act(STATE).speed == 3


def test_priority_merge_sums_equal_priorities_and_clamps() -> None:
    c = comp(
        PriorityMerge(),
        ("search", None, 2, 1.0),
        ("chase", Action(speed=40, turn=60, vote=1), 1, 1.0),
        ("flee", Action(speed=-20, turn=60, vote=2), 1, 1.0),
        ("low", Action(speed=99, turn=0), 0, 1.0),
    )
    trace = c.evaluate(STATE)
    assert trace.action.speed == 20
    assert trace.action.turn == 100  # 120 clamped
    assert trace.action.vote == 2
    assert sorted(trace.winning_leaves()) == ["chase", "flee"]


def test_priority_merge_higher_priority_wins_outright() -> None:
    c = comp(
        PriorityMerge(),
        ("a", Action(speed=10, turn=80), 2, 1.0),
        ("b", Action(speed=40), 1, 1.0),
        ("c", Action(speed=-40), 1, 1.0),
    )
    assert (c.act(STATE).speed, c.act(STATE).turn) == (10, 80)


def test_priority_merge_unset_fields_do_not_contribute() -> None:
    c = comp(
        PriorityMerge(),
        ("a", Action(speed=30), 1, 1.0),
        ("b", Action(turn=-20, message="hi"), 1, 1.0),
        ("c", Action(message="later"), 1, 1.0),
    )
    result = c.act(STATE)
    assert (result.speed, result.turn, result.message) == (30, -20, "hi")
    assert result.leds is None


def test_priority_fusion_fills_unset_fields_from_lower_priorities() -> None:
    c = comp(
        PriorityFusion(),
        ("low", Action(speed=5, turn=5, leds=3), 0, 1.0),
        ("high", Action(speed=50), 9, 1.0),
        ("mid", Action(turn=-30, vote=1), 4, 1.0),
        ("mid2", Action(turn=30, vote=2), 4, 1.0),  # same priority, larger utility wins
    )
    trace = c.evaluate(STATE)
    assert (trace.action.speed, trace.action.turn, trace.action.leds) == (50, 30, 3)
    assert sorted(trace.winning_leaves()) == ["high", "low", "mid2"]


def test_utility_fusion_fieldwise_by_vote_then_child_order() -> None:
    c = comp(
        UtilityFusion(),
        ("a", Action(speed=10, vote=1), 99, 1.0),
        ("b", Action(turn=20, message="b", vote=5), 0, 1.0),
        ("c", Action(speed=30, message="c", vote=5), 0, 1.0),
    )
    result = c.act(STATE)
    # b and c tie on utility: b comes first and has message; speed only c sets among top.
    assert (result.speed, result.turn, result.message, result.vote) == (30, 20, "b", 5)


def test_command_fusion_weighted_mean_skips_unset() -> None:
    c = comp(
        CommandFusion(),
        ("a", Action(speed=100, turn=0, vote=1), 0, 1.0),
        ("b", Action(speed=0, vote=1), 0, 3.0),
        ("c", Action(turn=-60, vote=2), 0, 1.0),
    )
    result = c.act(STATE)
    assert result.speed == pytest.approx(25.0)  # (100*1 + 0*3) / 4
    assert result.turn == pytest.approx(-40.0)  # (0*1 + -60*2) / 3


def test_command_fusion_zero_weight_does_not_count() -> None:
    c = comp(CommandFusion(), ("a", Action(speed=100), 0, 0.0), ("b", Action(speed=10), 0, 1.0))
    assert c.act(STATE).speed == 10
    only_zero = comp(CommandFusion(), ("a", Action(speed=100), 0, 0.0))
    assert only_zero.act(STATE) is None


def test_monte_carlo_is_seedable_and_proportional() -> None:
    def run(seed: int) -> list[float]:
        c = comp(
            MonteCarlo(seed=seed),
            ("a", Action(speed=1, vote=1), 0, 1.0),
            ("b", Action(speed=2, vote=3), 0, 1.0),
        )
        return [c.act(STATE).speed for _ in range(4000)]

    first = run(7)
    assert first == run(7)
    share_b = first.count(2) / len(first)
    assert 0.70 < share_b < 0.80  # expected 0.75


def test_monte_carlo_hold_counts_down_and_releases() -> None:
    arbiter = MonteCarlo(hold_ticks=3, rng=random.Random(3))
    c = comp(
        arbiter,
        ("a", Action(speed=1), 0, 1.0),
        ("b", Action(speed=2), 0, 1.0),
    )
    picks = [c.act(STATE).speed for _ in range(300)]
    # Runs of one choice come in multiples of 3 (a fresh draw can repeat the same child).
    blocks = [picks[i : i + 3] for i in range(0, 300, 3)]
    assert all(len(set(block)) == 1 for block in blocks)
    assert len({block[0] for block in blocks}) == 2  # it does release and redraw


def test_monte_carlo_redraws_when_held_child_abstains() -> None:
    flag = {"a_on": True}
    a = FunctionBehavior(lambda s: Action(speed=1) if flag["a_on"] else None, name="a")
    b = FunctionBehavior(lambda s: Action(speed=2, vote=1e-9), name="b")
    c = Composite(name="mc", arbiter=MonteCarlo(hold_ticks=100, seed=0), children=[a, b])
    assert c.act(STATE).speed == 1
    flag["a_on"] = False
    assert c.act(STATE).speed == 2


def test_conditional_evaluates_only_the_chosen_child() -> None:
    calls: list[str] = []

    def leaf(name: str, speed: float) -> Behavior:
        def fn(state: State) -> Action:
            calls.append(name)
            return Action(speed=speed)

        return FunctionBehavior(fn, name=name)

    c = Composite(
        name="cond",
        arbiter=Conditional(lambda s: s.value("range/front", "range_mm", 9999) < 200),
        children=[leaf("avoid", -50), leaf("cruise", 50)],
    )
    near = State.of(range__front={"range_mm": 100, "status": "ok"})
    far = State.of(range__front={"range_mm": 900, "status": "ok"})
    assert c.act(near).speed == -50
    assert c.act(far).speed == 50
    assert calls == ["avoid", "cruise"]


def test_conditional_needs_two_children() -> None:
    # Refused when the composite is built, not on its first tick.
    with pytest.raises(ConfigurationError, match=r"'cond'.*exactly two children"):
        Composite(name="cond", arbiter=Conditional(lambda s: True), children=[const("a", None)])


def test_nesting_three_levels_and_trace() -> None:
    leaf_turn = const("turn_left", Action(turn=50, vote=2))
    leaf_slow = const("slow", Action(speed=10))
    inner = Composite(name="inner", arbiter=UtilityFusion(), children=[leaf_turn, leaf_slow])
    middle = Composite(
        name="middle",
        arbiter=PriorityMerge(),
        children=[Child(inner, priority=1), Child(const("push", Action(speed=20)), priority=1)],
    )
    root = Composite(
        name="root",
        arbiter=HighestPriority(),
        children=[Child(middle, priority=5), Child(const("idle", Action(speed=0)), priority=0)],
    )
    trace = root.evaluate(STATE)
    assert (trace.action.speed, trace.action.turn) == (30, 50)
    assert sorted(trace.winning_leaves()) == ["push", "slow", "turn_left"]
    text = trace.render()
    assert "middle" in text and "* turn_left" in text and "  idle" in text
    tree = root.render_tree()
    assert tree.splitlines()[0].startswith("root <HighestPriority>")
    assert "      turn_left" in tree  # three levels of indentation


def test_arbiter_and_children_replaceable_at_run_time() -> None:
    c = comp(
        HighestActivation(),
        ("a", Action(speed=10, vote=1), 1, 1.0),
        ("b", Action(speed=-10, vote=1), 1, 1.0),
    )
    assert c.act(STATE).speed == 10
    c.arbiter = PriorityMerge()
    assert c.act(STATE).speed == 0
    c.arbiter = CommandFusion()
    c.remove("b")
    c.add(const("c", Action(speed=30)), priority=0, weight=1.0)
    assert c.act(STATE).speed == pytest.approx(20)
    with pytest.raises(ValueError, match="already has a child"):
        c.add(const("c", None))
    with pytest.raises(KeyError):
        c.remove("nope")


def test_child_validation() -> None:
    with pytest.raises(ValueError):
        Child(const("a", None), weight=float("nan"))
    with pytest.raises(ValueError):
        Child(const("a", None), weight=-1)


def reference_winners(trace) -> list[str]:
    """The winning leaves read through the built child traces (what ``render`` shows)."""
    if not trace.children:
        return [trace.name] if trace.action is not None else []
    return [name for child in trace.children if child.won for name in reference_winners(child)]


def random_tree(rng: random.Random, depth: int, counter: list[int]) -> Behavior:
    counter[0] += 1
    name = f"n{counter[0]}"
    if depth == 0 or rng.random() < 0.4:
        roll = rng.random()
        if roll < 0.2:
            return const(name, None)
        if roll < 0.3:
            def fail(state: State) -> Action | None:
                raise RuntimeError("a behaviour that fails")
            return FunctionBehavior(fail, name=name)
        return const(name, Action(speed=rng.uniform(-100, 100), turn=rng.uniform(-100, 100),
                                  vote=rng.choice([0.0, 1.0, 2.0])))
    arbiter = rng.choice(ALL_ARBITERS)()
    children = [Child(random_tree(rng, depth - 1, counter), priority=rng.randint(0, 3),
                      weight=rng.choice([0.5, 1.0])) for _ in range(rng.randint(0, 4))]
    return Composite(name=name, arbiter=arbiter, children=children)


@pytest.mark.parametrize("seed", range(40))
def test_winning_leaves_read_from_an_unbuilt_trace_match_the_built_children(seed: int) -> None:
    # The controller asks every tick, before anything builds the child traces.
    rng = random.Random(seed)
    root = Composite(name="root", arbiter=rng.choice(ALL_ARBITERS)(),
                     children=[random_tree(rng, 2, counter)
                               for counter in [[0]] for _ in range(rng.randint(1, 4))])
    for _ in range(3):
        trace = root.evaluate(STATE)
        fast = trace.winning_leaves()
        assert fast == reference_winners(trace)  # (this builds the children)
        assert trace.winning_leaves() == fast
