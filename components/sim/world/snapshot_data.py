"""World snapshots as plain data and back, for sim-backed devices in other processes.

Symmetric pure functions: ``snapshot_from_data(snapshot_to_data(s)) == s``. The simulator
publishes :func:`snapshot_to_data` on ``ubf/<robot>/sim/world``; a device process rebuilds the
snapshot and runs the same backends (ray casting, rendering) on it.
"""

from __future__ import annotations

from dataclasses import asdict
from typing import Any

from components.sim.world.config import BoxObstacle, Lighting, Wall
from components.sim.world.snapshot import BallState, DistractorState, RobotState, WorldSnapshot

__all__ = ["snapshot_from_data", "snapshot_to_data"]

# The world snapshot's topic (ubf_async.wire.topics.SIM_WORLD) is checked generically on the wire
# and then by snapshot_from_data.


def snapshot_to_data(snapshot: WorldSnapshot) -> dict[str, Any]:
    return asdict(snapshot)


def _with_color(cls: type, data: dict[str, Any]) -> Any:
    fields = dict(data)
    if "color" in fields:
        fields["color"] = tuple(fields["color"])
    return cls(**fields)


def snapshot_from_data(data: dict[str, Any]) -> WorldSnapshot:
    """Rebuild a snapshot; raises ``ValueError`` for data that is not one."""
    try:
        return WorldSnapshot(
            time_s=float(data["time_s"]),
            step_count=int(data["step_count"]),
            robot=RobotState(**data["robot"]),
            ball=None if data["ball"] is None else _with_color(BallState, data["ball"]),
            walls=tuple(_with_color(Wall, w) for w in data["walls"]),
            boxes=tuple(_with_color(BoxObstacle, b) for b in data["boxes"]),
            distractors=tuple(_with_color(DistractorState, d) for d in data["distractors"]),
            lighting=Lighting(**data["lighting"]),
        )
    except (KeyError, TypeError, AttributeError) as exc:
        raise ValueError(f"not a world snapshot: {exc!r}") from None
