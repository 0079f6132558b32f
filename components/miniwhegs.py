"""Physical constants of the Mini-WHEGS robot shared by the HAL and the simulator.

Numbers follow the thesis (DESIGN.md §3): under 4 in (≈10 cm) long, 100–200 g, two motors in
skid-steer (left pair / right pair of wheel-legs), one quadrature encoder per motor with 1024
counts per revolution and 4 edges per count.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["MINI_WHEGS", "MiniWhegsGeometry"]


@dataclass(frozen=True, slots=True, kw_only=True)
class MiniWhegsGeometry:
    """Dimensions the odometry and the simulator both use (SI units)."""

    length_m: float = 0.10
    width_m: float = 0.07
    mass_kg: float = 0.15
    track_width_m: float = 0.06
    """Distance between the left and right wheel-leg contact lines."""
    wheel_radius_m: float = 0.02
    """Effective rolling radius of a wheel-leg."""
    counts_per_rev: int = 1024
    edges_per_count: int = 4

    @property
    def edges_per_rev(self) -> int:
        return self.counts_per_rev * self.edges_per_count


MINI_WHEGS = MiniWhegsGeometry()
