"""The scenario file's format as msgspec types (docs/scenarios.md, "File format").

Decoding a scenario document into :class:`ScenarioFile` checks every field's type and range and
refuses unknown fields, listing the valid ones — the robot file's mechanism: these types derive
from :class:`ubf_async.assembly.robotfile.Spec`, and :mod:`components.sim.scenarios.scenario`
reports msgspec's errors at ``FILE:LINE`` through :class:`ubf_async.assembly.robotfile.Locator`.
What needs more than one field — a script naming a distractor, placement in the arena — is
checked there, when the runtime :class:`~components.sim.scenarios.scenario.Scenario` is built.

Every number has a range, which also refuses infinities and NaN.
"""

from __future__ import annotations

from typing import Annotated, Any, ClassVar, Literal

import msgspec

from components.sim.world.config import BALL_DIAMETER_M, ORANGE
from ubf_async.assembly.robotfile import Spec

__all__ = ["STEP_KINDS", "ArenaSpec", "DistractorSpec", "ExpectSpec", "FromCameraSpec",
           "LightingChange", "LightingSpec", "ObstacleSpec", "OutOfViewSpec", "PositionSpec",
           "Push", "ScenarioFile", "StartSpec", "StepSpec", "WallSpec", "WaveSpec"]

MAX_M = 1000.0
"""Largest distance or coordinate (metres)."""
MAX_S = 1e7
"""Latest time a scenario may name (simulated seconds)."""

Metres = Annotated[float, msgspec.Meta(ge=-MAX_M, le=MAX_M, description="metres")]
Size = Annotated[float, msgspec.Meta(gt=0.0, le=MAX_M, description="metres, > 0")]
Degrees = Annotated[float, msgspec.Meta(ge=-360.0, le=360.0, description="degrees")]
At = Annotated[float, msgspec.Meta(ge=0.0, le=MAX_S, description="simulated seconds")]
Seconds = Annotated[float, msgspec.Meta(ge=0.0, le=MAX_S)]
Duration = Annotated[float, msgspec.Meta(gt=0.0, le=MAX_S)]
Speed = Annotated[float, msgspec.Meta(gt=0.0, le=100.0, description="m/s")]
Brightness = Annotated[float, msgspec.Meta(gt=0.0, le=100.0)]
Glare = Annotated[float, msgspec.Meta(ge=0.0, le=100.0)]
Channel = Annotated[int, msgspec.Meta(ge=0, le=255)]
Text = Annotated[str, msgspec.Meta(min_length=1)]


class StartSpec(Spec):
    what: ClassVar[str] = "`robot`"

    x_m: Metres = 0.0
    y_m: Metres = 0.0
    heading_deg: Degrees = 0.0


class PositionSpec(Spec):
    what: ClassVar[str] = "a position"

    x_m: Metres
    y_m: Metres


class BallSpec(Spec):
    what: ClassVar[str] = "`ball`"

    x_m: Metres
    y_m: Metres
    radius_m: Annotated[float, msgspec.Meta(ge=0.01, le=0.5)] = BALL_DIAMETER_M / 2
    """The thesis's ball is 6.5 cm across; a scenario for a larger robot may size it up."""


class ArenaSpec(Spec):
    what: ClassVar[str] = "`arena`"

    x_min_m: Metres
    y_min_m: Metres
    x_max_m: Metres
    y_max_m: Metres

    def __post_init__(self) -> None:
        if not (self.x_min_m < self.x_max_m and self.y_min_m < self.y_max_m):
            raise ValueError("an arena needs x_min_m < x_max_m and y_min_m < y_max_m")


class WallSpec(Spec):
    what: ClassVar[str] = "a wall"

    x1_m: Metres
    y1_m: Metres
    x2_m: Metres
    y2_m: Metres

    def __post_init__(self) -> None:
        if (self.x1_m, self.y1_m) == (self.x2_m, self.y2_m):
            raise ValueError("a wall needs two distinct end points")


class ObstacleSpec(Spec):
    what: ClassVar[str] = "an obstacle"

    x_m: Metres
    y_m: Metres
    length_m: Size
    width_m: Size
    height_m: Size = 0.10
    yaw_deg: Degrees = 0.0


class DistractorSpec(Spec):
    """``kind`` may be left out (a sphere), so the kinds are one type, not a tagged union."""

    what: ClassVar[str] = "a distractor"

    x_m: Metres
    y_m: Metres
    kind: Literal["sphere", "cylinder", "box"] = "sphere"
    name: Text | None = None
    """Default ``distractor<i>``."""
    color: tuple[Channel, Channel, Channel] = ORANGE
    radius_m: Size = BALL_DIAMETER_M / 2
    length_m: Size = 0.05
    width_m: Size = 0.05
    height_m: Size | None = None
    yaw_deg: Degrees = 0.0
    movable: bool = False


class LightingSpec(Spec):
    what: ClassVar[str] = "`lighting`"

    brightness: Brightness = 1.0
    glare: Glare = 1.0


class FromCameraSpec(Spec):
    """A place relative to the robot's camera (``relative`` and ``follow`` steps)."""

    what: ClassVar[str] = "a place from the camera"

    distance_m: Size
    bearing_deg: Degrees = 0.0


class OutOfViewSpec(Spec):
    what: ClassVar[str] = "`out_of_view`"

    side: Literal["left", "right"]
    bearing_deg: Degrees = 70.0
    distance_m: Size = 0.7


class WaveSpec(Spec):
    what: ClassVar[str] = "`wave`"

    distance_m: Size = 0.5
    amplitude_deg: Degrees = 25.0
    period_s: Duration = 0.8


STEP_KINDS = ("place", "move_to", "relative", "out_of_view", "follow", "wave", "hide")


class StepSpec(Spec):
    """A step of an object's script: ``at_s``, ``speed_m_s`` and exactly one of
    :data:`STEP_KINDS` (the format names the kind by its key, so this is no tagged union)."""

    what: ClassVar[str] = "a script step"

    at_s: At
    speed_m_s: Speed = 0.3
    place: PositionSpec | None = None
    move_to: PositionSpec | None = None
    relative: FromCameraSpec | None = None
    out_of_view: Literal["left", "right"] | OutOfViewSpec | None = None
    follow: FromCameraSpec | None = None
    wave: WaveSpec | None = None
    hide: bool | None = None

    def __post_init__(self) -> None:
        given = [kind for kind in STEP_KINDS if getattr(self, kind) is not None]
        if len(given) != 1:
            raise ValueError(f"a step needs exactly one of {', '.join(STEP_KINDS)}; got "
                             f"{', '.join(given) or 'none'}")
        if self.hide is False:
            raise ValueError("`hide` must be true (leave the step out to keep the object)")

    @property
    def kind(self) -> str:
        return next(kind for kind in STEP_KINDS if getattr(self, kind) is not None)


class LightingChange(Spec):
    """From ``at_s``, ramp the lighting linearly to ``brightness``/``glare`` (``None``: keep)
    over ``over_s`` (0: at once)."""

    what: ClassVar[str] = "a lighting change"

    at_s: At
    brightness: Brightness | None = None
    glare: Glare | None = None
    over_s: Seconds = 0.0

    def __post_init__(self) -> None:
        if self.brightness is None and self.glare is None:
            raise ValueError("a lighting change needs brightness and/or glare")


class Push(Spec):
    """From ``at_s``, shove the robot ``forward_m``/``left_m`` (its own frame at the start of
    the push) and turn it ``turn_deg``, evenly over ``over_s``."""

    what: ClassVar[str] = "a push"

    at_s: At
    forward_m: Metres = 0.0
    left_m: Metres = 0.0
    turn_deg: Degrees = 0.0
    over_s: Seconds = 0.3


class ExpectSpec(Spec):
    """``{"outcome": TEXT, "criteria": {"PATH": [LOW, HIGH], "|PATH|": [..]}}``."""

    what: ClassVar[str] = "`expect`"

    outcome: Text
    criteria: dict[str, Any] = msgspec.field(default_factory=dict)
    """Checked one by one (scenarios._criterion), so that a mistake names its key."""
    behaviors: list[Text] = msgspec.field(default_factory=list)


class ScenarioFile(Spec):
    """A scenario document: everything but ``name`` is optional."""

    what: ClassVar[str] = "a scenario"

    name: Text
    title: str | None = None
    """Default: the name."""
    description: str = ""
    seed: int = 0
    duration_s: Duration = 30.0
    robot: StartSpec = msgspec.field(default_factory=StartSpec)
    ball: BallSpec | None = None
    arena: ArenaSpec | None = None
    walls: list[WallSpec] = msgspec.field(default_factory=list)
    obstacles: list[ObstacleSpec] = msgspec.field(default_factory=list)
    distractors: list[DistractorSpec] = msgspec.field(default_factory=list)
    lighting: LightingSpec = msgspec.field(default_factory=LightingSpec)
    ball_script: list[StepSpec] = msgspec.field(default_factory=list)
    scripts: dict[str, Any] = msgspec.field(default_factory=dict)
    """A distractor's name → its steps, each decoded as a :class:`StepSpec` on its own (so
    that a mistake names the distractor: msgspec's paths leave dictionary keys out)."""
    lighting_script: list[LightingChange] = msgspec.field(default_factory=list)
    pushes: list[Push] = msgspec.field(default_factory=list)
    expect: ExpectSpec | None = None
    search_period_s: Duration | None = None
    """Deprecated and ignored (the search behaviour's ``period_s`` in the robot file)."""
