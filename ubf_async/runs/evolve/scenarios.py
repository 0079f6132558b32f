"""Scenario sets: training and held-out scenarios made by generators, so that nobody writes
fifty scenario files by hand.

A set names built-in scenarios (or scenario files) and generators; a generator makes
``count`` scenario files of one kind, each drawn from one generator seeded by the set's
``seed`` (the same seed, the same files, on any machine):

* ``random`` — the ball at a random distance and bearing from the robot (default 0.4–1.2 m,
  anywhere around it);
* ``behind`` — the ball behind the robot (bearing 150–210°);
* ``fov_edge`` — the ball about the edge of the camera's field of view (±17.5°: bearings
  of 14–21° either side, some just in view, some just out);
* ``moving`` — the ball in view, then moved across the arena to a random place at a walking
  pace (0.1–0.3 m/s), from a random moment 3–8 s into the run.

The robot starts at the arena's centre with a random heading; the arena is the built-in
scenarios' 3 × 3 m. The files follow the scenario format (docs/scenarios.md): the simulator's
own loader checks them when the SPEC is checked, before anything runs.
"""

from __future__ import annotations

import json
import math
import random
from dataclasses import dataclass

__all__ = ["ARENA_HALF_M", "DEFAULTS", "KINDS", "MAX_DISTANCE_M", "Generated", "generate"]

ARENA_HALF_M = 1.5
MAX_DISTANCE_M = 1.3
"""Farthest a ball is placed from the robot's centre (inside the arena, its radius clear)."""

DEFAULTS: dict[str, dict[str, tuple[float, float]]] = {
    "random": {"distance_m": (0.4, 1.2), "bearing_deg": (-180.0, 180.0)},
    "behind": {"distance_m": (0.5, 1.1), "bearing_deg": (150.0, 210.0)},
    "fov_edge": {"distance_m": (0.5, 1.0), "bearing_deg": (14.0, 21.0)},
    "moving": {"distance_m": (0.5, 0.9), "bearing_deg": (-10.0, 10.0),
               "speed_m_s": (0.1, 0.3), "at_s": (3.0, 8.0)},
}
"""Each kind's ranges; a SPEC's generator may narrow or move them."""
KINDS = tuple(DEFAULTS)


@dataclass(frozen=True, slots=True)
class Generated:
    """A scenario file made by a generator: its name and its text."""

    name: str
    text: str

    @property
    def file_name(self) -> str:
        return f"{self.name}.json"


def _draw(rng: random.Random, span: tuple[float, float]) -> float:
    return round(rng.uniform(*span), 3)


def _place(x_m: float, y_m: float, heading_deg: float, distance_m: float,
           bearing_deg: float) -> dict[str, float]:
    angle = math.radians(heading_deg + bearing_deg)
    return {"x_m": round(x_m + distance_m * math.cos(angle), 3),
            "y_m": round(y_m + distance_m * math.sin(angle), 3)}


def generate(kind: str, count: int, *, rng: random.Random, prefix: str,
             duration_s: float, ranges: dict[str, tuple[float, float]] | None = None,
             start: int = 0) -> list[Generated]:
    """``count`` scenarios of ``kind`` drawn from ``rng``, named ``{prefix}-{kind}-{i}`` from
    ``start``. ``ranges`` replaces the kind's default ranges (:data:`DEFAULTS`) it names."""
    spans = {**DEFAULTS[kind], **(ranges or {})}
    made = []
    for i in range(start, start + count):
        heading = _draw(rng, (-180.0, 180.0))
        distance = min(MAX_DISTANCE_M, _draw(rng, spans["distance_m"]))
        bearing = _draw(rng, spans["bearing_deg"])
        if kind == "fov_edge" and rng.random() < 0.5:
            bearing = -bearing
        name = f"{prefix}-{kind}-{i}"
        scenario: dict[str, object] = {
            "name": name,
            "title": f"{kind} {i} ({prefix})",
            "description": (f"Made by the scenario generator {kind!r}: the ball {distance} m "
                            f"from the robot at a bearing of {bearing}°."),
            "duration_s": duration_s,
            "robot": {"x_m": 0.0, "y_m": 0.0, "heading_deg": heading},
            "ball": _place(0.0, 0.0, heading, distance, bearing),
            "arena": {"x_min_m": -ARENA_HALF_M, "y_min_m": -ARENA_HALF_M,
                      "x_max_m": ARENA_HALF_M, "y_max_m": ARENA_HALF_M},
        }
        if kind == "moving":
            target_distance = _draw(rng, (0.5, 1.1))
            to = _place(0.0, 0.0, _draw(rng, (-180.0, 180.0)), target_distance, 0.0)
            scenario["ball_script"] = [{"at_s": _draw(rng, spans["at_s"]),
                                        "speed_m_s": _draw(rng, spans["speed_m_s"]),
                                        "move_to": to}]
        made.append(Generated(name, json.dumps(scenario, indent=2) + "\n"))
    return made
