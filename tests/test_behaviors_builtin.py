"""The built-in plug-ins as a robot file reaches them: by name through the registries, with
parameters checked by the msgspec Struct of their signature; and the predicates."""

from __future__ import annotations

import importlib.util
import random
from pathlib import Path
from typing import Any

import msgspec
import pytest

from ubf_async.assembly import registry
from ubf_async.assembly.plugins import conditional, predicate_from
from ubf_async.behaviors.basic import ConstantDrive, Stop
from ubf_async.behaviors.obstacles import Avoid
from ubf_async.behaviors.pink_ball import Chase, Flee, Search
from ubf_async.core.action import Action
from ubf_async.core.arbiters import Conditional, MonteCarlo
from ubf_async.core.behavior import Arbiter, Behavior, Composite, FunctionBehavior
from ubf_async.core.state import Reading, State
from ubf_async.errors import ConfigurationError, PluginError

INJECTED = frozenset({"name", "rng"})
ARBITER_NAMES = ("HighestActivation", "HighestPriority", "PriorityMerge", "PriorityFusion",
                 "UtilityFusion", "CommandFusion", "MonteCarlo", "Conditional")
BEHAVIOR_CLASSES = {"search": Search, "chase": Chase, "flee": Flee, "avoid": Avoid,
                    "stop": Stop, "drive": ConstantDrive}
EXAMPLES = Path(__file__).resolve().parent.parent / "examples"


def build(group: registry.Registry, plugin: str, data: dict[str, Any], /,
          **inject: Any) -> Any:
    """What the robot-file loader does: look up, check the data, inject, call."""
    factory = group.get(plugin)
    struct = registry.parameters_of(factory, injected=INJECTED)
    params = msgspec.convert(data, struct)
    kwargs = {f: getattr(params, f) for f in params.__struct_fields__}
    kwargs.update({k: v for k, v in inject.items() if registry.accepts(factory, k)})
    return factory(**kwargs)


def stale(**values: dict[str, Any]) -> State:
    return State({name.replace("__", "/"): Reading(value=v, stamp_ns=0, stale=True)
                  for name, v in values.items()})


def field_types(struct: type[msgspec.Struct]) -> dict[str, msgspec.inspect.Type]:
    info = msgspec.inspect.type_info(struct)
    assert isinstance(info, msgspec.inspect.StructType)
    return {f.name: f.type for f in info.fields}


# -- arbiters ----------------------------------------------------------------------------------

ARBITER_DATA: dict[str, dict[str, Any]] = {
    "MonteCarlo": {"hold_ticks": 3, "seed": 7},
    "Conditional": {"predicate": "sees_color", "predicate_params": {"min_pixels": 1}},
}


@pytest.mark.parametrize("name", ARBITER_NAMES)
def test_every_arbiter_is_built_from_keyword_data(name: str) -> None:
    assert name in registry.ARBITERS.names()
    arbiter = build(registry.ARBITERS, name, ARBITER_DATA.get(name, {}),
                    rng=random.Random(0), name=name)
    assert isinstance(arbiter, Arbiter)
    assert arbiter.name == name
    go = FunctionBehavior(lambda s: Action(speed=30), name="go")
    stop = FunctionBehavior(lambda s: Action(speed=0), name="stop")
    c = Composite(name="c", arbiter=arbiter, children=[go, stop])
    action = c.act(State.of(camera__front={"bins": [0, 0, 5, 0, 0], "total": 5}))
    assert action is not None and action.speed in (0, 15, 30)


@pytest.mark.parametrize("name", ARBITER_NAMES)
def test_every_arbiter_parameter_has_a_concrete_type(name: str) -> None:
    struct = registry.parameters_of(registry.ARBITERS.get(name), injected=INJECTED)
    for field, kind in field_types(struct).items():
        assert not isinstance(kind, msgspec.inspect.AnyType), f"{name}.{field} is untyped"


def test_arbiters_without_parameters_refuse_any() -> None:
    with pytest.raises(msgspec.ValidationError, match="unknown field `speed`"):
        build(registry.ARBITERS, "PriorityMerge", {"speed": 1})


def test_monte_carlo_from_data_is_checked_and_seedable() -> None:
    with pytest.raises(msgspec.ValidationError, match=r"\$\.hold_ticks"):
        build(registry.ARBITERS, "MonteCarlo", {"hold_ticks": 0})
    with pytest.raises(msgspec.ValidationError, match=r"\$\.seed"):
        build(registry.ARBITERS, "MonteCarlo", {"seed": "seven"})
    with pytest.raises(ConfigurationError, match="hold_ticks"):
        MonteCarlo(hold_ticks=0)

    def draws(arbiter: MonteCarlo) -> list[float]:
        c = Composite(name="mc", arbiter=arbiter, children=[
            FunctionBehavior(lambda s: Action(speed=1), name="a"),
            FunctionBehavior(lambda s: Action(speed=2), name="b")])
        return [c.act(State()).speed for _ in range(200)]

    # An explicit seed wins over the injected rng: the same draws whatever the robot seed.
    seeded = [draws(build(registry.ARBITERS, "MonteCarlo", {"seed": 5}, rng=random.Random(r)))
              for r in (1, 2)]
    assert seeded[0] == seeded[1]
    # Without a seed the injected rng decides.
    injected = [draws(build(registry.ARBITERS, "MonteCarlo", {}, rng=random.Random(r)))
                for r in (3, 3, 4)]
    assert injected[0] == injected[1] != injected[2]


def test_conditional_by_name_picks_by_the_predicate() -> None:
    arbiter = conditional(predicate="sees_color", predicate_params={"min_pixels": 10})
    c = Composite(name="if", arbiter=arbiter, children=[
        FunctionBehavior(lambda s: Action(speed=40), name="chase"),
        FunctionBehavior(lambda s: Action(speed=0), name="wait")])
    assert c.act(State.of(camera__front={"bins": [0, 0, 10, 0, 0], "total": 10})).speed == 40
    assert c.act(State.of(camera__front={"bins": [0, 0, 9, 0, 0], "total": 9})).speed == 0
    assert c.act(State()).speed == 0
    assert arbiter.describe() == "Conditional(sees_color(min_pixels=10))"


def test_conditional_refuses_an_unknown_predicate_when_built() -> None:
    with pytest.raises(PluginError, match=r"unknown predicate 'sees_colour'.*sees_color"):
        conditional(predicate="sees_colour")
    with pytest.raises(PluginError, match="unknown predicate"):
        build(registry.ARBITERS, "Conditional", {"predicate": "nope"})
    with pytest.raises(PluginError, match="cannot import"):
        conditional(predicate="no_such_module:factory")


def test_conditional_refuses_bad_predicate_params_when_built() -> None:
    with pytest.raises(ConfigurationError, match=r"'sees_color'.*\$\.min_pixels"):
        conditional(predicate="sees_color", predicate_params={"min_pixels": "many"})
    with pytest.raises(ConfigurationError, match=r"'sees_color'.*\$\.min_pixels"):
        conditional(predicate="sees_color", predicate_params={"min_pixels": -1})
    with pytest.raises(ConfigurationError, match="unknown field `pixels`"):
        conditional(predicate="sees_color", predicate_params={"pixels": 1})
    with pytest.raises(ConfigurationError, match="missing required field `source`"):
        conditional(predicate="source_fresh")
    # The core's Conditional takes a callable only; names are the assembly's (conditional).
    with pytest.raises(ConfigurationError, match=r"got str.*assembly\.plugins\.conditional"):
        Conditional("sees_color")  # type: ignore[arg-type]
    with pytest.raises(ConfigurationError, match="got int"):
        Conditional(42)  # type: ignore[arg-type]


def test_conditional_predicate_by_module_reference_and_by_callable() -> None:
    by_reference = conditional(predicate="ubf_async.behaviors.predicates:source_fresh",
                               predicate_params={"source": "range/front"})
    assert by_reference.predicate(State.of(range__front={"range_mm": 1, "status": "ok"}))
    assert not by_reference.predicate(State())
    by_callable = Conditional(lambda s: True, label="always")
    assert by_callable.describe() == "Conditional(always)"


def test_predicate_factory_that_returns_no_callable_is_refused() -> None:
    registry.PREDICATES.register("broken_predicate", lambda: 42)
    try:
        with pytest.raises(PluginError, match="not a State -> bool callable"):
            predicate_from("broken_predicate")
    finally:
        registry.PREDICATES.unregister("broken_predicate")


# -- behaviours --------------------------------------------------------------------------------


@pytest.mark.parametrize(("name", "cls"), sorted(BEHAVIOR_CLASSES.items()))
def test_builtin_behaviours_are_registered_and_built_from_defaults(
    name: str, cls: type[Behavior]
) -> None:
    assert registry.BEHAVIORS.get(name) is cls
    built = build(registry.BEHAVIORS, name, {}, name=f"my_{name}", rng=random.Random(1))
    assert isinstance(built, cls) and built.name == f"my_{name}"
    assert cls().name == name  # the registered class's own default name
    struct = registry.parameters_of(cls, injected=INJECTED)
    assert not {"name", "rng"} & set(struct.__struct_fields__)
    for field, kind in field_types(struct).items():
        assert not isinstance(kind, msgspec.inspect.AnyType), f"{name}.{field} is untyped"


WRONG_TYPES = [
    ("search", {"period_s": "soon"}, "period_s"),
    ("chase", {"min_pixels": 1.5}, "min_pixels"),
    ("flee", {"start_pixels": "near"}, "start_pixels"),
    ("avoid", {"sources": "range/front"}, "sources"),
    ("avoid", {"near_mm": "close"}, "near_mm"),
    ("drive", {"speed": "fast"}, "speed"),
    ("stop", {"vote": [1]}, "vote"),
    ("chase", {"source": 3}, "source"),
]
OUT_OF_RANGE = [
    ("search", {"period_s": 0}, "period_s"),
    ("chase", {"min_pixels": -1}, "min_pixels"),
    ("chase", {"speed": 101}, "speed"),
    ("flee", {"min_speed": 5}, "min_speed"),
    ("flee", {"speed_per_pixel": -1}, "speed_per_pixel"),
    ("avoid", {"near_mm": 0}, "near_mm"),
    ("avoid", {"hold_s": -1}, "hold_s"),
    ("avoid", {"hold_s": 61}, "hold_s"),
    ("drive", {"turn": -100.5}, "turn"),
    ("stop", {"vote": -1}, "vote"),
]


@pytest.mark.parametrize(("name", "data", "field"), WRONG_TYPES + OUT_OF_RANGE)
def test_bad_behaviour_parameters_are_refused_naming_the_field(
    name: str, data: dict[str, Any], field: str
) -> None:
    struct = registry.parameters_of(registry.BEHAVIORS.get(name), injected=INJECTED)
    with pytest.raises(msgspec.ValidationError, match=rf"at `\$\.{field}`$"):
        msgspec.convert(data, struct)


@pytest.mark.parametrize(("name", "data", "field"), OUT_OF_RANGE)
def test_the_same_bounds_hold_when_built_from_code(
    name: str, data: dict[str, Any], field: str
) -> None:
    with pytest.raises(ConfigurationError, match=rf"{field} must be"):
        BEHAVIOR_CLASSES[name](**data)


def test_unknown_behaviour_parameter_is_refused() -> None:
    struct = registry.parameters_of(Search, injected=INJECTED)
    with pytest.raises(msgspec.ValidationError, match="unknown field `period`"):
        msgspec.convert({"period": 4}, struct)


def test_thesis_numbers_stay_the_defaults() -> None:
    search, chase, flee = Search(), Chase(), Flee()
    assert (search.speed, search.turn, search.period_ns) == (10.0, 80.0, 4_000_000_000)
    assert (chase.speed, chase.min_pixels) == (40.0, 1)
    assert (flee.start_pixels, flee.speed_per_pixel, flee.min_speed) == (100, 1.0, -80.0)


def test_stop_and_drive() -> None:
    assert Stop().act(State()) == Action(speed=0, turn=0)
    drive = build(registry.BEHAVIORS, "drive", {"speed": 35, "turn": -20}, name="cruise")
    assert drive.act(State()) == Action(speed=35, turn=-20)
    assert drive.name == "cruise"


def test_avoid_from_data() -> None:
    avoid = build(registry.BEHAVIORS, "avoid", {"sources": ["range/left"], "near_mm": 200,
                                                 "hold_s": 0})
    assert avoid.act(State.of(range__front={"range_mm": 10, "status": "ok"})) is None
    near = avoid.act(State.of(range__left={"range_mm": 100, "status": "ok"}))
    assert (near.speed, near.turn, near.vote) == (-30, -60, 1.5)  # on the left: turn right
    assert avoid.act(stale(range__left={"range_mm": 10, "status": "ok"})) is None


def test_avoid_keeps_backing_away_for_its_hold() -> None:
    """Once the beam has met an obstacle within near_mm, avoid keeps backing and turning for
    hold_s (1.5 s by default) after the last such reading — so the body, not just the beam,
    turns clear of an edge — then lets go; a new reading renews the hold."""
    avoid = Avoid()
    assert avoid.hold_ns == 1_500_000_000
    s = 1_000_000_000
    clear = {"range_mm": 700, "status": "ok"}
    assert avoid.act(State.of(now_ns=0, range__front=clear)) is None
    near = avoid.act(State.of(now_ns=1 * s, range__front={"range_mm": 125, "status": "ok"}))
    assert near is not None and (near.speed, near.turn, near.vote) == (-30, 60, 1.5)
    held = avoid.act(State.of(now_ns=2 * s, range__front=clear))
    assert held is not None and (held.speed, held.turn, held.vote) == (-30, 60, 1.0)
    assert avoid.act(State.of(now_ns=int(2.49 * s), range__front=clear)) == held
    assert avoid.act(State.of(now_ns=int(2.5 * s), range__front=clear)) is None
    assert avoid.act(State.of(now_ns=int(2.6 * s), range__front=clear)) is None
    avoid.act(State.of(now_ns=3 * s, range__front={"range_mm": 0, "status": "too_close"}))
    assert avoid.act(State.of(now_ns=4 * s, range__front=clear)) == held
    avoid.reset()
    assert avoid.act(State.of(now_ns=4 * s, range__front=clear)) is None


def test_the_example_still_runs_the_moved_behaviour_under_its_old_name() -> None:
    spec = importlib.util.spec_from_file_location("avoid_example",
                                                  EXAMPLES / "avoid_obstacles.py")
    assert spec is not None and spec.loader is not None
    example = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(example)
    behaviour = example.AvoidObstacles(near_mm=250)
    assert isinstance(behaviour, Avoid) and behaviour.name == "avoid_obstacles"
    args = example.build_parser().parse_args(["--source", "range/front", "--near-mm", "300"])
    made = example.make_behavior(args)
    assert (made.name, made.sources, made.near_mm) == ("avoid_obstacles", ["range/front"], 300)
    assert made.hold_ns == Avoid().hold_ns  # the built-in's hold unless told otherwise
    args = example.build_parser().parse_args(["--hold-s", "0.25"])
    assert example.make_behavior(args).hold_ns == 250_000_000


# -- predicates --------------------------------------------------------------------------------


def predicate(name: str, **params: Any) -> Any:
    return predicate_from(name, params)


def test_predicates_are_registered() -> None:
    assert {"sees_color", "obstacle_within", "source_fresh"} <= set(registry.PREDICATES.names())


def test_sees_color() -> None:
    sees = predicate("sees_color")
    assert sees(State.of(camera__front={"bins": [0, 1, 0, 0, 0], "total": 1}))
    assert not sees(State.of(camera__front={"bins": [0, 0, 0, 0, 0], "total": 0}))
    assert not sees(State())
    assert not sees(stale(camera__front={"bins": [9, 9, 9, 9, 9], "total": 45}))
    rear = predicate("sees_color", source="camera/rear", min_pixels=20)
    assert rear(State.of(camera__rear={"bins": [10, 10, 0, 0, 0], "total": 20}))
    assert not rear(State.of(camera__rear={"bins": [10, 9, 0, 0, 0], "total": 19}),)
    assert not rear(State.of(camera__front={"bins": [50, 50, 0, 0, 0], "total": 100}))
    anything = predicate("sees_color", min_pixels=0)
    assert anything(State.of(camera__front={"bins": [0, 0, 0, 0, 0], "total": 0}))


def test_obstacle_within() -> None:
    near = predicate("obstacle_within")
    assert near(State.of(range__front={"range_mm": 250, "status": "ok"}))
    assert not near(State.of(range__front={"range_mm": 251, "status": "ok"}))
    assert near(State.of(range__left={"range_mm": None, "status": "too_close"}))
    assert not near(State.of(range__left={"range_mm": None, "status": "too_far"}))
    assert not near(stale(range__front={"range_mm": 10, "status": "ok"}))
    assert not near(State.of(sonar__front={"range_mm": 10, "status": "ok"}))  # not range/*
    front = predicate("obstacle_within", near_mm=100, sources=["range/front"])
    assert front(State.of(range__front={"range_mm": 90, "status": "ok"}))
    assert not front(State.of(range__left={"range_mm": 10, "status": "ok"}))
    with pytest.raises(ConfigurationError, match=r"\$\.near_mm"):
        predicate("obstacle_within", near_mm=0)


def test_source_fresh() -> None:
    fresh = predicate("source_fresh", source="custom/odometry")
    assert fresh(State.of(custom__odometry={"x": 0}))
    assert not fresh(stale(custom__odometry={"x": 0}))
    assert not fresh(State())
    with pytest.raises(ConfigurationError, match="must not be empty"):
        predicate("source_fresh", source="")
