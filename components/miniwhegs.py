"""A body's dimensions as the HAL and the simulator use them, and the Mini-WHEGS's.

The robot file's ``body`` (:class:`ubf_async.assembly.body.BodySpec`) declares a body;
:meth:`MiniWhegsGeometry.of` is what odometry, the quadrature decoders and the simulated
world read of it. The defaults, and :data:`MINI_WHEGS`, are the thesis's robot
(:data:`~ubf_async.assembly.body.DEFAULT_BODY`, DESIGN.md §3): under 4 in (≈10 cm) long,
100–200 g, two motors in skid-steer (left pair / right pair of wheel-legs), one quadrature
encoder per motor with 1024 counts per revolution and 4 edges per count. Code a body can change
takes a geometry; the constant is only the default a robot file without ``body`` gets.
"""

from __future__ import annotations

from dataclasses import dataclass

from ubf_async.assembly.body import DEFAULT_BODY, BodySpec

__all__ = ["MINI_WHEGS", "MiniWhegsGeometry"]


@dataclass(frozen=True, slots=True, kw_only=True)
class MiniWhegsGeometry:
    """Dimensions the odometry and the simulator both use (SI units)."""

    length_m: float = DEFAULT_BODY.length_m
    width_m: float = DEFAULT_BODY.width_m
    mass_kg: float = DEFAULT_BODY.mass_kg
    track_width_m: float = DEFAULT_BODY.track_m
    """Distance between the left and right wheel(-leg) contact lines."""
    wheel_radius_m: float = DEFAULT_BODY.wheel_radius_m
    """Effective rolling radius of a wheel(-leg)."""
    counts_per_rev: int = DEFAULT_BODY.encoders.counts_per_rev
    edges_per_count: int = DEFAULT_BODY.encoders.edges_per_count

    @classmethod
    def of(cls, body: BodySpec) -> MiniWhegsGeometry:
        """What odometry and the simulator read of a robot file's ``body``."""
        return cls(length_m=body.length_m, width_m=body.width_m, mass_kg=body.mass_kg,
                   track_width_m=body.track_m, wheel_radius_m=body.wheel_radius_m,
                   counts_per_rev=body.encoders.counts_per_rev,
                   edges_per_count=body.encoders.edges_per_count)

    @property
    def edges_per_rev(self) -> int:
        return self.counts_per_rev * self.edges_per_count


MINI_WHEGS = MiniWhegsGeometry()
