"""Scenarios as data: a world, a robot start, scripted objects, lighting, pushes and a seed,
in a JSON file.

The format is documented in ``docs/scenarios.md``. The thesis's four experiments (§4.2) and a
few more situations ship as built-ins in ``scenario_files/``; :func:`load_scenario` takes a
built-in name or a path.

Scripts move objects like the experimenter's hand did: the ball (``ball_script``) and any
named distractor (``scripts``, which makes it movable). Each step starts at ``at_s``
(simulated seconds) and is one of

* ``place``      — teleport to ``{"x_m", "y_m"}``;
* ``move_to``    — walk to ``{"x_m", "y_m"}`` at ``speed_m_s``;
* ``relative``   — walk to ``{"distance_m", "bearing_deg"}`` measured from the robot's camera
  at the moment the step starts (``bearing_deg`` positive to the robot's left);
* ``out_of_view``— walk to ``"left"`` or ``"right"`` of the robot, ``bearing_deg`` (default
  70°) off its heading at ``distance_m`` (default 0.7 m), i.e. across and out of the 35° view;
* ``follow``     — keep ``{"distance_m", "bearing_deg"}`` from the robot's camera as the robot
  moves (a hand holding the object there, moving at up to ``speed_m_s``) until the next step;
* ``wave``       — wave it to and fro across the view, ``{"distance_m", "amplitude_deg",
  "period_s"}`` around the robot's heading at the start, as fast as the hand goes;
* ``hide``       — lift it out of the arena (nothing can see it); the next step puts it
  straight down at its target instead of walking it there;
a walking step ends when the object arrives (or when the next step starts).

``lighting_script`` changes the lighting over time (a dimmer room, a lamp switched on), and
``pushes`` shove the robot by hand (its wheels do not turn, so its encoders see nothing).
:func:`parse_scenario` refuses objects placed outside the arena or overlapping the robot at
its start, naming them.
"""

from __future__ import annotations

import json
import math
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

from components.sim.world import (
    BALL_DIAMETER_M,
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

__all__ = ["BallScript", "BallStep", "LightingChange", "ObjectScript", "Push", "Scenario",
           "ScenarioError", "builtin_names", "load_scenario", "parse_scenario"]

CAMERA_OFFSET_M = 0.05
"""The camera sits this far ahead of the robot's centre (see camera_render.CameraParams)."""
HIDDEN_AT = (50.0, 50.0)
"""Where a hidden ball waits: far outside any arena, behind its walls."""
BUILTIN_DIR = "scenario_files"


@dataclass(frozen=True, slots=True, kw_only=True)
class BallStep:
    """One step of an object's script (the ball's or a distractor's)."""

    at_s: float
    kind: str
    target: dict[str, float] = field(default_factory=dict)
    speed_m_s: float = 0.3


@dataclass(frozen=True, slots=True, kw_only=True)
class LightingChange:
    """From ``at_s``, ramp the lighting linearly to ``brightness``/``glare`` (``None``: keep)
    over ``over_s`` (0: at once)."""

    at_s: float
    brightness: float | None = None
    glare: float | None = None
    over_s: float = 0.0


@dataclass(frozen=True, slots=True, kw_only=True)
class Push:
    """From ``at_s``, shove the robot ``forward_m``/``left_m`` (its own frame at the start of
    the push) and turn it ``turn_deg``, evenly over ``over_s``."""

    at_s: float
    forward_m: float = 0.0
    left_m: float = 0.0
    turn_deg: float = 0.0
    over_s: float = 0.3


@dataclass(frozen=True, slots=True)
class Criterion:
    """One number of the run's summary that must lie within ``[low, high]`` (``path`` is
    dotted: ``motion_last_2s.max_offset_m``; ``abs`` judges the magnitude)."""

    path: str
    low: float
    high: float
    absolute: bool = False

    def judge(self, summary: Mapping[str, Any]) -> dict[str, Any]:
        value: Any = summary
        for part in self.path.split("."):
            value = value.get(part) if isinstance(value, Mapping) else None
        ok = isinstance(value, int | float) and math.isfinite(value) and (
            self.low <= (abs(value) if self.absolute else value) <= self.high)
        return {"criterion": f"{'|' + self.path + '|' if self.absolute else self.path}",
                "range": [self.low, self.high], "value": value, "pass": ok}


@dataclass(frozen=True, slots=True)
class Expectation:
    """What the thesis says a scenario ends with, and the numbers that show it."""

    outcome: str
    criteria: tuple[Criterion, ...] = ()
    behaviors: tuple[str, ...] = ()
    """The behaviours the outcome describes (``search``'s counter, ``flee`` backing away):
    judged only on a robot that ran them."""

    def judge(self, summary: Mapping[str, Any], *,
              ran: Callable[[str], bool] = lambda name: True) -> dict[str, Any]:
        """Each criterion's verdict, and ``pass``: all of them met — or ``None`` when the
        file gives no criteria (nothing was checked: the outcome is only words), or when the
        robot did not run a behaviour the outcome describes (``ran(name)`` false; then
        ``applicable`` is false and ``why`` says which)."""
        missing = [name for name in self.behaviors if not ran(name)]
        if missing:
            return {"outcome": self.outcome, "criteria": [], "pass": None,
                    "applicable": False,
                    "why": f"the robot has no {', '.join(missing)}, which it describes"}
        verdicts = [c.judge(summary) for c in self.criteria]
        return {"outcome": self.outcome, "criteria": verdicts, "applicable": True,
                "pass": all(v["pass"] for v in verdicts) if verdicts else None}


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
    scripts: dict[int, tuple[BallStep, ...]] = field(default_factory=dict)
    """Scripts of distractors, by their index in ``world.distractors``."""
    lighting_script: tuple[LightingChange, ...] = ()
    pushes: tuple[Push, ...] = ()
    expect: Expectation | None = None
    """The expected outcome (``expect`` in the file), judged in the run's summary."""
    distractor_names: tuple[str, ...] = ()
    """The name of each of ``world.distractors`` (``distractor<i>`` unless the file names it)."""

    def install(self, world: World) -> None:
        """Attach the scripts, lighting changes and pushes to ``world`` (step hooks)."""
        if self.ball_script:
            world.add_step_hook(BallScript(self.ball_script))
        for index, steps in sorted(self.scripts.items()):
            world.add_step_hook(ObjectScript(steps, _DistractorMover(index)))
        if self.lighting_script:
            world.add_step_hook(LightingScript(self.lighting_script))
        if self.pushes:
            world.add_step_hook(PushScript(self.pushes))


class _Mover:
    """Where a scripted object is and how to put it somewhere (the ball by default)."""

    hidden_at: tuple[float, float] = HIDDEN_AT

    def position(self, world: World) -> tuple[float, float] | None:
        ball = world.snapshot().ball
        return None if ball is None else (ball.x_m, ball.y_m)

    def place(self, world: World, x_m: float, y_m: float) -> None:
        world.place_ball(x_m, y_m)


class _DistractorMover(_Mover):
    def __init__(self, index: int) -> None:
        self.index = index
        # Hidden objects wait apart from each other (and from the ball).
        self.hidden_at = (HIDDEN_AT[0] + 2.0 * (index + 1), HIDDEN_AT[1])

    def position(self, world: World) -> tuple[float, float] | None:
        d = world.snapshot().distractors[self.index]
        return d.x_m, d.y_m

    def place(self, world: World, x_m: float, y_m: float) -> None:
        world.place_distractor(self.index, x_m, y_m)


def _camera_pose(world: World) -> tuple[float, float, float]:
    robot = world.snapshot().robot
    return (robot.x_m + CAMERA_OFFSET_M * math.cos(robot.heading_rad),
            robot.y_m + CAMERA_OFFSET_M * math.sin(robot.heading_rad), robot.heading_rad)


def _from_camera(world: World, distance_m: float, bearing_deg: float) -> tuple[float, float]:
    cam_x, cam_y, heading = _camera_pose(world)
    bearing = heading + math.radians(bearing_deg)
    return cam_x + distance_m * math.cos(bearing), cam_y + distance_m * math.sin(bearing)


class ObjectScript:
    """Step hook that plays an object's script on the simulation clock."""

    def __init__(self, steps: tuple[BallStep, ...], mover: _Mover | None = None) -> None:
        self.steps = sorted(steps, key=lambda s: s.at_s)
        self.mover = mover if mover is not None else _Mover()
        self.next_index = 0
        self.target: tuple[float, float] | None = None
        self.speed_m_s = 0.0
        self.follow: BallStep | None = None
        self.wave: tuple[BallStep, float, float, float, float] | None = None
        """The wave step, its start time and the camera pose (x, y, heading) it waves around."""

    def __call__(self, world: World, dt_s: float) -> None:
        now = world.time_s
        while self.next_index < len(self.steps) and self.steps[self.next_index].at_s <= now:
            self._begin(world, self.steps[self.next_index])
            self.next_index += 1
        if self.wave is not None:
            step, t0, cam_x, cam_y, heading = self.wave
            phase = 2.0 * math.pi * (now - t0) / step.target["period_s"]
            bearing = heading + math.radians(step.target["amplitude_deg"]) * math.sin(phase)
            distance = step.target["distance_m"]
            self.mover.place(world, cam_x + distance * math.cos(bearing),
                             cam_y + distance * math.sin(bearing))
            return
        if self.follow is not None:
            self.target = _from_camera(world, self.follow.target["distance_m"],
                                       self.follow.target["bearing_deg"])
        if self.target is None:
            return
        here = self.mover.position(world)
        if here is None:
            return
        dx, dy = self.target[0] - here[0], self.target[1] - here[1]
        remaining = math.hypot(dx, dy)
        stride = self.speed_m_s * dt_s
        if remaining <= stride:
            self.mover.place(world, *self.target)
            if self.follow is None:
                self.target = None
        else:
            self.mover.place(world, here[0] + dx / remaining * stride,
                             here[1] + dy / remaining * stride)

    def _begin(self, world: World, step: BallStep) -> None:
        self.follow = None
        self.wave = None
        if step.kind == "place":
            self.target = None
            self.mover.place(world, step.target["x_m"], step.target["y_m"])
            return
        if step.kind == "hide":
            self.target = None
            self.mover.place(world, *self.mover.hidden_at)
            return
        hidden = self.mover.position(world) == self.mover.hidden_at
        if step.kind == "wave":
            cam_x, cam_y, heading = _camera_pose(world)
            self.target = None
            self.wave = (step, world.time_s, cam_x, cam_y, heading)
            return
        if step.kind == "move_to":
            target = (step.target["x_m"], step.target["y_m"])
        else:  # relative, out_of_view, follow: from the camera, at the moment the step starts
            target = _from_camera(world, step.target["distance_m"], step.target["bearing_deg"])
        if step.kind == "follow":
            self.follow = step
        if hidden:  # a lifted object is put straight down where it is meant to go
            self.mover.place(world, *target)
            self.target = target if step.kind == "follow" else None
            self.speed_m_s = step.speed_m_s
            return
        self.target = target
        self.speed_m_s = step.speed_m_s


class BallScript(ObjectScript):
    """Step hook that plays the ball's script (:class:`ObjectScript` on the ball)."""

    def __init__(self, steps: tuple[BallStep, ...]) -> None:
        super().__init__(steps)


class LightingScript:
    """Step hook that plays the lighting changes."""

    def __init__(self, changes: tuple[LightingChange, ...]) -> None:
        self.changes = sorted(changes, key=lambda c: c.at_s)
        self.next_index = 0
        self.ramp: tuple[float, float, Lighting, Lighting] | None = None
        """Start time, duration, from and to."""

    def __call__(self, world: World, dt_s: float) -> None:
        now = world.time_s
        while self.next_index < len(self.changes) and self.changes[self.next_index].at_s <= now:
            change = self.changes[self.next_index]
            self.next_index += 1
            current = world.snapshot().lighting
            goal = Lighting(
                brightness=current.brightness if change.brightness is None else change.brightness,
                glare=current.glare if change.glare is None else change.glare)
            self.ramp = (change.at_s, change.over_s, current, goal)
        if self.ramp is None:
            return
        t0, over_s, start, goal = self.ramp
        f = 1.0 if over_s <= 0.0 else min(1.0, (now - t0) / over_s)
        world.set_lighting(Lighting(
            brightness=start.brightness + f * (goal.brightness - start.brightness),
            glare=start.glare + f * (goal.glare - start.glare)))
        if f >= 1.0:
            self.ramp = None


class PushScript:
    """Step hook that plays the pushes: each moves the robot by an equal share per step."""

    def __init__(self, pushes: tuple[Push, ...]) -> None:
        self.pushes = sorted(pushes, key=lambda p: p.at_s)
        self.next_index = 0
        self.active: list[tuple[float, float, float, float, float]] = []
        """(end time, dx/s, dy/s, dheading/s, start time) of the pushes under way."""

    def __call__(self, world: World, dt_s: float) -> None:
        now = world.time_s
        while self.next_index < len(self.pushes) and self.pushes[self.next_index].at_s <= now:
            push = self.pushes[self.next_index]
            self.next_index += 1
            heading = world.snapshot().robot.heading_rad
            c, s = math.cos(heading), math.sin(heading)
            dx = c * push.forward_m - s * push.left_m
            dy = s * push.forward_m + c * push.left_m
            if push.over_s <= 0.0:
                world.shift_robot(dx, dy, math.radians(push.turn_deg))
                continue
            over = push.over_s
            self.active.append((now + over, dx / over, dy / over,
                                math.radians(push.turn_deg) / over, now))
        still = []
        for end, vx, vy, w, _start in self.active:
            share = min(dt_s, max(0.0, end - now))
            if share > 0.0:
                world.shift_robot(vx * share, vy * share, w * share)
            if now + dt_s < end:
                still.append((end, vx, vy, w, _start))
        self.active = still


# ---------------------------------------------------------------------------------------------
# Parsing

_TOP_LEVEL = {"name", "title", "description", "seed", "duration_s", "robot", "ball", "arena",
              "walls", "obstacles", "distractors", "lighting", "ball_script", "scripts",
              "lighting_script", "pushes", "expect"}
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
    kinds = ("place", "move_to", "relative", "out_of_view", "follow", "wave", "hide")
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
    elif kind in ("relative", "follow"):
        body = _check_keys(body, {"distance_m", "bearing_deg"}, f"{where}.{kind}")
        target = {"distance_m": _number(body, "distance_m", f"{where}.{kind}"),
                  "bearing_deg": _number(body, "bearing_deg", f"{where}.{kind}", 0.0)}
        if target["distance_m"] <= 0:
            raise ScenarioError(f"{where}.{kind}.distance_m must be > 0")
    elif kind == "wave":
        w = f"{where}.wave"
        body = _check_keys(body, {"distance_m", "amplitude_deg", "period_s"}, w)
        target = {"distance_m": _number(body, "distance_m", w, 0.5),
                  "amplitude_deg": _number(body, "amplitude_deg", w, 25.0),
                  "period_s": _number(body, "period_s", w, 0.8)}
        if target["distance_m"] <= 0 or target["period_s"] <= 0:
            raise ScenarioError(f"{w}: distance_m and period_s must be > 0")
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
        arena = Arena(x_min_m=_number(a, "x_min_m", "arena"),
                      y_min_m=_number(a, "y_min_m", "arena"),
                      x_max_m=_number(a, "x_max_m", "arena"),
                      y_max_m=_number(a, "y_max_m", "arena"))
    walls = []
    for i, w in enumerate(data.get("walls", [])):
        w = _check_keys(w, {"x1_m", "y1_m", "x2_m", "y2_m"}, f"walls[{i}]")
        where = f"walls[{i}]"
        walls.append(Wall(x1_m=_number(w, "x1_m", where), y1_m=_number(w, "y1_m", where),
                          x2_m=_number(w, "x2_m", where), y2_m=_number(w, "y2_m", where)))
    boxes = []
    for i, b in enumerate(data.get("obstacles", [])):
        where = f"obstacles[{i}]"
        b = _check_keys(b, {"x_m", "y_m", "length_m", "width_m", "height_m", "yaw_deg"}, where)
        try:
            boxes.append(BoxObstacle(x_m=_number(b, "x_m", where), y_m=_number(b, "y_m", where),
                                     length_m=_number(b, "length_m", where),
                                     width_m=_number(b, "width_m", where),
                                     height_m=_number(b, "height_m", where, 0.10),
                                     yaw_rad=math.radians(_number(b, "yaw_deg", where, 0.0))))
        except ValueError as exc:
            raise ScenarioError(f"{where}: {exc}") from exc
    scripts_data = data.get("scripts", {})
    if not isinstance(scripts_data, dict):
        raise ScenarioError("scripts must be an object: a distractor's name → its steps")
    distractors = []
    names: dict[str, int] = {}
    for i, d in enumerate(data.get("distractors", [])):
        where = f"distractors[{i}]"
        d = _check_keys(d, {"kind", "name", "x_m", "y_m", "color", "radius_m", "length_m",
                            "width_m", "height_m", "yaw_deg", "movable"}, where)
        kind = d.get("kind", "sphere")
        if kind not in ("sphere", "cylinder", "box"):
            raise ScenarioError(f"{where}.kind must be sphere, cylinder or box")
        name_i = d.get("name", f"distractor{i}")
        if not isinstance(name_i, str) or not name_i or name_i == "ball" or name_i in names:
            raise ScenarioError(f"{where}.name must be a unique non-empty string other than "
                                f"'ball', got {name_i!r}")
        names[name_i] = i
        movable = d.get("movable", False)
        if not isinstance(movable, bool):
            raise ScenarioError(f"{where}.movable must be true or false")
        height = d.get("height_m")
        try:
            distractors.append(Distractor(
                kind=kind, x_m=_number(d, "x_m", where), y_m=_number(d, "y_m", where),
                color=_color(d.get("color", [255, 140, 0]), f"{where}.color"),
                radius_m=_number(d, "radius_m", where, BALL_DIAMETER_M / 2),
                length_m=_number(d, "length_m", where, 0.05),
                width_m=_number(d, "width_m", where, 0.05),
                height_m=None if height is None else _number(d, "height_m", where),
                yaw_rad=math.radians(_number(d, "yaw_deg", where, 0.0)),
                # A scripted object is carried by hand: it must be a body that can move.
                movable=movable or name_i in scripts_data))
        except ValueError as exc:
            raise ScenarioError(f"{where}: {exc}") from exc
    scripts: dict[int, tuple[BallStep, ...]] = {}
    for name_s, steps_data in scripts_data.items():
        if name_s not in names:
            raise ScenarioError(f"scripts.{name_s}: no distractor is named {name_s!r} (named: "
                                f"{sorted(names)}; the ball's script is ball_script)")
        if not isinstance(steps_data, list):
            raise ScenarioError(f"scripts.{name_s} must be a list of steps")
        scripts[names[name_s]] = tuple(_ball_step(st, f"scripts.{name_s}[{j}]")
                                       for j, st in enumerate(steps_data))
    lighting_script = []
    ls_data = data.get("lighting_script", [])
    if not isinstance(ls_data, list):
        raise ScenarioError("lighting_script must be a list")
    for i, c in enumerate(ls_data):
        where = f"lighting_script[{i}]"
        c = _check_keys(c, {"at_s", "brightness", "glare", "over_s"}, where)
        if "brightness" not in c and "glare" not in c:
            raise ScenarioError(f"{where}: needs brightness and/or glare")
        change = LightingChange(
            at_s=_number(c, "at_s", where),
            brightness=_number(c, "brightness", where) if "brightness" in c else None,
            glare=_number(c, "glare", where) if "glare" in c else None,
            over_s=_number(c, "over_s", where, 0.0))
        if (change.brightness is not None and change.brightness <= 0) or (
                change.glare is not None and change.glare < 0) or change.over_s < 0:
            raise ScenarioError(f"{where}: brightness must be > 0, glare and over_s >= 0")
        lighting_script.append(change)
    pushes = []
    p_data = data.get("pushes", [])
    if not isinstance(p_data, list):
        raise ScenarioError("pushes must be a list")
    for i, p in enumerate(p_data):
        where = f"pushes[{i}]"
        p = _check_keys(p, {"at_s", "forward_m", "left_m", "turn_deg", "over_s"}, where)
        push = Push(at_s=_number(p, "at_s", where),
                    forward_m=_number(p, "forward_m", where, 0.0),
                    left_m=_number(p, "left_m", where, 0.0),
                    turn_deg=_number(p, "turn_deg", where, 0.0),
                    over_s=_number(p, "over_s", where, 0.3))
        if push.over_s < 0:
            raise ScenarioError(f"{where}.over_s must be >= 0")
        pushes.append(push)
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
    distractor_names = tuple(names)  # in the order of distractors (dicts keep it)
    check_placement(world, ball_script=steps, scripts=scripts, where=f"scenario {name!r}",
                    distractor_names=distractor_names)
    return Scenario(name=name, title=str(data.get("title", name)),
                    description=str(data.get("description", "")), world=world,
                    ball_script=steps, duration_s=duration, seed=seed,
                    source=source, scripts=scripts, lighting_script=tuple(lighting_script),
                    pushes=tuple(pushes), expect=_expectation(data.get("expect")),
                    distractor_names=distractor_names)


def _expectation(data: Any) -> Expectation | None:
    """``expect``: ``{"outcome": TEXT, "criteria": {"PATH": [LOW, HIGH], "|PATH|": [..]}}``."""
    if data is None:
        return None
    data = _check_keys(data, {"outcome", "criteria", "behaviors"}, "expect")
    outcome = data.get("outcome")
    if not isinstance(outcome, str) or not outcome:
        raise ScenarioError("expect.outcome must be a non-empty string")
    behaviors = data.get("behaviors", [])
    if not isinstance(behaviors, list) or not all(isinstance(b, str) and b for b in behaviors):
        raise ScenarioError(f"expect.behaviors: expected a list of behaviour names, got "
                            f"{behaviors!r}")
    criteria_data = data.get("criteria", {})
    if not isinstance(criteria_data, dict):
        raise ScenarioError("expect.criteria must be an object: a summary field → [low, high]")
    criteria = []
    for key, bounds in criteria_data.items():
        where = f"expect.criteria.{key}"
        absolute = key.startswith("|") and key.endswith("|")
        path = key.strip("|")
        if not path or not isinstance(bounds, list) or len(bounds) != 2 or not all(
                isinstance(b, int | float) and not isinstance(b, bool) and math.isfinite(b)
                for b in bounds) or bounds[0] > bounds[1]:
            raise ScenarioError(f"{where}: expected [low, high] with finite low <= high, got "
                                f"{bounds!r}")
        criteria.append(Criterion(path=path, low=float(bounds[0]), high=float(bounds[1]),
                                  absolute=absolute))
    return Expectation(outcome=outcome, criteria=tuple(criteria), behaviors=tuple(behaviors))


# ---------------------------------------------------------------------------------------------
# Placement checks

Polygon = list[tuple[float, float]]


def _robot_outline(world: WorldConfig) -> Polygon:
    geo = world.robot.geometry
    p = world.robot_start
    c, s = math.cos(p.heading_rad), math.sin(p.heading_rad)
    hl, hw = geo.length_m / 2, geo.width_m / 2
    return [(p.x_m + c * x - s * y, p.y_m + s * x + c * y)
            for x, y in ((hl, -hw), (hl, hw), (-hl, hw), (-hl, -hw))]


def _box_outline(x: float, y: float, yaw: float, length: float, width: float) -> Polygon:
    c, s = math.cos(yaw), math.sin(yaw)
    hl, hw = length / 2, width / 2
    return [(x + c * a - s * b, y + s * a + c * b)
            for a, b in ((hl, -hw), (hl, hw), (-hl, hw), (-hl, -hw))]


def _polygons_overlap(a: Polygon, b: Polygon) -> bool:
    """Separating-axis test for two convex polygons (touching counts as no overlap)."""
    for poly in (a, b):
        for (x1, y1), (x2, y2) in zip(poly, poly[1:] + poly[:1], strict=True):
            nx, ny = y2 - y1, x1 - x2
            pa = [nx * x + ny * y for x, y in a]
            pb = [nx * x + ny * y for x, y in b]
            if max(pa) <= min(pb) or max(pb) <= min(pa):
                return False
    return True


def _circle_overlaps_polygon(x: float, y: float, r: float, poly: Polygon) -> bool:
    inside = True
    nearest = math.inf
    for (x1, y1), (x2, y2) in zip(poly, poly[1:] + poly[:1], strict=True):
        ex, ey = x2 - x1, y2 - y1
        t = max(0.0, min(1.0, ((x - x1) * ex + (y - y1) * ey) / (ex * ex + ey * ey)))
        nearest = min(nearest, math.hypot(x - x1 - t * ex, y - y1 - t * ey))
        if ex * (y - y1) - ey * (x - x1) < 0.0:  # right of a CCW edge: outside
            inside = False
    return inside or nearest < r


def _ccw(poly: Polygon) -> Polygon:
    area2 = sum(x1 * y2 - x2 * y1
                for (x1, y1), (x2, y2) in zip(poly, poly[1:] + poly[:1], strict=True))
    return poly if area2 >= 0 else poly[::-1]


def check_placement(world: WorldConfig, *, ball_script: tuple[BallStep, ...] = (),
                    scripts: dict[int, tuple[BallStep, ...]] | None = None,
                    where: str = "scenario", distractor_names: Sequence[str] = ()) -> None:
    """Refuse (:class:`~ubf_async.errors.ScenarioError`, naming the object) the robot or an
    object — ball, distractor, obstacle, or a ``place``/``move_to`` target of a script —
    outside the arena, and an object, a wall, or a script's first step at ``at_s`` 0
    (``place``, or ``relative``/``follow`` from the camera) that overlaps the robot at its
    start pose."""
    def name_of(index: int) -> str:
        return (distractor_names[index] if index < len(distractor_names)
                else f"distractor{index}")

    objects: list[tuple[str, Polygon | None, tuple[float, float, float] | None]] = []
    if world.ball is not None:
        objects.append(("the ball", None, (world.ball.x_m, world.ball.y_m,
                                           world.ball.radius_m)))
    for i, d in enumerate(world.distractors):
        label = f"distractors[{i}] ({d.kind}, {name_of(i)!r})"
        if d.kind == "box":
            objects.append((label, _box_outline(d.x_m, d.y_m, d.yaw_rad, d.length_m,
                                                d.width_m), None))
        else:
            objects.append((label, None, (d.x_m, d.y_m, d.radius_m)))
    for i, b in enumerate(world.boxes):
        objects.append((f"obstacles[{i}]", _box_outline(b.x_m, b.y_m, b.yaw_rad, b.length_m,
                                                        b.width_m), None))
    targets: list[tuple[str, tuple[float, float, float]]] = []
    at_start: list[tuple[str, tuple[float, float, float]]] = []
    """Where a script puts its object at the start, when the robot is at its start pose."""
    radius_of = {-1: world.ball.radius_m if world.ball is not None else 0.0}
    radius_of.update({i: d.radius_m for i, d in enumerate(world.distractors)})
    start = world.robot_start
    cam_x = start.x_m + CAMERA_OFFSET_M * math.cos(start.heading_rad)
    cam_y = start.y_m + CAMERA_OFFSET_M * math.sin(start.heading_rad)
    for index, steps in [(-1, ball_script), *sorted((scripts or {}).items())]:
        label = "ball_script" if index == -1 else f"scripts.{name_of(index)}"
        for j, step in enumerate(steps):
            step_label = f"{label}[{j}] ({step.kind})"
            if step.kind in ("place", "move_to"):
                target = (step.target["x_m"], step.target["y_m"], radius_of[index])
                targets.append((step_label, target))
                if step.kind == "place" and step.at_s <= 0.0:
                    at_start.append((step_label, target))
            elif step.kind in ("relative", "follow") and step.at_s <= 0.0:
                bearing = start.heading_rad + math.radians(step.target["bearing_deg"])
                distance = step.target["distance_m"]
                at_start.append((step_label, (cam_x + distance * math.cos(bearing),
                                              cam_y + distance * math.sin(bearing),
                                              radius_of[index])))
    robot = _ccw(_robot_outline(world))
    arena = world.arena
    if arena is not None:
        def outside(px: float, py: float, margin: float = 0.0) -> bool:
            return not (arena.x_min_m + margin <= px <= arena.x_max_m - margin
                        and arena.y_min_m + margin <= py <= arena.y_max_m - margin)

        bounds = (f"the arena (x {arena.x_min_m:g}…{arena.x_max_m:g} m, "
                  f"y {arena.y_min_m:g}…{arena.y_max_m:g} m)")
        if any(outside(x, y) for x, y in robot):
            p = world.robot_start
            raise ScenarioError(f"{where}: the robot at ({p.x_m:g}, {p.y_m:g}) m does not fit "
                                f"inside {bounds}")
        for label, poly, circle in objects:
            if poly is not None and any(outside(x, y) for x, y in poly):
                cx = sum(x for x, _ in poly) / len(poly)
                cy = sum(y for _, y in poly) / len(poly)
                raise ScenarioError(f"{where}: {label} at ({cx:g}, {cy:g}) m lies (partly) "
                                    f"outside {bounds}")
            if circle is not None and outside(circle[0], circle[1], circle[2]):
                raise ScenarioError(f"{where}: {label} at ({circle[0]:g}, {circle[1]:g}) m lies "
                                    f"(partly) outside {bounds}")
        for label, (x, y, r) in targets:
            if outside(x, y, r):
                raise ScenarioError(f"{where}: {label} puts its object at ({x:g}, {y:g}) m, "
                                    f"outside {bounds}")
    for i, wall in enumerate(world.walls):
        # A segment is convex: the separating-axis test holds for it too.
        objects.append((f"walls[{i}] from ({wall.x1_m:g}, {wall.y1_m:g}) to ({wall.x2_m:g}, "
                        f"{wall.y2_m:g}) m", [(wall.x1_m, wall.y1_m), (wall.x2_m, wall.y2_m)],
                        None))
    pose = (f"({start.x_m:g}, {start.y_m:g}) m, heading "
            f"{math.degrees(start.heading_rad):g}°")
    for label, poly, circle in objects:
        hit = (_polygons_overlap(robot, _ccw(poly)) if poly is not None
               else circle is not None and _circle_overlaps_polygon(*circle, robot))
        if hit:
            raise ScenarioError(f"{where}: {label} overlaps the robot at its start {pose}")
    for label, (x, y, r) in at_start:
        if _circle_overlaps_polygon(x, y, r, robot):
            raise ScenarioError(f"{where}: {label} puts its object at ({x:.3g}, {y:.3g}) m at "
                                f"the start, onto the robot at {pose}")


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
