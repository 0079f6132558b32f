"""When something moved the robot that its wheels did not: contacts and pushes, and what they
did to the encoders' odometry (pure bookkeeping for the run's summary).

The encoders count wheel rotations, with the direction taken from the command (the thesis's
HAL): a body pressed against a box while its wheels spin, or shoved by a hand, moves without
the wheels saying so, and no odometry from the wheels can follow it. :class:`HeadingAudit`
takes the run's samples (every ``SAMPLE_PERIOD_S`` of simulated time): the true heading and the
odometry's, both unwrapped (full turns count, so an error past 180° stays visible), and what
touched the robot since the previous sample (:meth:`components.sim.world.physics.World.contacts`). A
sample interval in which anything touched or pushed the robot is *disturbed*; the heading
error gained over the other intervals is the odometry's own error, which the built-in
scenarios bound at 10 % of the angle turned over them (docs/scenarios.md, Outputs).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

__all__ = ["MAX_LISTED_PERIODS", "DisturbedPeriod", "HeadingAudit"]

MAX_LISTED_PERIODS = 100
"""Disturbed periods listed in the summary (the first ones; ``count`` counts them all)."""


@dataclass(slots=True, kw_only=True)
class DisturbedPeriod:
    """Consecutive disturbed sample intervals, and what touched the robot over them."""

    from_s: float
    to_s: float
    by: set[str]

    def as_dict(self) -> dict[str, Any]:
        return {"from_s": self.from_s, "to_s": self.to_s, "by": sorted(self.by)}


class HeadingAudit:
    """The odometry's heading against the true one, split into disturbed and undisturbed
    sample intervals (see the module docstring). Feed it with :meth:`add` in time order."""

    def __init__(self, *, max_listed: int = MAX_LISTED_PERIODS) -> None:
        self.max_listed = max_listed
        self.periods: list[DisturbedPeriod] = []
        """The first ``max_listed`` disturbed periods (the last may still be growing)."""
        self.count = 0
        self.disturbed_s = 0.0
        self.longest_s = 0.0
        """The longest disturbed period: how long the robot stayed against something."""
        self.time_by: dict[str, float] = {}
        """Per thing that touched the robot, the time of the intervals it touched it in."""
        self.turned_rad = 0.0
        self.turned_undisturbed_rad = 0.0
        self.error_rad = 0.0
        """Signed: odometry's heading change minus the true one, over the whole run."""
        self.error_undisturbed_rad = 0.0
        self._last: tuple[float, float, float | None] | None = None
        self._open: DisturbedPeriod | None = None

    def add(self, *, t_s: float, true_heading_rad: float, odometry_heading_rad: float | None,
            touched: Iterable[str] = ()) -> None:
        """One sample: the simulated time, both headings unwrapped (``odometry_heading_rad``
        None without encoders) and what touched the robot since the previous sample."""
        last = self._last
        self._last = (t_s, true_heading_rad, odometry_heading_rad)
        if last is None:
            return  # the first sample is where both headings start
        t0, true0, odo0 = last
        d_true = true_heading_rad - true0
        error = (odometry_heading_rad - odo0 if odometry_heading_rad is not None
                 and odo0 is not None else 0.0) - d_true
        self.turned_rad += abs(d_true)
        self.error_rad += error
        by = set(touched)
        if not by:
            self.turned_undisturbed_rad += abs(d_true)
            self.error_undisturbed_rad += error
            self._open = None
            return
        dt = t_s - t0
        self.disturbed_s += dt
        for label in by:
            self.time_by[label] = self.time_by.get(label, 0.0) + dt
        if self._open is not None:
            self._open.to_s = t_s
            self._open.by |= by
        else:
            self.count += 1
            self._open = DisturbedPeriod(from_s=t0, to_s=t_s, by=by)
            if len(self.periods) < self.max_listed:
                self.periods.append(self._open)
        self.longest_s = max(self.longest_s, self._open.to_s - self._open.from_s)

    def contacts_summary(self) -> dict[str, Any]:
        """The summary's ``contacts``: how many disturbed periods, their total time, the time
        per thing that touched the robot, and the first periods."""
        return {"count": self.count, "time_s": self.disturbed_s,
                "longest_s": self.longest_s, "by": dict(self.time_by),
                "periods": [p.as_dict() for p in self.periods]}

    def heading_summary(self) -> dict[str, Any]:
        """The heading fields of the summary's ``odometry``: the error over the whole run and
        over its undisturbed intervals, each with the angle turned and their ratio."""
        return {
            "heading_error_deg": math.degrees(abs(self.error_rad)),
            "turned_deg": math.degrees(self.turned_rad),
            "heading_error_fraction": _fraction(self.error_rad, self.turned_rad),
            "undisturbed": {
                "heading_error_deg": math.degrees(abs(self.error_undisturbed_rad)),
                "turned_deg": math.degrees(self.turned_undisturbed_rad),
                "heading_error_fraction": _fraction(self.error_undisturbed_rad,
                                                    self.turned_undisturbed_rad),
            },
            "disturbed_heading_error_deg": math.degrees(
                abs(self.error_rad - self.error_undisturbed_rad)),
        }


def _fraction(error_rad: float, turned_rad: float) -> float | None:
    """``|error| / turned``: 0 for no error over no turn (error ≤ 10 % of turned holds), None
    for an error over no turn at all (no fraction: a criterion on it fails)."""
    if turned_rad > 0.0:
        return abs(error_rad) / turned_rad
    return 0.0 if error_rad == 0.0 else None
