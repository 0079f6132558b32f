"""Ray casting for the simulated IR range finders (pure geometry on a snapshot).

A sensor sits at a :class:`~components.range.backend.MountPose` in the robot frame (REP-103:
x forward, y left, yaw CCW from the robot's heading). Its beam is a ray in the floor plane from
the mount point; :func:`beam_distance_m` returns the distance **from the mount point** (not from
the robot's centre) to the first surface the ray meets: walls (infinitely thin segments), box
obstacles and box distractors (rectangles), cylinders, spheres and the ball (circles of their
radius; the beam is assumed to pass at the height of their widest section). The robot's own body
is ignored. A sensor whose mount point lies inside an object reads 0.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

from components.range.backend import MountPose
from components.sim.world.snapshot import WorldSnapshot

__all__ = ["Point", "beam_distance_m", "ray_box", "ray_circle", "ray_segment", "sensor_ray"]

Point = tuple[float, float]


def sensor_ray(snapshot: WorldSnapshot, mount: MountPose) -> tuple[Point, Point]:
    """World-frame origin and unit direction of a sensor's beam."""
    r = snapshot.robot
    c, s = math.cos(r.heading_rad), math.sin(r.heading_rad)
    origin = (r.x_m + c * mount.x_m - s * mount.y_m, r.y_m + s * mount.x_m + c * mount.y_m)
    yaw = r.heading_rad + mount.yaw_rad
    return origin, (math.cos(yaw), math.sin(yaw))


def ray_segment(origin: Point, direction: Point, a: Point, b: Point) -> float | None:
    """Distance along a unit ray to segment a–b, or None (parallel rays never hit)."""
    ox, oy = origin
    dx, dy = direction
    ex, ey = b[0] - a[0], b[1] - a[1]
    denom = dx * ey - dy * ex
    if abs(denom) < 1e-12:
        return None
    wx, wy = a[0] - ox, a[1] - oy
    t = (wx * ey - wy * ex) / denom
    u = (wx * dy - wy * dx) / denom
    if t >= 0.0 and -1e-12 <= u <= 1.0 + 1e-12:
        return t
    return None


def ray_circle(origin: Point, direction: Point, centre: Point, radius: float) -> float | None:
    """Distance along a unit ray to a circle's boundary; 0 if the origin is inside."""
    fx, fy = origin[0] - centre[0], origin[1] - centre[1]
    c = fx * fx + fy * fy - radius * radius
    if c <= 0.0:
        return 0.0
    b = fx * direction[0] + fy * direction[1]
    if b >= 0.0:
        return None  # pointing away
    disc = b * b - c
    if disc < 0.0:
        return None
    return -b - math.sqrt(disc)


def ray_box(
    origin: Point, direction: Point, centre: Point, yaw: float, length: float, width: float
) -> float | None:
    """Distance along a unit ray to a rotated rectangle (slab test); 0 if the origin is inside."""
    c, s = math.cos(yaw), math.sin(yaw)
    rx, ry = origin[0] - centre[0], origin[1] - centre[1]
    # Into the box frame.
    ox, oy = c * rx + s * ry, -s * rx + c * ry
    dx, dy = c * direction[0] + s * direction[1], -s * direction[0] + c * direction[1]
    t_min, t_max = -math.inf, math.inf
    for o, d, half in ((ox, dx, length / 2), (oy, dy, width / 2)):
        if abs(d) < 1e-12:
            if abs(o) > half:
                return None
            continue
        t1, t2 = (-half - o) / d, (half - o) / d
        if t1 > t2:
            t1, t2 = t2, t1
        t_min, t_max = max(t_min, t1), min(t_max, t2)
        if t_min > t_max:
            return None
    if t_max < 0.0:
        return None
    return max(t_min, 0.0)


def _hits(snapshot: WorldSnapshot, origin: Point, direction: Point) -> Iterable[float | None]:
    for wall in snapshot.walls:
        yield ray_segment(origin, direction, (wall.x1_m, wall.y1_m), (wall.x2_m, wall.y2_m))
    for box in snapshot.boxes:
        yield ray_box(
            origin, direction, (box.x_m, box.y_m), box.yaw_rad, box.length_m, box.width_m
        )
    for d in snapshot.distractors:
        if d.kind == "box":
            yield ray_box(origin, direction, (d.x_m, d.y_m), d.yaw_rad, d.length_m, d.width_m)
        else:
            yield ray_circle(origin, direction, (d.x_m, d.y_m), d.radius_m)
    if snapshot.ball is not None:
        ball = snapshot.ball
        yield ray_circle(origin, direction, (ball.x_m, ball.y_m), ball.radius_m)


def beam_distance_m(
    snapshot: WorldSnapshot, mount: MountPose, max_range_m: float
) -> float | None:
    """True distance from the sensor's mount point along its beam to the first surface.

    ``None`` when nothing lies within ``max_range_m``.
    """
    if not (math.isfinite(max_range_m) and max_range_m > 0.0):
        raise ValueError(f"max_range_m must be a positive finite number, got {max_range_m!r}")
    origin, direction = sensor_ray(snapshot, mount)
    best = math.inf
    for t in _hits(snapshot, origin, direction):
        if t is not None and t < best:
            best = t
    return best if best <= max_range_m else None
