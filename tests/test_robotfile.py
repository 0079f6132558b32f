"""Robot files: typed decoding, every mistake refused at load time with its file and line,
round trips, the JSON Schema kept current, and the shipped default."""

from __future__ import annotations

import json
import textwrap
from pathlib import Path

import jsonschema
import msgspec
import pytest
import yaml

from ubf_async.assembly.registry import ARBITERS
from ubf_async.assembly.robotfile import (
    DEFAULT_ROBOT_FILE,
    RobotFile,
    decode_robot_file,
    first_duplicate_key,
    load_robot,
    load_robot_text,
    load_tree_fragment,
    parse_error_path,
    read_robot_file,
    robot_file_schema,
    schema_text,
    shipped_schema_text,
)
from ubf_async.behaviors.pink_ball import Chase, Flee, Search
from ubf_async.core.arbiters import (
    CommandFusion,
    Conditional,
    HighestActivation,
    HighestPriority,
    MonteCarlo,
    PriorityFusion,
    PriorityMerge,
    UtilityFusion,
)
from ubf_async.core.behavior import Composite
from ubf_async.errors import ConfigurationError, RobotFileError, UbfError

TREE_ONLY = """\
name: tester
tree:
  name: root
  arbiter: PriorityMerge
  children:
    - behavior: search
      priority: 2
      params: {period_s: 4.0}
    - behavior: chase
      priority: 1
    - behavior: flee
      priority: 1
"""


def line_of(text: str, needle: str, occurrence: int = 1) -> int:
    """1-based line of the ``occurrence``-th line containing ``needle``."""
    seen = 0
    for number, line in enumerate(text.splitlines(), start=1):
        if needle in line:
            seen += 1
            if seen == occurrence:
                return number
    raise AssertionError(f"{needle!r} not in text")


def refused(text: str, *, source: str = "robot.yaml") -> RobotFileError:
    with pytest.raises(RobotFileError) as info:
        load_robot_text(text, source=source)
    return info.value


# -- the happy path ---------------------------------------------------------------------------


def test_tree_is_built_from_registered_names_with_parameters() -> None:
    robot = load_robot_text(TREE_ONLY, source="t.yaml", seed=7)
    root = robot.root
    assert isinstance(root, Composite) and root.name == "root"
    assert isinstance(root.arbiter, PriorityMerge)
    kinds = [(type(c.behavior), c.behavior.name, c.priority, c.weight) for c in root.children]
    assert kinds == [(Search, "search", 2, 1.0), (Chase, "chase", 1, 1.0),
                     (Flee, "flee", 1, 1.0)]
    search = root.children[0].behavior
    assert isinstance(search, Search) and search.period_ns == 4_000_000_000


def test_thesis_numbers_are_defaults_not_constants() -> None:
    text = TREE_ONLY.replace("    - behavior: chase\n      priority: 1\n",
                             "    - behavior: chase\n      priority: 1\n"
                             "      params: {speed: 25, min_pixels: 10}\n")
    chase = load_robot_text(text).root.children[1].behavior
    assert isinstance(chase, Chase) and (chase.speed, chase.min_pixels) == (25.0, 10)
    flee = load_robot_text(TREE_ONLY).root.children[2].behavior
    assert isinstance(flee, Flee) and flee.start_pixels == 100  # the thesis's default


def test_search_draws_from_the_seed_so_runs_repeat() -> None:
    a = load_robot_text(TREE_ONLY, seed=11).root.children[0].behavior
    b = load_robot_text(TREE_ONLY, seed=11).root.children[0].behavior
    assert isinstance(a, Search) and isinstance(b, Search)
    assert [a.rng.random() for _ in range(5)] == [b.rng.random() for _ in range(5)]


ARBITER_CASES = [
    ("HighestActivation", {}, HighestActivation),
    ("HighestPriority", {}, HighestPriority),
    ("PriorityMerge", {}, PriorityMerge),
    ("PriorityFusion", {}, PriorityFusion),
    ("UtilityFusion", {}, UtilityFusion),
    ("CommandFusion", {}, CommandFusion),
    ("MonteCarlo", {"seed": 3, "hold_ticks": 5}, MonteCarlo),
]


@pytest.mark.parametrize(("name", "params", "cls"), ARBITER_CASES)
def test_every_arbiter_by_name_with_parameters(name: str, params: dict[str, object],
                                                cls: type) -> None:
    arbiter = {"type": name, "params": params} if params else name
    text = TREE_ONLY.replace("arbiter: PriorityMerge", f"arbiter: {json.dumps(arbiter)}")
    root = load_robot_text(text).root
    assert type(root.arbiter) is cls
    for key, value in params.items():
        if key != "seed":
            assert getattr(root.arbiter, key) == value


def test_conditional_by_name_with_a_registered_predicate() -> None:
    text = """\
name: t
tree:
  name: root
  arbiter: {type: Conditional, params: {predicate: sees_color, predicate_params: {min_pixels: 5}}}
  children:
    - behavior: chase
    - behavior: search
"""
    root = load_robot_text(text).root
    assert isinstance(root.arbiter, Conditional)


def test_all_eight_arbiters_are_registered() -> None:
    assert set(ARBITERS.names()) >= {c[0] for c in ARBITER_CASES} | {"Conditional"}


def test_user_behaviour_by_module_factory_reference() -> None:
    text = TREE_ONLY.replace("behavior: flee", "behavior: tests.plugin_behaviors:Spin\n"
                                                "      params: {turn: 45}")
    spin = load_robot_text(text).root.children[2].behavior
    assert type(spin).__name__ == "Spin" and spin.name == "Spin"
    assert spin.turn == 45.0  # type: ignore[attr-defined]


def test_remote_slots_are_declared_in_the_tree() -> None:
    text = TREE_ONLY + "    - remote: teleop\n      priority: 10\n      weight: 2\n"
    robot = load_robot_text(text)
    assert [c.behavior.name for c in robot.root.children] == ["search", "chase", "flee"]
    assert robot.remote_config() == {"root/teleop": (10, 2.0)}


def test_nested_composites() -> None:
    text = """\
name: t
tree:
  name: root
  arbiter: HighestPriority
  children:
    - name: seek
      arbiter: PriorityMerge
      priority: 1
      children:
        - behavior: chase
        - behavior: flee
    - behavior: stop
      priority: 0
"""
    root = load_robot_text(text).root
    seek = root.find("seek")
    assert isinstance(seek, Composite) and len(seek.children) == 2


def test_round_trip_keeps_every_field() -> None:
    text, source = read_robot_file(DEFAULT_ROBOT_FILE)
    spec, _ = decode_robot_file(text, source=source)
    again = msgspec.yaml.decode(msgspec.yaml.encode(spec), type=RobotFile)
    assert again == spec
    for name, params, _cls in ARBITER_CASES:
        arbiter = {"type": name, "params": params}
        one = msgspec.yaml.decode(TREE_ONLY.replace("arbiter: PriorityMerge",
                                                    f"arbiter: {json.dumps(arbiter)}"),
                                  type=RobotFile)
        assert msgspec.yaml.decode(msgspec.yaml.encode(one), type=RobotFile) == one


def test_shipped_default_robot_file_loads() -> None:
    robot = load_robot()
    assert robot.name == "mini"
    assert {(d.kind, d.name) for d in robot.devices} == {
        ("motors", "main"), ("encoders", "wheels"), ("camera", "front"), ("range", "front"),
        ("radio", "link"), ("leds", "panel")}
    assert robot.simulators() == ["mini-whegs"]
    assert [c.behavior.name for c in robot.root.children] == ["search", "chase", "flee"]


# -- every mistake: refused at load time, with file and line ---------------------------------


def test_unknown_behaviour_names_the_known_ones_and_the_line() -> None:
    text = TREE_ONLY.replace("behavior: chase", "behavior: chsae")
    error = refused(text)
    assert error.path == "robot.yaml" and error.line == line_of(text, "chsae")
    assert "unknown behaviour 'chsae'" in str(error)
    assert "chase" in str(error) and "search" in str(error)
    assert str(error).startswith(f"robot.yaml:{error.line}: ")


def test_unknown_arbiter() -> None:
    text = TREE_ONLY.replace("arbiter: PriorityMerge", "arbiter: PriorityMerj")
    error = refused(text)
    assert error.line == line_of(text, "PriorityMerj")
    assert "unknown arbiter 'PriorityMerj'" in str(error) and "MonteCarlo" in str(error)


DEVICE = """\
devices:
  - kind: motors
    name: main
    backend: sim
"""


def test_unknown_device_kind() -> None:
    text = TREE_ONLY + DEVICE.replace("kind: motors", "kind: motorz")
    error = refused(text)
    assert error.line == line_of(text, "motorz")
    assert "unknown device kind 'motorz'" in str(error) and "camera" in str(error)


def test_unknown_backend_lists_the_kinds_backends() -> None:
    text = TREE_ONLY + DEVICE.replace("backend: sim", "backend: gpio9")
    error = refused(text)
    assert error.line == line_of(text, "gpio9")
    assert "unknown backend 'motors.gpio9'" in str(error) and "sim" in str(error)


def test_wrong_type_names_the_expected_type() -> None:
    text = TREE_ONLY.replace("priority: 2", "priority: high")
    error = refused(text)
    assert error.line == line_of(text, "priority: high")
    assert "Expected `int`, got `str`" in str(error)
    assert "tree.children[0].priority" in str(error)


def test_wrong_parameter_type_of_a_behaviour() -> None:
    text = TREE_ONLY.replace("period_s: 4.0", "period_s: soon")
    error = refused(text)
    assert error.line == line_of(text, "period_s: soon")
    assert "Expected `float`, got `str`" in str(error) and "period_s" in str(error)


def test_wrong_parameter_type_of_a_device() -> None:
    text = TREE_ONLY + DEVICE + "    params: {timeout_s: forever}\n"
    error = refused(text)
    assert error.line == line_of(text, "timeout_s: forever")
    assert "timeout_s" in str(error) and "Expected" in str(error)


@pytest.mark.parametrize(("old", "new", "expected"), [
    ("priority: 2", "priority: 2000000", "<= 1000000"),
    ("priority: 2", "priority: -2000000", ">= -1000000"),
    ("priority: 2", "priority: 2\n      weight: -1", ">= 0.0"),
    ("priority: 2", "priority: 2\n      weight: .inf", "<= 1000000.0"),
])
def test_out_of_range_priority_and_weight(old: str, new: str, expected: str) -> None:
    text = TREE_ONLY.replace(old, new)
    error = refused(text)
    assert expected in str(error)
    assert error.line in (line_of(text, new.splitlines()[-1].strip()),)


def test_duplicate_child_names() -> None:
    text = TREE_ONLY.replace("behavior: flee", "behavior: chase")
    error = refused(text)
    assert error.line == line_of(text, "behavior: chase", occurrence=2)
    assert "duplicate child name 'chase'" in str(error) and "`name`" in str(error)


def test_duplicate_child_names_between_a_behaviour_and_a_remote_slot() -> None:
    text = TREE_ONLY + "    - remote: flee\n"
    error = refused(text)
    assert error.line == line_of(text, "remote: flee")
    assert "duplicate child name 'flee'" in str(error)


def test_duplicate_devices() -> None:
    text = TREE_ONLY + DEVICE + DEVICE.removeprefix("devices:\n")
    error = refused(text)
    assert error.line == line_of(text, "kind: motors", occurrence=2)
    assert "duplicate device motors/main" in str(error)


@pytest.mark.parametrize("children", [1, 3])
def test_conditional_without_two_children(children: int) -> None:
    kids = "".join(f"    - behavior: drive\n      name: d{i}\n" for i in range(children))
    text = textwrap.dedent("""\
        name: t
        tree:
          name: root
          arbiter: {type: Conditional, params: {predicate: sees_color}}
          children:
        """) + kids
    error = refused(text)
    assert error.line == line_of(text, "name: root")
    assert "two children" in str(error) or "2 children" in str(error)


def test_missing_required_parameter() -> None:
    text = TREE_ONLY.replace("arbiter: PriorityMerge", "arbiter: Conditional")
    error = refused(text)
    assert error.line == line_of(text, "arbiter: Conditional")
    assert "missing required field `predicate`" in str(error)


def test_unknown_parameter_lists_the_accepted_ones() -> None:
    text = TREE_ONLY.replace("period_s: 4.0", "perod_s: 4.0")
    error = refused(text)
    assert error.line == line_of(text, "perod_s")
    assert "unknown field `perod_s`" in str(error) and "period_s" in str(error)


def test_unknown_key_in_the_file() -> None:
    text = TREE_ONLY.replace("name: tester", "name: tester\nspeeed: 3")
    error = refused(text)
    assert error.line == line_of(text, "speeed")
    assert "unknown field `speeed`" in str(error)


def test_node_with_neither_behaviour_nor_arbiter() -> None:
    text = TREE_ONLY.replace("    - behavior: chase\n", "    - name: chase\n")
    error = refused(text)
    assert error.line == line_of(text, "- name: chase")
    assert "exactly one of `behavior`" in str(error)


def test_a_behaviour_factory_returning_something_else() -> None:
    text = TREE_ONLY.replace("behavior: flee", "behavior: tests.plugin_behaviors:not_a_behavior")
    error = refused(text)
    assert "not a ubf_async.core.behavior.Behavior" in str(error)


def test_invalid_yaml_says_where() -> None:
    text = TREE_ONLY + "  oops: [\n"
    error = refused(text)
    assert "not valid YAML" in str(error) and error.line == line_of(text, "oops: [")


# Each mistake, and the line it is on (the parser notices some of them a line or more later).
SYNTAX_ERRORS = {
    "a key without its colon": ("      priority: 2\n", "      priority 2\n", "priority 2"),
    "an unclosed brace": ("{period_s: 4.0}", "{period_s: 4.0", "{period_s: 4.0"),
    "an unclosed quote": ("behavior: chase", 'behavior: "chase', '"chase'),
    "an indentation that breaks a list": ("      priority: 2\n", "     priority: 2\n",
                                          "     priority: 2"),
    "a tab": ("      priority: 2\n", "\tpriority: 2\n", "\tpriority"),
}


@pytest.mark.parametrize("case", sorted(SYNTAX_ERRORS))
def test_a_yaml_syntax_error_points_at_its_own_line(case: str) -> None:
    old, new, needle = SYNTAX_ERRORS[case]
    text = TREE_ONLY.replace(old, new)
    error = refused(text)
    assert error.message.startswith("not valid YAML: "), error
    assert error.line == line_of(text, needle), error


def test_a_key_given_twice_is_refused_at_its_second_line() -> None:
    text = TREE_ONLY.replace("      priority: 2\n", "      priority: 2\n      priority: 7\n")
    error = refused(text)
    assert error.line == line_of(text, "priority: 7")
    assert str(error).startswith(f"robot.yaml:{error.line}: duplicate key `priority` (also on "
                                 f"line {line_of(text, 'priority: 2')})")


@pytest.mark.parametrize(("old", "new", "key"), [
    ("name: tester\n", "name: tester\nname: other\n", "name"),               # the file's
    ("{period_s: 4.0}", "{period_s: 4.0, period_s: 5}", "period_s"),           # a flow mapping
    ("    - behavior: chase\n", "    - behavior: chase\n      behavior: flee\n", "behavior"),
])
def test_duplicate_keys_are_refused_everywhere(old: str, new: str, key: str) -> None:
    text = TREE_ONLY.replace(old, new)
    error = refused(text)
    assert f"duplicate key `{key}`" in str(error)
    assert error.line == line_of(text, new.splitlines()[-1].strip().removeprefix("- "))


def test_duplicates_are_told_from_merge_keys_and_from_other_types() -> None:
    root = yaml.compose("base: &b {a: 1}\nm: {<<: *b, a: 2}\nn: {1: x, '1': y}\n")
    assert first_duplicate_key(root) is None  # `a` overrides the merged one; 1 is not '1'


def test_a_tree_fragment_with_a_duplicate_key_is_refused() -> None:
    with pytest.raises(RobotFileError, match=r"frag.yaml:3: duplicate key `arbiter`"):
        load_tree_fragment("name: root\narbiter: PriorityMerge\narbiter: HighestPriority\n"
                           "children: [{behavior: stop}]\n", source="frag.yaml")


@pytest.mark.parametrize(("old", "new", "misspelt", "what", "field"), [
    ("priority: 2", "priorty: 2", "priorty", "a tree node takes: ", "priority"),
    ("name: tester", "name: tester\nspeeed: 3", "speeed", "a robot file takes: ", "seed"),
    ("arbiter: PriorityMerge", "arbiter: {type: MonteCarlo, prams: {seed: 3}}", "prams",
     "an arbiter takes: ", "params"),
    ("name: tester", "name: tester\ncontroller: {rate: 20}", "rate", "`controller` takes: ",
     "rate_hz"),
])
def test_a_misspelt_field_lists_the_valid_ones(old: str, new: str, misspelt: str, what: str,
                                               field: str) -> None:
    text = TREE_ONLY.replace(old, new)
    error = refused(text)
    assert error.line == line_of(text, misspelt)
    assert f"unknown field `{misspelt}`" in str(error)
    listed = str(error).split(what, 1)[1].split(", ")
    assert field in listed, str(error)


def test_a_factory_names_its_behaviour_unless_the_file_does() -> None:
    text = TREE_ONLY.replace("behavior: flee", "behavior: tests.plugin_behaviors:SpinWhenClose")
    children = load_robot_text(text).root.children
    assert [c.behavior.name for c in children] == ["search", "chase", "spin_when_close"]
    named = text.replace(":SpinWhenClose", ":SpinWhenClose\n      name: spinner")
    assert load_robot_text(named).root.children[2].behavior.name == "spinner"
    # A factory that takes no name gets the file's all the same...
    spin = text.replace(":SpinWhenClose", ":Spin\n      name: spinner")
    assert load_robot_text(spin).root.children[2].behavior.name == "spinner"
    # ...and one that requires a name, without one in the file, the name it is referenced by.
    needs = text.replace(":SpinWhenClose", ":needs_a_name")
    assert load_robot_text(needs).root.children[2].behavior.name == "needs_a_name"


def test_missing_file_and_unknown_shipped_name(tmp_path: Path) -> None:
    with pytest.raises(RobotFileError, match="no such file"):
        load_robot(tmp_path / "nope.yaml")
    with pytest.raises(RobotFileError, match="mini-whegs"):
        load_robot("not-a-shipped-robot")


def test_errors_share_one_root() -> None:
    assert issubclass(RobotFileError, ConfigurationError)
    assert issubclass(ConfigurationError, UbfError)
    error = refused(TREE_ONLY.replace("behavior: chase", "behavior: nope"))
    assert isinstance(error, UbfError) and isinstance(error, ValueError)


def test_error_paths_parse() -> None:
    assert parse_error_path("$.tree.children[1].priority") == ("tree", "children", 1, "priority")
    assert parse_error_path("$") == ()


# -- fragments (live tree changes) ------------------------------------------------------------


def test_tree_fragment_with_or_without_the_tree_key() -> None:
    body = TREE_ONLY.split("tree:\n", 1)[1]
    bare = textwrap.dedent(body)
    root, slots = load_tree_fragment(bare)
    assert root.name == "root" and not slots
    root2, _ = load_tree_fragment("tree:\n" + body)
    assert [c.behavior.name for c in root2.children] == ["search", "chase", "flee"]
    with pytest.raises(RobotFileError, match="unknown behaviour"):
        load_tree_fragment(bare.replace("chase", "chaes"), source="frag.yaml")


# -- the JSON Schema --------------------------------------------------------------------------


def test_shipped_json_schema_is_current() -> None:
    # Compared as data: msgspec.Meta(gt=0) == Meta(gt=0.0), so typing's cache may hand back
    # either spelling depending on which module built its Annotated type first.
    assert json.loads(shipped_schema_text()) == json.loads(schema_text()), (
        "regenerate with: python -m ubf_async.robotfile schema --write "
        "ubf_async/robot-file.schema.json")


def test_json_schema_accepts_the_shipped_file_and_refuses_mistakes() -> None:
    schema = robot_file_schema()
    text, _ = read_robot_file(DEFAULT_ROBOT_FILE)
    data = msgspec.yaml.decode(text)
    validator = jsonschema.Draft202012Validator(schema)
    assert list(validator.iter_errors(data)) == []
    data["tree"]["children"][0]["priority"] = "high"
    assert list(validator.iter_errors(data))



LOAD_TIME_TYPE_ERRORS = {
    # case: (the tree's arbiter and children, the line the refusal points at, what it says)
    "a behaviour reading a source of the wrong kind": (
        " PriorityMerge\n  children:\n    - behavior: chase\n"
        "      params: {source: range/front}\n",
        "params:", "behaviour 'chase': Chase 'chase': 'range/front' is a range source; its "
        "samples have no field 'bins'"),
    "a predicate reading a source of the wrong kind": (
        "\n    type: Conditional\n    params:\n      predicate: sees_color\n"
        "      predicate_params: {source: range/front}\n"
        "  children:\n    - behavior: chase\n    - behavior: search\n",
        "predicate:", "arbiter 'Conditional': predicate 'sees_color': sees_color: "
        "'range/front' is a range source; its samples have no field 'bins'"),
    "a predicate's parameter of the wrong type": (
        "\n    type: Conditional\n    params:\n      predicate: obstacle_within\n"
        "      predicate_params: {near_mm: near}\n"
        "  children:\n    - behavior: chase\n    - behavior: search\n",
        "predicate:", "arbiter 'Conditional': predicate 'obstacle_within': Expected `int`, "
        "got `str` (at $.near_mm)"),
}


@pytest.mark.parametrize("case", sorted(LOAD_TIME_TYPE_ERRORS))
def test_a_type_error_of_the_tree_is_refused_at_load_at_its_line(case: str) -> None:
    """Issue 51, item 3: a behaviour or a predicate given a source of the wrong kind, or a
    parameter of the wrong type, is refused when the file loads (launch --check), at the
    line of its parameters — not when it ticks."""
    tree, at, said = LOAD_TIME_TYPE_ERRORS[case]
    text = f"format: 1\nname: wrong\ndevices: []\ntree:\n  name: root\n  arbiter:{tree}"
    assert str(refused(text)).startswith(f"robot.yaml:{line_of(text, at)}: {said}")
