"""Ready-made worlds for code that wants a world without a scenario's script."""

from __future__ import annotations

from dataclasses import replace

from components.sim.scenarios.scenario import load_scenario
from components.sim.world.config import WorldConfig

__all__ = ["ball_in_view"]


def ball_in_view(*, seed: int = 0) -> WorldConfig:
    """The world of the built-in ``ball-in-sight`` scenario: the pink ball ≈60 cm ahead of
    the camera and 10° to the left, in a 3 m × 3 m arena."""
    return replace(load_scenario("ball-in-sight").world, seed=seed)
