"""Ready-made worlds. The thesis's four scenarios arrive as data in a later step; this is the
default world of ``python -m ubf_async.launch``."""

from __future__ import annotations

from components.sim.world import Arena, BallConfig, Distractor, Pose2D, WorldConfig


def ball_in_view(*, seed: int = 0) -> WorldConfig:
    """A 3 m × 3 m arena, the robot at its centre facing +x, the pink ball 0.9 m ahead and
    slightly to the left (inside the 35° field of view), an orange ball off to the right."""
    return WorldConfig(
        robot_start=Pose2D(x_m=0.0, y_m=0.0, heading_rad=0.0),
        ball=BallConfig(x_m=0.9, y_m=0.12),
        arena=Arena(),
        distractors=(Distractor(kind="sphere", x_m=1.2, y_m=-0.9),),
        seed=seed,
    )
