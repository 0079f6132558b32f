"""Scenarios as data: a world, a robot start, a scripted ball and a seed, in a JSON file.

The format is documented in ``docs/scenarios.md``. The thesis's four experiments (§4.2) ship
as built-ins in ``scenario_files/``; :func:`load_scenario` takes a built-in name or a path.

The ball script moves the ball like the experimenter's hand did: each step starts at
``at_s`` (simulated seconds) and is one of

* ``place``      — teleport to ``{"x_m", "y_m"}``;
* ``move_to``    — walk to ``{"x_m", "y_m"}`` at ``speed_m_s``;
* ``relative``   — walk to ``{"distance_m", "bearing_deg"}`` measured from the robot's camera
  at the moment the step starts (``bearing_deg`` positive to the robot's left);
* ``out_of_view``— walk to ``"left"`` or ``"right"`` of the robot, ``bearing_deg`` (default
  70°) off its heading at ``distance_m`` (default 0.7 m), i.e. across and out of the 35° view;
* ``hide``       — lift the ball out of the arena (nothing can see it); the next step puts
  it straight down at its target instead of walking it there;
a step of a moving ball ends when it arrives (or when the next step starts).
"""

from __future__ import annotations

import json
import math
import warnings
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

from components.sim.world import (
    Arena,
    BallConfig,
    BoxObstacle,
    Distractor,
    Lighting,
    Pose2D,
    Wall,
    World,
    WorldConfig,
)
from ubf_async.errors import ScenarioError

__all__ = ["BallScript", "BallStep", "Scenario", "ScenarioError", "builtin_names",
           "load_scenario", "parse_scenario"]

CAMERA_OFFSET_M = 0.05
"""The camera sits this far ahead of the robot's centre (see camera_render.CameraParams)."""
HIDDEN_AT = (50.0, 50.0)
"""Where a hidden ball waits: far outside any arena, behind its walls."""
BUILTIN_DIR = "scenario_files"


@dataclass(frozen=True, slots=True, kw_only=True)
class BallStep:
    at_s: float
    kind: str
    target: dict[str, float] = field(default_factory=dict)
    speed_m_s: float = 0.3


@dataclass(frozen=True, slots=True, kw_only=True)
class Scenario:
    name: str
    title: str
    description: str
    world: WorldConfig
    ball_script: tuple[BallStep, ...]
    duration_s: float
    seed: int
    source: str

    def install(self, world: World) -> None:
        """Attach the ball script to ``world`` (a step hook)."""
        if self.ball_script:
            world.add_step_hook(BallScript(self.ball_script))


class BallScript:
    """Step hook that plays a ball script on the simulation clock."""

    def __init__(self, steps: tuple[BallStep, ...]) -> None:
        self.steps = sorted(steps, key=lambda s: s.at_s)
        self.next_index = 0
        self.target: tuple[float, float] | None = None
        self.speed_m_s = 0.0

    def __call__(self, world: World, dt_s: float) -> None:
        now = world.time_s
        while self.next_index < len(self.steps) and self.steps[self.next_index].at_s <= now:
            self._begin(world, self.steps[self.next_index])
            self.next_index += 1
        if self.target is None:
            return
        ball = world.snapshot().ball
        if ball is None:
            return
        dx, dy = self.target[0] - ball.x_m, self.target[1] - ball.y_m
        remaining = math.hypot(dx, dy)
        stride = self.speed_m_s * dt_s
        if remaining <= stride:
            world.place_ball(*self.target)
            self.target = None
        else:
            world.place_ball(ball.x_m + dx / remaining * stride, ball.y_m + dy / remaining * stride)

    def _begin(self, world: World, step: BallStep) -> None:
        if step.kind == "place":
            self.target = None
            world.place_ball(step.target["x_m"], step.target["y_m"])
            return
        if step.kind == "hide":
            self.target = None
            world.place_ball(*HIDDEN_AT)
            return
        snap = world.snapshot()
        hidden = snap.ball is not None and (snap.ball.x_m, snap.ball.y_m) == HIDDEN_AT
        robot = snap.robot
        cam_x = robot.x_m + CAMERA_OFFSET_M * math.cos(robot.heading_rad)
        cam_y = robot.y_m + CAMERA_OFFSET_M * math.sin(robot.heading_rad)
        if step.kind == "move_to":
            target = (step.target["x_m"], step.target["y_m"])
        else:  # relative and out_of_view: from the camera, at the moment the step starts
            bearing = robot.heading_rad + math.radians(step.target["bearing_deg"])
            distance = step.target["distance_m"]
            target = (cam_x + distance * math.cos(bearing), cam_y + distance * math.sin(bearing))
        if hidden:  # a lifted ball is put straight down where it is meant to go
            self.target = None
            world.place_ball(*target)
            return
        self.target = target
        self.speed_m_s = step.speed_m_s


# ---------------------------------------------------------------------------------------------
# Parsing

_TOP_LEVEL = {"name", "title", "description", "seed", "duration_s", "robot", "ball", "arena",
              "walls", "obstacles", "distractors", "lighting", "ball_script"}
_DEPRECATED = {"search_period_s"}
"""Fields old scenario files may still have: read (and checked), warned about, not used."""


def _number(data: dict[str, Any], key: str, where: str, default: float | None = None) -> float:
    value = data.get(key, default)
    if value is None:
        raise ScenarioError(f"{where}: missing {key!r}")
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ScenarioError(f"{where}.{key}: expected a finite number, got {value!r}")
    return float(value)


def _color(value: Any, where: str) -> tuple[int, int, int]:
    if (not isinstance(value, list) or len(value) != 3
            or any(isinstance(c, bool) or not isinstance(c, int) or not 0 <= c <= 255
                   for c in value)):
        raise ScenarioError(f"{where}: expected [R, G, B] with ints 0..255, got {value!r}")
    return (value[0], value[1], value[2])


def _check_keys(data: Any, allowed: set[str], where: str) -> dict[str, Any]:
    if not isinstance(data, dict):
        raise ScenarioError(f"{where}: expected an object, got {type(data).__name__}")
    unknown = sorted(set(data) - allowed)
    if unknown:
        raise ScenarioError(f"{where}: unknown field(s) {unknown}; allowed: {sorted(allowed)}")
    return data


def _ball_step(data: Any, where: str) -> BallStep:
    kinds = ("place", "move_to", "relative", "out_of_view", "hide")
    data = _check_keys(data, {"at_s", "speed_m_s", *kinds}, where)
    present = [k for k in kinds if k in data]
    if len(present) != 1:
        raise ScenarioError(f"{where}: needs exactly one of {list(kinds)}, got {present}")
    kind = present[0]
    at_s = _number(data, "at_s", where)
    speed = _number(data, "speed_m_s", where, 0.3)
    if speed <= 0:
        raise ScenarioError(f"{where}.speed_m_s must be > 0")
    body = data[kind]
    if kind in ("place", "move_to"):
        body = _check_keys(body, {"x_m", "y_m"}, f"{where}.{kind}")
        target = {"x_m": _number(body, "x_m", f"{where}.{kind}"),
                  "y_m": _number(body, "y_m", f"{where}.{kind}")}
    elif kind == "relative":
        body = _check_keys(body, {"distance_m", "bearing_deg"}, f"{where}.relative")
        target = {"distance_m": _number(body, "distance_m", f"{where}.relative"),
                  "bearing_deg": _number(body, "bearing_deg", f"{where}.relative", 0.0)}
    elif kind == "out_of_view":
        if isinstance(body, str):
            body = {"side": body}
        body = _check_keys(body, {"side", "bearing_deg", "distance_m"}, f"{where}.out_of_view")
        side = body.get("side")
        if side not in ("left", "right"):
            raise ScenarioError(f"{where}.out_of_view.side must be 'left' or 'right'")
        bearing = abs(_number(body, "bearing_deg", f"{where}.out_of_view", 70.0))
        target = {"distance_m": _number(body, "distance_m", f"{where}.out_of_view", 0.7),
                  "bearing_deg": bearing if side == "left" else -bearing}
        kind = "relative"
    else:  # hide
        if body is not True:
            raise ScenarioError(f"{where}.hide must be true")
        target = {}
    return BallStep(at_s=at_s, kind=kind, target=target, speed_m_s=speed)


def parse_scenario(data: Any, *, source: str = "<data>") -> Scenario:
    """Validate a decoded scenario document and build the :class:`Scenario`."""
    data = _check_keys(data, _TOP_LEVEL | _DEPRECATED, "scenario")
    name = data.get("name")
    if not isinstance(name, str) or not name:
        raise ScenarioError("scenario: 'name' must be a non-empty string")
    seed = data.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int):
        raise ScenarioError("scenario.seed must be an int")
    robot = _check_keys(data.get("robot", {}), {"x_m", "y_m", "heading_deg"}, "robot")
    start = Pose2D(
        x_m=_number(robot, "x_m", "robot", 0.0), y_m=_number(robot, "y_m", "robot", 0.0),
        heading_rad=math.radians(_number(robot, "heading_deg", "robot", 0.0)),
    )
    ball_data = data.get("ball")
    ball = None
    if ball_data is not None:
        ball_data = _check_keys(ball_data, {"x_m", "y_m"}, "ball")
        ball = BallConfig(x_m=_number(ball_data, "x_m", "ball"),
                          y_m=_number(ball_data, "y_m", "ball"))
    arena = None
    if data.get("arena") is not None:
        a = _check_keys(data["arena"], {"x_min_m", "y_min_m", "x_max_m", "y_max_m"}, "arena")
        arena = Arena(**{k: _number(a, k, "arena")
                         for k in ("x_min_m", "y_min_m", "x_max_m", "y_max_m")})
    walls = []
    for i, w in enumerate(data.get("walls", [])):
        w = _check_keys(w, {"x1_m", "y1_m", "x2_m", "y2_m"}, f"walls[{i}]")
        walls.append(Wall(**{k: _number(w, k, f"walls[{i}]")
                             for k in ("x1_m", "y1_m", "x2_m", "y2_m")}))
    boxes = []
    for i, b in enumerate(data.get("obstacles", [])):
        where = f"obstacles[{i}]"
        b = _check_keys(b, {"x_m", "y_m", "length_m", "width_m", "yaw_deg"}, where)
        boxes.append(BoxObstacle(x_m=_number(b, "x_m", where), y_m=_number(b, "y_m", where),
                                 length_m=_number(b, "length_m", where),
                                 width_m=_number(b, "width_m", where),
                                 yaw_rad=math.radians(_number(b, "yaw_deg", where, 0.0))))
    distractors = []
    for i, d in enumerate(data.get("distractors", [])):
        where = f"distractors[{i}]"
        d = _check_keys(d, {"kind", "x_m", "y_m", "color", "radius_m"}, where)
        kind = d.get("kind", "sphere")
        if kind not in ("sphere", "cylinder", "box"):
            raise ScenarioError(f"{where}.kind must be sphere, cylinder or box")
        distractors.append(Distractor(
            kind=kind, x_m=_number(d, "x_m", where), y_m=_number(d, "y_m", where),
            color=_color(d.get("color", [255, 140, 0]), f"{where}.color"),
            radius_m=_number(d, "radius_m", where, 0.0325)))
    light = _check_keys(data.get("lighting", {}), {"brightness", "glare"}, "lighting")
    lighting = Lighting(brightness=_number(light, "brightness", "lighting", 1.0),
                        glare=_number(light, "glare", "lighting", 1.0))
    script = data.get("ball_script", [])
    if not isinstance(script, list):
        raise ScenarioError("ball_script must be a list")
    steps = tuple(_ball_step(s, f"ball_script[{i}]") for i, s in enumerate(script))
    if steps and ball is None:
        raise ScenarioError("ball_script needs a ball")
    duration = _number(data, "duration_s", "scenario", 30.0)
    if duration <= 0:
        raise ScenarioError("scenario.duration_s must be > 0")
    if "search_period_s" in data:
        period = _number(data, "search_period_s", "scenario")
        if period <= 0:
            raise ScenarioError("scenario.search_period_s must be > 0")
        warnings.warn(
            f"{source}: 'search_period_s' in a scenario is deprecated and ignored: set "
            f"period_s of the search behaviour in the robot file instead (it was {period:g})",
            DeprecationWarning, stacklevel=3,
        )
    try:
        world = WorldConfig(robot_start=start, ball=ball, arena=arena, walls=tuple(walls),
                            boxes=tuple(boxes), distractors=tuple(distractors), lighting=lighting,
                            seed=seed)
    except ValueError as exc:
        raise ScenarioError(f"scenario {name!r}: {exc}") from exc
    return Scenario(name=name, title=str(data.get("title", name)),
                    description=str(data.get("description", "")), world=world,
                    ball_script=steps, duration_s=duration, seed=seed,
                    source=source)


def builtin_names() -> list[str]:
    folder = resources.files("components.sim") / BUILTIN_DIR
    return sorted(p.name.removesuffix(".json") for p in folder.iterdir()
                  if p.name.endswith(".json"))


def load_scenario(name_or_path: str) -> Scenario:
    """A built-in scenario by name, or a scenario file by path."""
    path = Path(name_or_path)
    if name_or_path in builtin_names():
        folder = resources.files("components.sim") / BUILTIN_DIR
        text = (folder / f"{name_or_path}.json").read_text(encoding="utf-8")
        source = f"built-in {name_or_path}"
    elif path.suffix == ".json" or path.exists():
        if not path.is_file():
            raise ScenarioError(f"no scenario file {path}")
        text = path.read_text(encoding="utf-8")
        source = str(path)
    else:
        raise ScenarioError(
            f"unknown scenario {name_or_path!r}: built-ins are {', '.join(builtin_names())}, "
            "or give a path to a .json file"
        )
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ScenarioError(f"{source}: not valid JSON: {exc}") from exc
    return parse_scenario(data, source=source)
