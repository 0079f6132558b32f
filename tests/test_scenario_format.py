"""The scenario format's elements (several scripted objects, follow and wave steps, lighting
over time, pushes) on the real simulated world, and the mistakes it refuses."""

from __future__ import annotations

import copy
import itertools
import math
from pathlib import Path
from typing import Any

import pytest

from components.sim.scenarios.scenario import Expectation, load_scenario, parse_scenario
from components.sim.world.physics import World
from ubf_async.errors import ScenarioError

ARENA = {"x_min_m": -1.5, "y_min_m": -1.5, "x_max_m": 1.5, "y_max_m": 1.5}
PINK = [236, 72, 132]


def base(**extra: Any) -> dict[str, Any]:
    return {"name": "t", "arena": ARENA, "ball": {"x_m": 0.6, "y_m": 0.0}, **extra}


def play(data: dict[str, Any], until_s: float, dt_s: float = 0.005) -> World:
    scenario = parse_scenario(data)
    world = World(scenario.world)
    scenario.install(world)
    while world.time_s < until_s - 1e-9:
        world.advance(dt_s)
    return world


def camera_view(world: World, x_m: float, y_m: float) -> tuple[float, float]:
    r = world.snapshot().robot
    cx, cy = r.x_m + 0.05 * math.cos(r.heading_rad), r.y_m + 0.05 * math.sin(r.heading_rad)
    bearing = math.degrees(math.atan2(y_m - cy, x_m - cx) - r.heading_rad)
    return math.hypot(x_m - cx, y_m - cy), (bearing + 180) % 360 - 180


def test_several_balls_and_a_moving_distractor() -> None:
    """A second pink ball and an orange ball, each named and scripted (which makes them
    movable), move on their own scripts beside the ball's."""
    data = base(
        distractors=[{"kind": "sphere", "name": "ball2", "x_m": 0.5, "y_m": 0.5, "color": PINK},
                     {"kind": "sphere", "name": "orange", "x_m": 1.0, "y_m": -0.5}],
        scripts={"ball2": [{"at_s": 0.5, "move_to": {"x_m": 0.5, "y_m": 0.1},
                            "speed_m_s": 1.0}],
                 "orange": [{"at_s": 0.2, "place": {"x_m": 1.0, "y_m": 0.8}},
                            {"at_s": 1.0, "hide": True}]},
        ball_script=[{"at_s": 0.1, "move_to": {"x_m": 0.8, "y_m": 0.0}}])
    scenario = parse_scenario(data)
    assert [d.movable for d in scenario.world.distractors] == [True, True]
    world = play(data, 0.8)
    ball2, orange = world.snapshot().distractors
    assert (orange.x_m, orange.y_m) == pytest.approx((1.0, 0.8))
    assert 0.1 < ball2.y_m < 0.5  # on its way
    world = play(data, 1.5)
    ball2, orange = world.snapshot().distractors
    assert (ball2.x_m, ball2.y_m) == pytest.approx((0.5, 0.1), abs=1e-6)
    assert orange.x_m > 10  # lifted out of the arena
    assert world.snapshot().ball.x_m == pytest.approx(0.8, abs=1e-6)


def test_follow_keeps_the_ball_where_the_hand_holds_it() -> None:
    data = base(ball_script=[{"at_s": 0, "follow": {"distance_m": 0.3, "bearing_deg": 10},
                              "speed_m_s": 2.0}],
                pushes=[{"at_s": 0.5, "forward_m": -0.2, "left_m": 0.1, "turn_deg": 30,
                         "over_s": 0.5}])
    world = play(data, 1.5)
    ball = world.snapshot().ball
    assert camera_view(world, ball.x_m, ball.y_m) == pytest.approx((0.3, 10.0), abs=1e-3)


def test_wave_sweeps_the_ball_to_and_fro_across_the_view() -> None:
    data = base(ball_script=[{"at_s": 0, "wave": {"distance_m": 0.5, "amplitude_deg": 30,
                                                   "period_s": 0.4}}])
    scenario = parse_scenario(data)
    world = World(scenario.world)
    scenario.install(world)
    bearings = []
    while world.time_s < 0.8:
        world.advance(0.005)
        ball = world.snapshot().ball
        distance, bearing = camera_view(world, ball.x_m, ball.y_m)
        assert distance == pytest.approx(0.5, abs=1e-6)
        bearings.append(bearing)
    assert max(bearings) == pytest.approx(30, abs=0.5)
    assert min(bearings) == pytest.approx(-30, abs=0.5)
    # Out of the 35° view on either side, and across it every half period (0.2, 0.4, 0.6 s).
    sides = [1 if b > 5 else -1 for b in bearings if abs(b) > 5]
    assert sum(1 for a, b in itertools.pairwise(sides) if a != b) == 3


def test_lighting_changes_over_time() -> None:
    data = base(lighting={"brightness": 1.0, "glare": 1.0},
                lighting_script=[{"at_s": 1.0, "brightness": 0.5, "over_s": 1.0},
                                 {"at_s": 3.0, "glare": 0.0}])
    assert play(data, 0.9).snapshot().lighting.brightness == 1.0
    halfway = play(data, 1.5).snapshot().lighting
    assert halfway.brightness == pytest.approx(0.75, abs=0.01) and halfway.glare == 1.0
    end = play(data, 3.1).snapshot().lighting
    assert (end.brightness, end.glare) == pytest.approx((0.5, 0.0))


def test_a_push_moves_the_robot_but_not_its_wheels() -> None:
    """The thesis's caveat: the encoders see the wheels, so a push goes unnoticed."""
    data = base(robot={"x_m": 0, "y_m": 0, "heading_deg": 90},
                pushes=[{"at_s": 0.2, "forward_m": 0.1, "left_m": 0.05, "turn_deg": -45}])
    world = play(data, 1.0)
    r = world.snapshot().robot
    assert (r.x_m, r.y_m) == pytest.approx((-0.05, 0.1), abs=2e-3)
    assert math.degrees(r.heading_rad) == pytest.approx(45, abs=0.5)
    assert (r.left_wheel_angle_rad, r.right_wheel_angle_rad) == (0.0, 0.0)


def test_the_built_in_format_examples_load() -> None:
    for name in ("ball-held-close", "obstacle-course", "busy-room"):
        assert load_scenario(name).name == name


MISTAKES = [
    ({"ball": {"x_m": 2.0, "y_m": 0.0}}, "the ball at \\(2, 0\\) m lies \\(partly\\) outside"),
    ({"ball": {"x_m": 1.49, "y_m": 0.0}}, "the ball .* outside the arena"),
    ({"distractors": [{"kind": "cylinder", "x_m": 0, "y_m": -1.6}]},
     "distractors\\[0\\] \\(cylinder, 'distractor0'\\) .* outside"),
    ({"distractors": [{"kind": "box", "x_m": 1.45, "y_m": 0, "length_m": 0.2}]},
     "distractors\\[0\\] \\(box, 'distractor0'\\) .* outside"),
    ({"obstacles": [{"x_m": -1.5, "y_m": 0, "length_m": 0.2, "width_m": 0.2}]},
     "obstacles\\[0\\] .* outside"),
    ({"robot": {"x_m": 1.47, "y_m": 0}}, "the robot at \\(1.47, 0\\) m does not fit"),
    ({"ball_script": [{"at_s": 1, "move_to": {"x_m": 0, "y_m": 3}}]},
     "ball_script\\[0\\] \\(move_to\\) puts its object at \\(0, 3\\) m, outside"),
    ({"ball": {"x_m": 0.07, "y_m": 0.0}}, "the ball overlaps the robot at its start"),
    ({"distractors": [{"kind": "sphere", "x_m": 0.0, "y_m": 0.0}]},
     "distractors\\[0\\] \\(sphere, 'distractor0'\\) overlaps the robot"),
    ({"obstacles": [{"x_m": 0.1, "y_m": 0.0, "length_m": 0.2, "width_m": 0.2, "yaw_deg": 45}]},
     "obstacles\\[0\\] overlaps the robot"),
    ({"scripts": {"nobody": [{"at_s": 0, "hide": True}]}}, "no distractor is named 'nobody'"),
    ({"walls": [{"x1_m": -0.5, "y1_m": 0.01, "x2_m": 0.5, "y2_m": 0.01}]},
     "walls\\[0\\] from \\(-0.5, 0.01\\) to \\(0.5, 0.01\\) m overlaps the robot"),
    ({"walls": [{"x1_m": 0.0, "y1_m": 0.0, "x2_m": 0.01, "y2_m": 0.0}]},
     "walls\\[0\\] .* overlaps the robot"),  # wholly inside the body
    ({"ball_script": [{"at_s": 0, "place": {"x_m": 0.02, "y_m": 0.0}}]},
     "ball_script\\[0\\] \\(place\\) puts its object at \\(0.02, 0\\) m at the start, "
     "onto the robot"),
    ({"distractors": [{"kind": "sphere", "name": "red", "x_m": 0.5, "y_m": 0.5}],
      "scripts": {"red": [{"at_s": 0, "place": {"x_m": -0.03, "y_m": 0.02}}]}},
     "scripts.red\\[0\\] \\(place\\) puts its object .* onto the robot"),
    ({"ball_script": [{"at_s": 0, "follow": {"distance_m": 0.01}}]},
     "ball_script\\[0\\] \\(follow\\) .* onto the robot"),
    ({"distractors": [{"kind": "sphere", "name": "red", "x_m": 0.5, "y_m": 0.5}],
      "scripts": {"red": [{"at_s": 3, "move_to": {"x_m": 3.0, "y_m": 0.0}}]}},
     "scripts.red\\[0\\] \\(move_to\\) puts its object at \\(3, 0\\) m, outside"),
    ({"distractors": [{"kind": "sphere", "name": "ball", "x_m": 0.5, "y_m": 0.5}]},
     "name must be a unique"),
    ({"ball_script": [{"at_s": 0, "wave": {"period_s": 0}}]},
     r"Expected `float` > 0.0 \(at ball_script\[0\]\.wave\.period_s\)"),
    ({"ball_script": [{"at_s": 0, "follow": {"distance_m": -1}}]},
     r"> 0.0 \(at ball_script\[0\]\.follow\.distance_m\)"),
    ({"lighting_script": [{"at_s": 1}]}, "needs brightness and/or glare"),
    ({"lighting_script": [{"at_s": 1, "brightness": 0}]},
     r"> 0.0 \(at lighting_script\[0\]\.brightness\)"),
    ({"pushes": [{"at_s": 1, "forward_m": 0.1, "over_s": -1}]},
     r">= 0.0 \(at pushes\[0\]\.over_s\)"),
    ({"pushes": [{"at_s": 1, "shove": 1}]}, "unknown field"),
]


@pytest.mark.parametrize(("change", "message"), MISTAKES)
def test_mistakes_are_refused_with_a_clear_error(change: dict[str, Any], message: str) -> None:
    data = copy.deepcopy(base())
    data.update(change)
    with pytest.raises(ScenarioError, match=message):
        parse_scenario(data)


def test_touching_is_not_overlapping() -> None:
    """The ball right in front of the robot's nose (3.5 cm from the camera, contact) loads;
    so does a wall along its side, a ball placed against its nose at the start and one placed
    on the robot's start later (the robot has moved on by then)."""
    parse_scenario(base(ball={"x_m": 0.05 + 0.0326, "y_m": 0.0}))
    parse_scenario(base(walls=[{"x1_m": -0.5, "y1_m": 0.035, "x2_m": 0.5, "y2_m": 0.035}]))
    parse_scenario(base(ball_script=[{"at_s": 0, "place": {"x_m": 0.0827, "y_m": 0.0}}]))
    parse_scenario(base(ball_script=[{"at_s": 5, "place": {"x_m": 0.0, "y_m": 0.0}}]))


def test_expected_outcomes_are_checked_when_the_scenario_loads() -> None:
    from components.sim.scenarios.scenario import parse_scenario

    base = {"name": "x", "ball": {"x_m": 0.6, "y_m": 0.0}}
    scenario = parse_scenario({**base, "expect": {
        "outcome": "settles", "criteria": {"|ball_bearing_deg|": [0, 10]}}})
    assert scenario.expect is not None
    judged = scenario.expect.judge({"ball_bearing_deg": -12.5})
    assert judged["pass"] is False and judged["criteria"][0]["value"] == -12.5
    assert scenario.expect.judge({"ball_bearing_deg": -9})["pass"] is True
    assert scenario.expect.judge({})["pass"] is False  # a number the run did not report
    # Without criteria nothing is checked: the verdict says so rather than "met".
    words_only = Expectation(outcome="finds the ball")
    assert words_only.judge({"ball_bearing_deg": 0})["pass"] is None
    for bad, message in (({"criteria": {}}, "outcome"),
                         ({"outcome": "x", "criteria": {"a": [2, 1]}}, r"\[low, high\]"),
                         ({"outcome": "x", "criteria": {"a": [0, "1"]}}, r"\[low, high\]"),
                         ({"outcome": "x", "when": 1}, "unknown field")):
        with pytest.raises(ScenarioError, match=message):
            parse_scenario({**base, "expect": bad})


# -- scenario files: mistakes at FILE:LINE, as in robot files -----------------------------------

FILE = """{
  "name": "lines",
  "seed": 4,
  "arena": {"x_min_m": -1.5, "y_min_m": -1.5, "x_max_m": 1.5, "y_max_m": 1.5},
  "ball": {"x_m": 0.6, "y_m": 0.0},
  "distractors": [
    {"kind": "sphere", "name": "red", "x_m": 0.5, "y_m": 0.5}
  ],
  "scripts": {
    "red": [
      {"at_s": 1, "move_to": {"x_m": 0.5, "y_m": -0.5}}
    ]
  },
  "ball_script": [
    {"at_s": 2, "relative": {"distance_m": 0.4, "bearing_deg": 20}, "speed_m_s": 0.5}
  ],
  "pushes": [{"at_s": 3, "left_m": 0.1}],
  "expect": {"outcome": "stays", "criteria": {"ball_distance_m": [0.3, 0.6]}}
}
"""


def file_error(tmp_path: Path, old: str, new: str) -> str:
    """The error loading FILE with ``old`` replaced by ``new`` (which must be there)."""
    assert FILE.count(old) == 1, old
    path = tmp_path / "lines.json"
    path.write_text(FILE.replace(old, new), encoding="utf-8")
    with pytest.raises(ScenarioError) as caught:
        load_scenario(str(path))
    return str(caught.value).replace(str(path), "FILE")


def test_the_file_for_the_line_tests_loads(tmp_path: Path) -> None:
    path = tmp_path / "lines.json"
    path.write_text(FILE, encoding="utf-8")
    scenario = load_scenario(str(path))
    assert (scenario.seed, scenario.distractor_names, scenario.source) == (4, ("red",), str(path))
    assert scenario.ball_script[0].target == {"distance_m": 0.4, "bearing_deg": 20.0}
    assert scenario.pushes[0].left_m == 0.1 and scenario.pushes[0].over_s == 0.3


@pytest.mark.parametrize(("old", "new", "expected"), [
    # a misspelt field: its own line, and the fields the object takes
    ('"left_m"', '"left"', "FILE:17: Object contains unknown field `left` (at pushes[0]); a push "
     "takes: at_s, forward_m, left_m, turn_deg, over_s"),
    ('"seed"', '"sead"', "FILE:3: Object contains unknown field `sead`; a scenario takes: name, "
     "title, description, seed, duration_s, robot, ball,"),
    ('"bearing_deg": 20', '"bearing": 20', "FILE:15: Object contains unknown field `bearing` "
     "(at ball_script[0].relative); a place from the camera takes: distance_m, bearing_deg"),
    # wrong types
    ('"seed": 4', '"seed": "4"', "FILE:3: Expected `int`, got `str` (at seed)"),
    ('"seed": 4', '"seed": 4.5', "FILE:3: Expected `int`, got `float` (at seed)"),
    ('"y_m": 0.0}', '"y_m": true}', "FILE:5: Expected `float`, got `bool` (at ball.y_m)"),
    ('"x_m": 0.6', '"x_m": NaN', "FILE:5: Expected `float`, got `str` (at ball.x_m)"),
    ('"kind": "sphere"', '"kind": "cube"', "FILE:7: Invalid enum value 'cube' "
     "(at distractors[0].kind)"),
    ('"red": [\n      {"at_s": 1, "move_to": {"x_m": 0.5, "y_m": -0.5}}\n    ]', '"red": {}',
     "FILE:10: expected an array of steps, got dict (at scripts.red)"),
    # out of range
    ('"speed_m_s": 0.5', '"speed_m_s": 0', "FILE:15: Expected `float` > 0.0 "
     "(at ball_script[0].speed_m_s)"),
    ('"at_s": 1,', '"at_s": -1,', "FILE:11: Expected `float` >= 0.0 (at scripts.red[0].at_s)"),
    ('"x_m": 0.6', '"x_m": 1e400', "FILE:5: Expected `float` <= 1000.0 (at ball.x_m)"),
    ('"name": "red",', '"name": "red", "color": [0, 0, 256],', "FILE:7: Expected `int` <= 255 "
     "(at distractors[0].color[2])"),
    # what spans fields, at the line of the field concerned
    ('"red": [', '"blue": [', "FILE:10: no distractor is named 'blue' (named: ['red']; the "
     "ball's script is ball_script) (at scripts.blue)"),
    ('"x_m": 0.5, "y_m": -0.5', '"x_m": 2.5, "y_m": -0.5', "FILE:11: scripts.red[0] (move_to) "
     "puts its object at (2.5, -0.5) m, outside the arena (x -1.5…1.5 m, y -1.5…1.5 m) "
     "(at scripts.red[0])"),
    ('"name": "red"', '"name": "ball"', "FILE:7: name must be a unique non-empty string other "
     "than 'ball'"),
    ('[0.3, 0.6]', '[0.6, 0.3]', "FILE:18: expected a summary field and [low, high] with finite "
     "low <= high, got [0.6, 0.3] (at expect.criteria.ball_distance_m)"),
    ('"x_max_m": 1.5', '"x_max_m": -2', "FILE:4: an arena needs x_min_m < x_max_m and y_min_m < "
     "y_max_m (at arena)"),
    # the file itself
    ('"seed": 4,', '"seed": 4, "seed": 5,', "FILE:3: duplicate key `seed` (also on line 3): a key "
     "may appear once in an object"),
    ('{"outcome": "stays"', '{"outcome": "stays", "outcome": "moves"', "FILE:18: duplicate key "
     "`outcome` (also on line 18)"),
    # (the JSON reader notices a missing comma at the next token)
    ('"seed": 4,', '"seed": 4', "FILE:4: not valid JSON: Expecting ',' delimiter (column 3)"),
])
def test_a_scenario_file_mistake_is_reported_at_its_line(tmp_path: Path, old: str, new: str,
                                                         expected: str) -> None:
    assert file_error(tmp_path, old, new).startswith(expected)


def test_a_duplicate_key_a_line_apart_names_both_lines(tmp_path: Path) -> None:
    message = file_error(tmp_path, '"ball": {"x_m": 0.6, "y_m": 0.0},',
                         '"ball": {"x_m": 0.6, "y_m": 0.0},\n  "ball": {"x_m": 0.7, "y_m": 0.0},')
    assert message.startswith("FILE:6: duplicate key `ball` (also on line 5)")


def test_data_without_a_file_names_the_path_but_no_line() -> None:
    with pytest.raises(ScenarioError) as caught:
        parse_scenario(base(pushes=[{"at_s": 1, "shove": 1}]), source="mine")
    assert str(caught.value).startswith("mine: Object contains unknown field `shove` "
                                        "(at pushes[0]); a push takes: at_s,")
