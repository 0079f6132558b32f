"""A robot file with values replaced at paths (ubf_async.runs.overrides): what may be replaced,
what may be added, and each refusal at its line, naming the path."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from ubf_async.assembly.robotfile import load_robot
from ubf_async.core.arbiters import UtilityFusion
from ubf_async.errors import OverridePathError, RobotFileError
from ubf_async.runs import inprocess
from ubf_async.runs.overrides import load_robot_text_with, load_robot_with, parse_path

ROBOT = Path(__file__).resolve().parent.parent / "ubf_async" / "robots" / "mini-whegs.yaml"


def line_of(text: str) -> int:
    """The line of the shipped robot file that holds ``text``."""
    return ROBOT.read_text().splitlines().index(text) + 1


def test_paths_read_as_the_robot_files_errors_write_them() -> None:
    assert parse_path("tree.children[1].params.period_s") == (
        "tree", "children", 1, "params", "period_s")
    assert parse_path('controller.stale_after_s["camera/front"]') == (
        "controller", "stale_after_s", "camera/front")
    for bad in ("tree..arbiter", "tree/arbiter", "[0].x", "tree.children[x]", ""):
        with pytest.raises(ValueError, match="not a path into a robot file"):
            parse_path(bad)


def test_values_are_replaced_and_the_file_is_not() -> None:
    robot = load_robot_with("mini-whegs", {"tree.arbiter": "UtilityFusion",
                                           "tree.children[0].params.period_s": 6,
                                           "tree.children[1].priority": 3})
    assert isinstance(robot.root.arbiter, UtilityFusion)
    search, chase, _ = robot.root.children
    assert search.behavior.period_ns == 6_000_000_000  # type: ignore[attr-defined]
    assert chase.priority == 3
    assert robot.source == "mini-whegs.yaml"
    plain = load_robot("mini-whegs")
    assert plain.root.arbiter.name == "PriorityMerge"


def test_new_keys_only_where_the_file_could_have_them() -> None:
    # a parameter the factory takes, a field the node's type has but the file leaves out
    robot = load_robot_with("mini-whegs", {"tree.children[0].params.speed": 20,
                                           "tree.children[0].weight": 2.5,
                                           "devices[4].params": {}})
    assert robot.root.children[0].weight == 2.5
    # a whole subtree replaced
    robot = load_robot_with("mini-whegs", {"tree.children[2]": {"behavior": "stop"}})
    assert [c.behavior.name for c in robot.root.children] == ["search", "chase", "stop"]


@pytest.mark.parametrize(("overrides", "line", "message"), [
    ({"tree.children[9].params.period_s": 4}, "    - behavior: search",
     "override tree.children[9].params.period_s: tree.children has 5 item(s), [0] to [4]"),
    ({"tree.children[0].prio": 1}, "    - behavior: search",
     "override tree.children[0].prio: no `prio` in tree.children[0] (a tree node takes: name, "),
    ({"remotes.max_remotes": 3}, "format: 1",
     "override remotes.max_remotes: no `remotes` in the file: give it in the file, or override "
     "remotes as a whole"),
    ({"tree.children[0].params.period_s.x": 1},
     "      params: {source: camera/front, period_s: 4.0, leds: 0}",
     "override tree.children[0].params.period_s.x: tree.children[0].params.period_s is not a "
     "mapping"),
    ({"tree.children[0].params.period_s": -1},
     "      params: {source: camera/front, period_s: 4.0, leds: 0}",
     "with tree.children[0].params.period_s = -1: behaviour 'search': Expected `float` > 0.0 "
     "(at tree.children[0].params.period_s)"),
    ({"tree.children[0].params.nope": 1},
     "      params: {source: camera/front, period_s: 4.0, leds: 0}",
     "with tree.children[0].params.nope = 1: behaviour 'search': Object contains unknown field "
     "`nope`"),
    ({"tree.arbiter": "Nope"}, "  arbiter: PriorityMerge",
     "with tree.arbiter = \"Nope\": unknown arbiter 'Nope'"),
    ({"controller.rate_hz": 0}, "  rate_hz: 50",
     "with controller.rate_hz = 0: Expected `float` > 0.0 (at controller.rate_hz)"),
])
def test_a_refusal_names_the_override_at_the_line_it_replaces(
        overrides: dict[str, object], line: str, message: str) -> None:
    with pytest.raises(RobotFileError) as refused:
        load_robot_with("mini-whegs", overrides)
    # the path itself leads nowhere, whatever the value (a sweep tells it at the path's line)
    assert isinstance(refused.value, OverridePathError) == message.startswith("override ")
    assert refused.value.path == "mini-whegs.yaml"
    assert refused.value.line == line_of(line), str(refused.value)
    assert refused.value.message.startswith(message), str(refused.value)


def test_a_bad_path_is_refused_as_a_path() -> None:
    with pytest.raises(OverridePathError, match=re.escape("override: not a path into a robot "
                                                          "file: 'tree/arbiter'")):
        load_robot_text_with(ROBOT.read_text(), {"tree/arbiter": "UtilityFusion"},
                             source="mini.yaml")


def test_an_overridden_robot_runs_as_its_plan_says() -> None:
    """The loaded robot is what experiment.run takes; a run reseeds it without reading the
    file again, and keeps the overrides."""
    robot = load_robot_with("mini-whegs", {"tree.arbiter": "UtilityFusion"}, seed=3)
    plan = inprocess.plan_run(robot, "ball-in-sight", seed=5, duration_s=1)
    assert isinstance(plan.robot.root.arbiter, UtilityFusion)
