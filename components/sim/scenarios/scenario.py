"""Scenarios as data: a world, a robot start, scripted objects, lighting, pushes and a seed,
in a JSON file.

The format is documented in ``docs/scenarios.md``. The thesis's four experiments (§4.2) and a
few more situations ship as built-ins in ``files/``; :func:`load_scenario` takes a
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
The file's format is the msgspec types of :mod:`components.sim.scenarios.format`;
:func:`parse_scenario` also refuses objects placed outside the arena or overlapping the robot at
its start, naming them. Every mistake reads ``FILE:LINE: message (at PATH)``, as the robot
file's do.
"""

from __future__ import annotations

import json
import math
import warnings
from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any, TypeVar

import msgspec
import yaml

from components.sim.scenarios.format import (
    ExpectSpec,
    FromCameraSpec,
    LightingChange,
    OutOfViewSpec,
    PositionSpec,
    Push,
    ScenarioFile,
    StepSpec,
    WaveSpec,
)
from components.sim.world.config import (
    CAMERA_X_M,
    Arena,
    BallConfig,
    BoxObstacle,
    Distractor,
    Lighting,
    Wall,
    WorldConfig,
    WorldPose,
)
from components.sim.world.physics import World
from ubf_async.assembly.robotfile import (
    YAML_LOADER,
    Locator,
    Path_,
    Spec,
    first_duplicate_key,
    format_path,
)
from ubf_async.errors import ScenarioError

__all__ = ["BallScript", "BallStep", "LightingChange", "ObjectScript", "Push", "Scenario",
           "ScenarioError", "builtin_names", "decode_scenario", "load_scenario",
           "parse_scenario"]

CAMERA_OFFSET_M = CAMERA_X_M
"""The Mini-WHEGS's camera sits this far ahead of its centre (another body's:
``RobotConfig.camera_x_m``)."""
HIDDEN_AT = (50.0, 50.0)
"""Where a hidden ball waits: far outside any arena, behind its walls."""
BUILTIN_DIR = "files"

_S = TypeVar("_S", bound=Spec)


@dataclass(frozen=True, slots=True, kw_only=True)
class BallStep:
    """One step of an object's script (the ball's or a distractor's)."""

    at_s: float
    kind: str
    target: dict[str, float] = field(default_factory=dict)
    speed_m_s: float = 0.3


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
              ran: Callable[[str], bool] = lambda name: True,
              open_ended_s: float | None = None) -> dict[str, Any]:
        """Each criterion's verdict, and ``pass``: all of them met — or ``None`` when the
        file gives no criteria (nothing was checked: the outcome is only words), when the
        robot did not run a behaviour the outcome describes (``ran(name)`` false; then
        ``applicable`` is false and ``why`` says which), or when the run ended before its
        duration (the summary's ``interrupted``: ``{"at_s", "of_s"}``) or had none and was
        stopped after ``open_ended_s`` (then ``judged`` is false and ``why`` says when): an
        outcome describes the end of a whole run."""
        missing = [name for name in self.behaviors if not ran(name)]
        if missing:
            return {"outcome": self.outcome, "criteria": [], "pass": None,
                    "applicable": False, "judged": False,
                    "why": f"the robot has no {', '.join(missing)}, which it describes"}
        interrupted = summary.get("interrupted")
        if interrupted:
            return {"outcome": self.outcome, "criteria": [], "pass": None,
                    "applicable": True, "judged": False,
                    "why": f"interrupted at {interrupted['at_s']:.1f} s of "
                           f"{interrupted['of_s']:g} s"}
        if open_ended_s is not None:
            return {"outcome": self.outcome, "criteria": [], "pass": None,
                    "applicable": True, "judged": False,
                    "why": f"stopped after {open_ended_s:.1f} s of an open-ended run; "
                           f"launch --judge judges it anyway"}
        verdicts = [c.judge(summary) for c in self.criteria]
        return {"outcome": self.outcome, "criteria": verdicts, "applicable": True,
                "judged": True,
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
    ahead = world.config.robot.camera_x_m  # the robot's first camera
    return (robot.x_m + ahead * math.cos(robot.heading_rad),
            robot.y_m + ahead * math.sin(robot.heading_rad), robot.heading_rad)


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
# Parsing: msgspec decodes the document into scenario_format's types (types, ranges, unknown
# fields); what follows checks what spans fields, and builds the runtime objects.


class _Errors:
    """Scenario errors reading ``FILE:LINE: message (at PATH)``, through the robot file's
    :class:`Locator` (no line when the data did not come from a file's text)."""

    def __init__(self, source: str, locator: Locator | None) -> None:
        self.locator = locator if locator is not None else Locator(None, source=source)

    def error(self, message: str, path: Path_, *, key: str | None = None) -> ScenarioError:
        text = f"{message} (at {format_path(path)})" if path else message
        return ScenarioError(str(self.locator.error(text, path, key=key)))

    def convert(self, data: Any, type_: type[_S], base: Path_ = ()) -> _S:
        """``data`` decoded as ``type_`` (found at ``base`` in the document)."""
        try:
            return msgspec.convert(data, type=type_)
        except msgspec.ValidationError as exc:
            raise ScenarioError(str(self.locator.from_validation(exc, base, root=type_))) \
                from None


def _ball_step(spec: StepSpec) -> BallStep:
    kind = spec.kind
    body = getattr(spec, kind)
    target: dict[str, float] = {}
    if isinstance(body, PositionSpec):
        target = {"x_m": body.x_m, "y_m": body.y_m}
    elif isinstance(body, FromCameraSpec):
        target = {"distance_m": body.distance_m, "bearing_deg": body.bearing_deg}
    elif isinstance(body, WaveSpec):
        target = {"distance_m": body.distance_m, "amplitude_deg": body.amplitude_deg,
                  "period_s": body.period_s}
    elif kind == "out_of_view":  # a walk to a place from the camera, off to one side
        side = body if isinstance(body, OutOfViewSpec) else OutOfViewSpec(side=body)
        bearing = abs(side.bearing_deg)
        target = {"distance_m": side.distance_m,
                  "bearing_deg": bearing if side.side == "left" else -bearing}
        kind = "relative"
    return BallStep(at_s=spec.at_s, kind=kind, target=target, speed_m_s=spec.speed_m_s)


def _distractor_names(spec: ScenarioFile, errors: _Errors) -> dict[str, int]:
    """Each distractor's name (``distractor<i>`` by default) → its index."""
    names: dict[str, int] = {}
    for i, d in enumerate(spec.distractors):
        name = d.name if d.name is not None else f"distractor{i}"
        if name == "ball" or name in names:
            raise errors.error(f"name must be a unique non-empty string other than 'ball' "
                               f"(the ball's script is ball_script), got {name!r}",
                               ("distractors", i, "name"))
        names[name] = i
    return names


def _scripts(spec: ScenarioFile, names: Mapping[str, int],
             errors: _Errors) -> dict[int, tuple[BallStep, ...]]:
    scripts: dict[int, tuple[BallStep, ...]] = {}
    for name, steps in spec.scripts.items():
        if name not in names:
            raise errors.error(f"no distractor is named {name!r} (named: {sorted(names)}; "
                               f"the ball's script is ball_script)", ("scripts", name),
                               key=name)
        if not isinstance(steps, list):
            raise errors.error(f"expected an array of steps, got {type(steps).__name__}",
                               ("scripts", name))
        scripts[names[name]] = tuple(
            _ball_step(errors.convert(step, StepSpec, ("scripts", name, j)))
            for j, step in enumerate(steps))
    return scripts


def _world(spec: ScenarioFile, scripted: Collection[str], names: Sequence[str],
           errors: _Errors) -> WorldConfig:
    r, a = spec.robot, spec.arena
    try:
        return WorldConfig(
            robot_start=WorldPose(x_m=r.x_m, y_m=r.y_m, heading_rad=math.radians(r.heading_deg)),
            ball=None if spec.ball is None else BallConfig(x_m=spec.ball.x_m,
                                                           y_m=spec.ball.y_m,
                                                           radius_m=spec.ball.radius_m),
            arena=None if a is None else Arena(x_min_m=a.x_min_m, y_min_m=a.y_min_m,
                                               x_max_m=a.x_max_m, y_max_m=a.y_max_m),
            walls=tuple(Wall(x1_m=w.x1_m, y1_m=w.y1_m, x2_m=w.x2_m, y2_m=w.y2_m)
                        for w in spec.walls),
            boxes=tuple(BoxObstacle(x_m=b.x_m, y_m=b.y_m, length_m=b.length_m,
                                    width_m=b.width_m, height_m=b.height_m,
                                    yaw_rad=math.radians(b.yaw_deg)) for b in spec.obstacles),
            distractors=tuple(
                Distractor(kind=d.kind, x_m=d.x_m, y_m=d.y_m, color=d.color,
                           radius_m=d.radius_m, length_m=d.length_m, width_m=d.width_m,
                           height_m=d.height_m, yaw_rad=math.radians(d.yaw_deg),
                           # A scripted object is carried by hand: a body that can move.
                           movable=d.movable or name in scripted)
                for d, name in zip(spec.distractors, names, strict=True)),
            lighting=Lighting(brightness=spec.lighting.brightness,
                              glare=spec.lighting.glare),
            seed=spec.seed)
    except ValueError as exc:  # the types' ranges should leave the world nothing to refuse
        raise errors.error(f"scenario {spec.name!r}: {exc}", ()) from None


def _criterion(key: str, bounds: Any, errors: _Errors) -> Criterion:
    path = key.strip("|")
    try:
        low, high = msgspec.convert(bounds, type=tuple[float, float])
    except msgspec.ValidationError:
        low = high = math.nan
    if not (path and math.isfinite(low) and math.isfinite(high) and low <= high):
        raise errors.error(f"expected a summary field and [low, high] with finite low <= high, "
                           f"got {bounds!r}", ("expect", "criteria", key), key=key)
    return Criterion(path=path, low=low, high=high,
                     absolute=key.startswith("|") and key.endswith("|"))


def _expectation(spec: ExpectSpec | None, errors: _Errors) -> Expectation | None:
    if spec is None:
        return None
    return Expectation(outcome=spec.outcome, behaviors=tuple(spec.behaviors),
                       criteria=tuple(_criterion(key, bounds, errors)
                                      for key, bounds in spec.criteria.items()))


def parse_scenario(data: Any, *, source: str = "<data>",
                   locator: Locator | None = None) -> Scenario:
    """Check a decoded scenario document (JSON's objects, arrays, numbers, strings) and build
    the :class:`Scenario`. A mistake raises :class:`ScenarioError` reading
    ``SOURCE:LINE: message (at PATH)`` — the line when ``locator`` maps the document's paths
    to its text (:func:`decode_scenario`)."""
    errors = _Errors(source, locator)
    spec = errors.convert(data, ScenarioFile)
    names = _distractor_names(spec, errors)
    scripts = _scripts(spec, names, errors)
    ball_script = tuple(_ball_step(step) for step in spec.ball_script)
    if ball_script and spec.ball is None:
        raise errors.error("a ball_script needs a `ball`", ("ball_script",))
    if spec.search_period_s is not None:
        warnings.warn(
            f"{source}: 'search_period_s' in a scenario is deprecated and ignored: set "
            f"period_s of the search behaviour in the robot file instead (it was "
            f"{spec.search_period_s:g})", DeprecationWarning, stacklevel=2)
    world = _world(spec, spec.scripts.keys(), list(names), errors)
    problem = placement_problem(world, ball_script=ball_script, scripts=scripts,
                                distractor_names=list(names))
    if problem is not None:
        raise errors.error(problem[1], problem[0])
    return Scenario(name=spec.name, title=spec.name if spec.title is None else spec.title,
                    description=spec.description, world=world, ball_script=ball_script,
                    duration_s=spec.duration_s, seed=spec.seed, source=source,
                    scripts=scripts, lighting_script=tuple(spec.lighting_script),
                    pushes=tuple(spec.pushes), expect=_expectation(spec.expect, errors),
                    distractor_names=tuple(names))


def decode_scenario(text: str, *, source: str = "<scenario>") -> Scenario:
    """A scenario file's JSON text as a :class:`Scenario` (mistakes at ``FILE:LINE``)."""
    try:
        # NaN and Infinity are no JSON numbers: kept as the words, refused as "not a number".
        data = json.loads(text, parse_constant=str)
    except json.JSONDecodeError as exc:
        raise ScenarioError(f"{source}:{exc.lineno}: not valid JSON: {exc.msg} (column "
                            f"{exc.colno})") from None
    return parse_scenario(data, source=source, locator=_json_locator(text, source))


def _json_locator(text: str, source: str) -> Locator:
    """The robot file's :class:`Locator` over JSON text (JSON is YAML's flow style), refusing a
    key given twice in an object, which JSON readers silently resolve to the last."""
    try:
        root = yaml.compose(text, Loader=YAML_LOADER)
    except yaml.YAMLError:  # JSON the YAML parser reads otherwise (a "\ud83d\ude00" escape)
        return Locator(None, source=source)  # paths without lines
    duplicate = first_duplicate_key(root)
    if duplicate is not None:
        first, again = duplicate
        raise ScenarioError(f"{source}:{again.start_mark.line + 1}: duplicate key "
                            f"`{again.value}` (also on line {first.start_mark.line + 1}): a key "
                            f"may appear once in an object; JSON readers would keep the last")
    return Locator(root, source=source)


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
    """Refuse (:class:`~ubf_async.errors.ScenarioError`, ``where: …``) what
    :func:`placement_problem` finds."""
    problem = placement_problem(world, ball_script=ball_script, scripts=scripts,
                                distractor_names=distractor_names)
    if problem is not None:
        raise ScenarioError(f"{where}: {problem[1]}")


_Object = tuple[Path_, str, Polygon | None, tuple[float, float, float] | None]
"""Where in the file, a label, and the outline or the circle (x, y, radius)."""
_Target = tuple[Path_, str, tuple[float, float, float]]


def _objects(world: WorldConfig, name_of: Callable[[int], str]) -> list[_Object]:
    objects: list[_Object] = []
    if world.ball is not None:
        objects.append((("ball",), "the ball", None,
                        (world.ball.x_m, world.ball.y_m, world.ball.radius_m)))
    for i, d in enumerate(world.distractors):
        label = f"distractors[{i}] ({d.kind}, {name_of(i)!r})"
        if d.kind == "box":
            objects.append((("distractors", i), label,
                            _box_outline(d.x_m, d.y_m, d.yaw_rad, d.length_m, d.width_m), None))
        else:
            objects.append((("distractors", i), label, None, (d.x_m, d.y_m, d.radius_m)))
    for i, b in enumerate(world.boxes):
        objects.append((("obstacles", i), f"obstacles[{i}]",
                        _box_outline(b.x_m, b.y_m, b.yaw_rad, b.length_m, b.width_m), None))
    return objects


def _script_targets(world: WorldConfig, scripts: list[tuple[int, tuple[BallStep, ...]]],
                    name_of: Callable[[int], str]) -> tuple[list[_Target], list[_Target]]:
    """The ``place``/``move_to`` targets of the scripts (index -1: the ball's), and where
    their steps at ``at_s`` 0 put their objects while the robot is at its start pose."""
    targets: list[_Target] = []
    at_start: list[_Target] = []
    radius_of = {-1: world.ball.radius_m if world.ball is not None else 0.0}
    radius_of.update({i: d.radius_m for i, d in enumerate(world.distractors)})
    start = world.robot_start
    ahead = world.robot.camera_x_m
    cam_x = start.x_m + ahead * math.cos(start.heading_rad)
    cam_y = start.y_m + ahead * math.sin(start.heading_rad)
    for index, steps in scripts:
        base: Path_ = ("ball_script",) if index == -1 else ("scripts", name_of(index))
        label = "ball_script" if index == -1 else f"scripts.{name_of(index)}"
        for j, step in enumerate(steps):
            where, step_label = (*base, j), f"{label}[{j}] ({step.kind})"
            if step.kind in ("place", "move_to"):
                target = (step.target["x_m"], step.target["y_m"], radius_of[index])
                targets.append((where, step_label, target))
                if step.kind == "place" and step.at_s <= 0.0:
                    at_start.append((where, step_label, target))
            elif step.kind in ("relative", "follow") and step.at_s <= 0.0:
                bearing = start.heading_rad + math.radians(step.target["bearing_deg"])
                distance = step.target["distance_m"]
                at_start.append((where, step_label, (cam_x + distance * math.cos(bearing),
                                                     cam_y + distance * math.sin(bearing),
                                                     radius_of[index])))
    return targets, at_start


def _outside_arena(world: WorldConfig, objects: list[_Object],
                   targets: list[_Target]) -> tuple[Path_, str] | None:
    arena = world.arena
    if arena is None:
        return None

    def outside(px: float, py: float, margin: float = 0.0) -> bool:
        return not (arena.x_min_m + margin <= px <= arena.x_max_m - margin
                    and arena.y_min_m + margin <= py <= arena.y_max_m - margin)

    bounds = (f"the arena (x {arena.x_min_m:g}…{arena.x_max_m:g} m, "
              f"y {arena.y_min_m:g}…{arena.y_max_m:g} m)")
    if any(outside(x, y) for x, y in _robot_outline(world)):
        p = world.robot_start
        return ("robot",), f"the robot at ({p.x_m:g}, {p.y_m:g}) m does not fit inside {bounds}"
    for path, label, poly, circle in objects:
        if poly is not None and any(outside(x, y) for x, y in poly):
            cx = sum(x for x, _ in poly) / len(poly)
            cy = sum(y for _, y in poly) / len(poly)
            return path, f"{label} at ({cx:g}, {cy:g}) m lies (partly) outside {bounds}"
        if circle is not None and outside(circle[0], circle[1], circle[2]):
            return path, (f"{label} at ({circle[0]:g}, {circle[1]:g}) m lies (partly) "
                          f"outside {bounds}")
    for path, label, (x, y, r) in targets:
        if outside(x, y, r):
            return path, f"{label} puts its object at ({x:g}, {y:g}) m, outside {bounds}"
    return None


def placement_problem(world: WorldConfig, *, ball_script: tuple[BallStep, ...] = (),
                      scripts: dict[int, tuple[BallStep, ...]] | None = None,
                      distractor_names: Sequence[str] = ()) -> tuple[Path_, str] | None:
    """The first misplacement, naming the object, and its path in the scenario file: the
    robot or an object — ball, distractor, obstacle, or a ``place``/``move_to`` target of a
    script — outside the arena, or an object, a wall, or a script's first step at ``at_s`` 0
    (``place``, or ``relative``/``follow`` from the camera) that overlaps the robot at its
    start pose. ``None``: all is well."""
    def name_of(index: int) -> str:
        return (distractor_names[index] if index < len(distractor_names)
                else f"distractor{index}")

    objects = _objects(world, name_of)
    targets, at_start = _script_targets(world, [(-1, ball_script),
                                                *sorted((scripts or {}).items())], name_of)
    outside = _outside_arena(world, objects, targets)
    if outside is not None:
        return outside
    for i, wall in enumerate(world.walls):
        # A segment is convex: the separating-axis test holds for it too.
        objects.append((("walls", i), f"walls[{i}] from ({wall.x1_m:g}, {wall.y1_m:g}) to "
                        f"({wall.x2_m:g}, {wall.y2_m:g}) m",
                        [(wall.x1_m, wall.y1_m), (wall.x2_m, wall.y2_m)], None))
    robot = _ccw(_robot_outline(world))
    start = world.robot_start
    pose = f"({start.x_m:g}, {start.y_m:g}) m, heading {math.degrees(start.heading_rad):g}°"
    for path, label, poly, circle in objects:
        if (_polygons_overlap(robot, _ccw(poly)) if poly is not None
                else circle is not None and _circle_overlaps_polygon(*circle, robot)):
            return path, f"{label} overlaps the robot at its start {pose}"
    for path, label, (x, y, r) in at_start:
        if _circle_overlaps_polygon(x, y, r, robot):
            return path, (f"{label} puts its object at ({x:.3g}, {y:.3g}) m at the start, onto "
                          f"the robot at {pose}")
    return None


def builtin_names() -> list[str]:
    folder = resources.files("components.sim.scenarios") / BUILTIN_DIR
    return sorted(p.name.removesuffix(".json") for p in folder.iterdir()
                  if p.name.endswith(".json"))


def load_scenario(name_or_path: str) -> Scenario:
    """A built-in scenario by name, or a scenario file by path."""
    path = Path(name_or_path)
    if name_or_path in builtin_names():
        folder = resources.files("components.sim.scenarios") / BUILTIN_DIR
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
    return decode_scenario(text, source=source)
