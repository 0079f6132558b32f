"""Render the Mini-WHEGS camera's view of a :class:`~components.sim.world.WorldSnapshot`.

A pinhole camera sits at the robot's front (``mount_x_m`` ahead of the body centre), 4 cm above
the floor, looking forward and pitched up slightly, with the OV9655's 1280×1024 frame, ≈35°
horizontal field of view and square pixels. The picture is painted back to front (painter's
algorithm): a cached floor/backdrop, then walls (cut into short chunks), boxes and cylinders
(shaded prisms) and spheres (the ball and ball-like distractors, shaded per pixel), each sorted
by distance, and finally a little sensor noise from a pre-generated noise field shifted by a
random offset per frame.

Calibration (regenerate the table with ``python -m components.sim.calibrate``): the ball is lit
mostly from above (a hemispherical "sky" term that is full on its top and falls to nothing at its
bottom, plus an optional Lambert key light) and the camera is exposed for the room, so the top of
the ball rolls off to a washed-out pale pink and carries a white glare patch, the bottom rim sits
in the ball's own shadow, and only a band just above that shadow passes the thesis's pink rule.
With the defaults the largest seekcolor bin reads ≈140 with the ball ≈45 cm in front of the
camera, falls steadily with distance and still averages a couple of pixels at 3.6 m (the body's
bob, ``pitch_jitter_deg``, moves the thin far band across the subsampling grid). Because the band
is at the bottom of the ball it is the first part to leave the view, which happens at ≈31 cm, so
the count peaks at ≈30 cm and collapses closer in.

Neutral colours (floor, backdrop, default walls and boxes) keep their green channel above the pink
rule's limit of 120 or well above their blue channel, so noise cannot make them read pink; an
orange object can never pass either (its blue stays below its green).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import cv2
import numpy as np

from components.sim.world import Color, Lighting, WorldSnapshot

FRAME_WIDTH_PX = 1280
FRAME_HEIGHT_PX = 1024


@dataclass(frozen=True, slots=True, kw_only=True)
class CameraParams:
    """Camera model, scene colours and the ball-shading calibration."""

    width_px: int = FRAME_WIDTH_PX
    height_px: int = FRAME_HEIGHT_PX
    hfov_deg: float = 35.0
    mount_x_m: float = 0.05
    """Camera position ahead of the robot's centre (robot frame)."""
    mount_y_m: float = 0.0
    height_m: float = 0.04
    pitch_deg: float = 7.0
    """Upward tilt of the optical axis; puts the bottom of the view at ≈-7.2°, where a ball
    resting on the floor ≈31 cm ahead starts to leave the frame."""
    near_m: float = 0.01
    pitch_jitter_deg: float = 0.3
    """Standard deviation of the per-frame pitch wobble of the body (the wheel-legs make the
    robot bob); clipped to ±3σ and to ±1.5°. Only applied when rendering with an ``rng``."""

    floor_color: Color = (168, 160, 138)
    backdrop_color: Color = (204, 198, 182)
    """The far room above the horizon (neutral beige-grey)."""

    # Ball / sphere shading (calibrated, see calibrate.py). Linear radiance of a sphere pixel is
    #   exposure · brightness · (ambient + sky · ((1 + n_up) / 2) ** sky_exponent
    #                            + diffuse · max(0, n · L))
    # times the object's colour, rolled off toward white above 255 (see _tone_map); then a
    # white glare patch is blended in.
    exposure: float = 1.0
    """Overall gain of sphere shading (× Lighting.brightness). The camera is exposed for the
    room, so the top of the brightly lit ball saturates to a washed-out pinkish white."""
    ambient: float = 0.07
    """Light reaching the ball's own shadow at the bottom (the dark underside)."""
    sky: float = 2.8
    """Overhead (hemispherical) light: zero at the bottom of a sphere, full on its top."""
    sky_exponent: float = 0.5
    """Fall-off of the overhead light toward the bottom (1 = cosine-like, < 1 = broader)."""
    diffuse: float = 0.0
    """Lambert term for the key light (the ceiling lamp that also causes the glare)."""
    light_elevation_deg: float = 55.0
    """Key light elevation above the camera's line of sight (it comes from above the camera)."""
    light_azimuth_deg: float = 0.0
    """Key light azimuth, positive to the camera's right."""
    glare_radius_deg: float = 30.0
    """Angular radius of the white glare patch at Lighting.glare = 1 (scales linearly)."""
    glare_softness_deg: float = 10.0
    """Width of the glare patch's soft edge."""
    glare_strength: float = 1.0
    """Whiteness at the centre of the glare patch (0…1)."""

    noise_sigma: float = 2.0
    """Standard deviation of the per-pixel sensor noise (8-bit levels)."""
    noise_clip: int = 5
    """Noise is clipped to ±noise_clip levels."""

    wall_chunk_m: float = 0.2
    """Walls are painted as chunks of at most this length (keeps depth sorting sane)."""
    cylinder_sides: int = 16
    max_sphere_samples: int = 60_000
    """Spheres larger than this many pixels are shaded at a coarser grid and upscaled."""

    def __post_init__(self) -> None:
        if self.width_px <= 0 or self.height_px <= 0:
            raise ValueError("frame size must be positive")
        if not 1.0 < self.hfov_deg < 170.0:
            raise ValueError(f"hfov_deg must be within (1, 170), got {self.hfov_deg}")
        if self.height_m <= 0.0 or self.near_m <= 0.0:
            raise ValueError("height_m and near_m must be positive")
        if self.noise_sigma < 0.0 or self.noise_clip < 0:
            raise ValueError("noise_sigma and noise_clip must be >= 0")
        if self.cylinder_sides < 3 or self.wall_chunk_m <= 0.0 or self.max_sphere_samples < 1:
            raise ValueError("cylinder_sides >= 3, wall_chunk_m > 0, max_sphere_samples >= 1")

    @property
    def focal_px(self) -> float:
        """Focal length in pixels (square pixels: same in x and y)."""
        return (self.width_px / 2) / math.tan(math.radians(self.hfov_deg) / 2)

    @property
    def vfov_deg(self) -> float:
        return math.degrees(2 * math.atan((self.height_px / 2) / self.focal_px))


DEFAULT_CAMERA = CameraParams()


# --------------------------------------------------------------------------------------------
# Camera pose and projection
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class _Cam:
    position: np.ndarray
    """Camera centre in the world (3,)."""
    rot: np.ndarray
    """Rows: camera x (right), y (down), z (forward) axes in world coordinates (3, 3)."""
    f: float
    cx: float
    cy: float
    tan_x: float
    tan_y: float
    near: float

    def to_cam(self, pts: np.ndarray) -> np.ndarray:
        return (pts - self.position) @ self.rot.T


def camera_pose(
    snapshot: WorldSnapshot, params: CameraParams, *, pitch_offset_deg: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """World position (3,) and rotation (rows = camera right, down, forward) of the camera."""
    r = snapshot.robot
    c, s = math.cos(r.heading_rad), math.sin(r.heading_rad)
    pos = np.array(
        [
            r.x_m + c * params.mount_x_m - s * params.mount_y_m,
            r.y_m + s * params.mount_x_m + c * params.mount_y_m,
            params.height_m,
        ]
    )
    fwd = np.array([c, s, 0.0])
    left = np.array([-s, c, 0.0])
    up = np.array([0.0, 0.0, 1.0])
    p = math.radians(params.pitch_deg + pitch_offset_deg)
    z_axis = math.cos(p) * fwd + math.sin(p) * up
    y_axis = math.sin(p) * fwd - math.cos(p) * up
    x_axis = -left
    return pos, np.stack([x_axis, y_axis, z_axis])


def _make_cam(snapshot: WorldSnapshot, params: CameraParams, pitch_offset_deg: float) -> _Cam:
    pos, rot = camera_pose(snapshot, params, pitch_offset_deg=pitch_offset_deg)
    f = params.focal_px
    return _Cam(
        position=pos, rot=rot, f=f, cx=params.width_px / 2, cy=params.height_px / 2,
        tan_x=(params.width_px / 2) / f * 1.02, tan_y=(params.height_px / 2) / f * 1.02,
        near=params.near_m,
    )


def _clip_polygon(poly: np.ndarray, cam: _Cam) -> np.ndarray:
    """Clip a convex polygon (N×3, camera coords) to the slightly enlarged view frustum."""
    # Planes as (a, b, c) with inside where a·x + b·y + c·z >= d; d only for the near plane.
    planes = (
        (np.array([0.0, 0.0, 1.0]), cam.near),
        (np.array([-1.0, 0.0, cam.tan_x]), 0.0),
        (np.array([1.0, 0.0, cam.tan_x]), 0.0),
        (np.array([0.0, -1.0, cam.tan_y]), 0.0),
        (np.array([0.0, 1.0, cam.tan_y]), 0.0),
    )
    pts = poly
    for normal, d in planes:
        if len(pts) == 0:
            break
        dist = pts @ normal - d
        if np.all(dist >= 0.0):
            continue
        if np.all(dist < 0.0):
            return pts[:0]
        out = []
        n = len(pts)
        for i in range(n):
            a, b = pts[i], pts[(i + 1) % n]
            da, db = dist[i], dist[(i + 1) % n]
            if da >= 0.0:
                out.append(a)
            if (da >= 0.0) != (db >= 0.0):
                t = da / (da - db)
                out.append(a + t * (b - a))
        pts = np.array(out) if out else pts[:0]
    return pts


def _fill_polygon(frame: np.ndarray, cam: _Cam, world_pts: np.ndarray, color: np.ndarray) -> None:
    _fill_clipped(frame, cam, _clip_polygon(cam.to_cam(world_pts), cam), color)


_SUBPIXEL_SHIFT = 4
"""fillConvexPoly vertices carry 4 fractional bits."""


def _project(pts: np.ndarray, cam: _Cam) -> np.ndarray:
    """Camera-frame points (…×3, z > 0) to fixed-point pixel vertices for fillConvexPoly."""
    u = cam.cx + cam.f * pts[..., 0] / pts[..., 2]
    v = cam.cy + cam.f * pts[..., 1] / pts[..., 2]
    return np.round(np.stack([u, v], axis=-1) * float(1 << _SUBPIXEL_SHIFT)).astype(np.int32)


def _fill_projected(frame: np.ndarray, poly: np.ndarray, color: np.ndarray) -> None:
    rgb = tuple(int(c) for c in np.clip(color, 0, 255))
    cv2.fillConvexPoly(frame, poly, rgb, lineType=cv2.LINE_8, shift=_SUBPIXEL_SHIFT)


def _fill_clipped(frame: np.ndarray, cam: _Cam, pts: np.ndarray, color: np.ndarray) -> None:
    if len(pts) >= 3:
        _fill_projected(frame, _project(pts, cam), color)


def _frustum_distances(pts: np.ndarray, cam: _Cam) -> np.ndarray:
    """Signed distances (…×5) of camera-frame points to the planes :func:`_clip_polygon` uses
    (near, left, right, top, bottom); inside where all are >= 0."""
    x, y, z = pts[..., 0], pts[..., 1], pts[..., 2]
    return np.stack(
        [z - cam.near, -x + cam.tan_x * z, x + cam.tan_x * z, -y + cam.tan_y * z,
         y + cam.tan_y * z], axis=-1,
    )


# --------------------------------------------------------------------------------------------
# Background and noise (cached)
# --------------------------------------------------------------------------------------------


_BG_MARGIN = 64
"""Extra rows above and below the cached background, so a pitch wobble is a row offset."""
_MAX_JITTER_DEG = 1.5


@functools.lru_cache(maxsize=8)
def _background(params: CameraParams) -> np.ndarray:
    """Floor below the horizon, backdrop above; a gentle vertical gradient, never pink.

    ``_BG_MARGIN`` extra rows above and below: row ``_BG_MARGIN + v`` is image row ``v`` at the
    nominal pitch.
    """
    w = params.width_px
    h = params.height_px + 2 * _BG_MARGIN
    f = params.focal_px
    horizon = params.height_px / 2 + f * math.tan(math.radians(params.pitch_deg)) + _BG_MARGIN
    rows = np.arange(h, dtype=np.float32) + 0.5
    floor = np.asarray(params.floor_color, dtype=np.float32)
    back = np.asarray(params.backdrop_color, dtype=np.float32)
    below = rows >= horizon
    # Floor: slightly darker toward the bottom (near the robot), lighter at the horizon.
    t_floor = np.clip((rows - horizon) / max(h - horizon, 1.0), 0.0, 1.0)
    floor_rows = floor[None, :] * (1.0 - 0.06 * t_floor)[:, None]
    # Backdrop: slightly lighter upward.
    t_back = np.clip((horizon - rows) / max(horizon, 1.0), 0.0, 1.0)
    back_rows = np.minimum(back[None, :] * (1.0 + 0.04 * t_back)[:, None], 255.0)
    column = np.where(below[:, None], floor_rows, back_rows)
    image = np.broadcast_to(np.round(column).astype(np.uint8)[:, None, :], (h, w, 3)).copy()
    image.setflags(write=False)
    return image


_NOISE_PAD = 61


@functools.lru_cache(maxsize=4)
def _noise_planes(h: int, w: int, sigma: float, clip: int) -> tuple[np.ndarray, np.ndarray]:
    """Positive and negative parts of a fixed noise field a little larger than the frame."""
    gen = np.random.default_rng(0x5EED)
    noise = np.clip(np.round(gen.normal(0.0, sigma, (h + _NOISE_PAD, w + _NOISE_PAD, 3))),
                    -clip, clip).astype(np.int16)
    pos = np.maximum(noise, 0).astype(np.uint8)
    neg = np.maximum(-noise, 0).astype(np.uint8)
    pos.setflags(write=False)
    neg.setflags(write=False)
    return pos, neg


def warm_up(params: CameraParams = DEFAULT_CAMERA) -> None:
    """Build the cached background and noise field for ``params`` now (they take a few hundred
    milliseconds the first time; every frame after reuses them)."""
    _background(params)
    if params.noise_sigma > 0.0 and params.noise_clip > 0:
        _noise_planes(params.height_px, params.width_px, params.noise_sigma, params.noise_clip)


def _add_noise(frame: np.ndarray, params: CameraParams, rng: np.random.Generator) -> None:
    if params.noise_sigma <= 0.0 or params.noise_clip == 0:
        return
    h, w = frame.shape[:2]
    pos, neg = _noise_planes(h, w, params.noise_sigma, params.noise_clip)
    oy, ox, oy2, ox2 = (int(v) for v in rng.integers(0, _NOISE_PAD + 1, size=4))
    cv2.add(frame, pos[oy:oy + h, ox:ox + w], dst=frame)
    cv2.subtract(frame, neg[oy2:oy2 + h, ox2:ox2 + w], dst=frame)


# --------------------------------------------------------------------------------------------
# Primitives
# --------------------------------------------------------------------------------------------


def _shade(color: Color, factor: float) -> np.ndarray:
    return np.asarray(color, dtype=np.float64) * factor


def _face_factor(normal_xy: np.ndarray, to_face_xy: np.ndarray) -> float:
    """Flat shading of a vertical face: brighter the more squarely it faces the camera."""
    norm = float(np.linalg.norm(to_face_xy))
    if norm == 0.0:
        return 1.0
    facing = max(0.0, -float(normal_xy @ to_face_xy) / norm)
    return 0.8 + 0.2 * facing


def _draw_prism(
    frame: np.ndarray, cam: _Cam, footprint: np.ndarray, height: float, color: Color,
    brightness: float,
) -> None:
    """A convex vertical prism standing on the floor; footprint is CCW (N×2)."""
    n = len(footprint)
    cam_xy = cam.position[:2]
    for i in range(n):
        a, b = footprint[i], footprint[(i + 1) % n]
        edge = b - a
        normal = np.array([edge[1], -edge[0]])
        length = float(np.linalg.norm(normal))
        if length == 0.0:
            continue
        normal /= length
        mid = 0.5 * (a + b)
        if float(normal @ (mid - cam_xy)) >= 0.0:
            continue  # back face
        quad = np.array(
            [[a[0], a[1], 0.0], [b[0], b[1], 0.0], [b[0], b[1], height], [a[0], a[1], height]]
        )
        factor = _face_factor(normal, mid - cam_xy) * brightness
        _fill_polygon(frame, cam, quad, _shade(color, factor))
    if cam.position[2] > height:
        top = np.column_stack([footprint, np.full(n, height)])
        _fill_polygon(frame, cam, top, _shade(color, 1.0 * brightness))


def _sphere_light(params: CameraParams) -> tuple[np.ndarray, np.ndarray]:
    el = math.radians(params.light_elevation_deg)
    az = math.radians(params.light_azimuth_deg)
    light = np.array([math.cos(el) * math.sin(az), math.sin(el), math.cos(el) * math.cos(az)])
    half = light + np.array([0.0, 0.0, 1.0])
    half /= np.linalg.norm(half)
    return light, half


def _tone_map(lin: np.ndarray) -> np.ndarray:
    """Hue-preserving highlight roll-off: a colour brighter than 255 in its strongest channel is
    scaled back to 255 there and washed toward white by the fraction it overshot (an over-exposed
    pink reads pale pink, an over-exposed orange pale orange, rather than clipping per channel)."""
    peak = np.maximum(lin.max(axis=-1, keepdims=True), np.float32(1e-6))
    scale = np.minimum(np.float32(255.0) / peak, np.float32(1.0))
    based = lin * scale
    return based + (np.float32(255.0) - based) * (np.float32(1.0) - scale)


def _draw_sphere(
    frame: np.ndarray, cam: _Cam, centre: np.ndarray, radius: float, color: Color,
    params: CameraParams, lighting: Lighting,
) -> None:
    """A shaded sphere: overhead + key light + ambient, over-exposure roll-off, glare patch."""
    xc, yc, zc = cam.to_cam(centre[None, :])[0]
    dist = math.sqrt(xc * xc + yc * yc + zc * zc)
    if zc <= cam.near or dist <= radius:
        return
    rad_px = cam.f * math.tan(math.asin(radius / dist))
    u0 = cam.cx + cam.f * xc / zc
    v0 = cam.cy + cam.f * yc / zc
    h, w = frame.shape[:2]
    x0, x1 = max(0, math.floor(u0 - rad_px)), min(w, math.ceil(u0 + rad_px) + 1)
    y0, y1 = max(0, math.floor(v0 - rad_px)), min(h, math.ceil(v0 + rad_px) + 1)
    if x0 >= x1 or y0 >= y1:
        return
    step = max(1, math.ceil(math.sqrt((x1 - x0) * (y1 - y0) / params.max_sphere_samples)))
    # Normalised disk coordinates of the sample pixels' centres (x right, y down).
    xs = ((np.arange(x0, x1, step, dtype=np.float32) + 0.5 - u0) / rad_px)[None, :]
    ys = ((np.arange(y0, y1, step, dtype=np.float32) + 0.5 - v0) / rad_px)[:, None]
    rho2 = xs * xs + ys * ys
    inside = rho2 < 1.0
    if not inside.any():
        return
    light, half = _sphere_light(params)
    need_normal_z = params.diffuse > 0.0 or (
        params.glare_radius_deg * lighting.glare > 0.0 and params.glare_strength > 0.0
    )
    nz = np.sqrt(np.maximum(1.0 - rho2, 0.0)) if need_normal_z else None
    # Overhead light depends on the row only: n_up = -y (view frame: x right, y up, z to camera).
    gain = params.exposure * lighting.brightness
    up = np.clip(0.5 * (1.0 - ys), 0.0, 1.0)
    intensity = gain * (params.ambient + params.sky * np.power(up, params.sky_exponent))
    if params.diffuse > 0.0:
        assert nz is not None
        ndotl = xs * np.float32(light[0]) - ys * np.float32(light[1]) + nz * np.float32(light[2])
        intensity = intensity + np.float32(gain * params.diffuse) * np.maximum(ndotl, 0.0)
    lin = _tone_map(intensity[..., None] * np.asarray(color, dtype=np.float32))
    glare_deg = params.glare_radius_deg * lighting.glare
    if glare_deg > 0.0 and params.glare_strength > 0.0:
        assert nz is not None
        ndoth = xs * np.float32(half[0]) - ys * np.float32(half[1]) + nz * np.float32(half[2])
        soft = max(params.glare_softness_deg, 1e-3)
        cos_in = math.cos(math.radians(min(glare_deg, 180.0)))
        cos_out = math.cos(math.radians(min(glare_deg + soft, 180.0)))
        if cos_in - cos_out > 1e-9:
            weight = np.clip((ndoth - np.float32(cos_out)) / np.float32(cos_in - cos_out), 0.0, 1.0)
        else:
            weight = (ndoth >= cos_in).astype(np.float32)
        weight = (weight * np.float32(params.glare_strength))[..., None]
        lin = lin + (np.float32(255.0) - lin) * weight
    sprite = np.clip(lin, 0.0, 255.0).astype(np.uint8)
    mask = inside.astype(np.uint8)
    if sprite.shape[:2] != mask.shape:
        sprite = np.ascontiguousarray(np.broadcast_to(sprite, (*mask.shape, 3)))
    if step > 1:
        size = (x1 - x0, y1 - y0)
        sprite = cv2.resize(sprite, size, interpolation=cv2.INTER_NEAREST)
        mask = cv2.resize(mask, size, interpolation=cv2.INTER_NEAREST)
    cv2.copyTo(sprite, mask, frame[y0:y1, x0:x1])


# --------------------------------------------------------------------------------------------
# Renderer
# --------------------------------------------------------------------------------------------


def _circle_footprint(x: float, y: float, radius: float, sides: int) -> np.ndarray:
    t = np.linspace(0.0, 2 * math.pi, sides, endpoint=False)
    # Circumscribe so the silhouette is not smaller than the circle.
    r = radius / math.cos(math.pi / sides)
    return np.column_stack([x + r * np.cos(t), y + r * np.sin(t)])


def _box_footprint(x: float, y: float, yaw: float, length: float, width: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    local = np.array(
        [[length / 2, -width / 2], [length / 2, width / 2], [-length / 2, width / 2],
         [-length / 2, -width / 2]]
    )
    return local @ np.array([[c, s], [-s, c]]) + np.array([x, y])


def _wall_items(
    snapshot: WorldSnapshot, params: CameraParams, cam: _Cam
) -> list[tuple[float, int, object]]:
    """Paint items (kind 0) for the wall chunks in view, computed for all chunks at once.

    A chunk wholly outside one frustum plane is dropped; one wholly inside is projected here;
    only the few that straddle the frustum's edge are clipped polygon by polygon. Each item's
    payload is ``(camera-frame quad, projected vertices or None, colour)``."""
    quads, normals, colors = [], [], []
    for wall in snapshot.walls:
        a = np.array([wall.x1_m, wall.y1_m])
        b = np.array([wall.x2_m, wall.y2_m])
        n = max(1, math.ceil(wall.length_m / params.wall_chunk_m))
        pts = a[None, :] + np.linspace(0.0, 1.0, n + 1)[:, None] * (b - a)[None, :]
        p, q = pts[:-1], pts[1:]
        zero, top = np.zeros(n), np.full(n, wall.height_m)
        quads.append(np.stack([
            np.column_stack([p, zero]), np.column_stack([q, zero]),
            np.column_stack([q, top]), np.column_stack([p, top]),
        ], axis=1))
        edge = b - a
        normals.append(np.broadcast_to(np.array([edge[1], -edge[0]]) / wall.length_m, (n, 2)))
        colors.append(np.broadcast_to(np.asarray(wall.color, dtype=np.float64), (n, 3)))
    if not quads:
        return []
    world = np.concatenate(quads)  # chunks × 4 corners × xyz
    to_face = 0.5 * (world[:, 0, :2] + world[:, 1, :2]) - cam.position[:2]
    depth = np.linalg.norm(to_face, axis=1)
    # Flat shading, brighter the more squarely a chunk faces the camera (either side).
    facing = np.abs(np.einsum("ij,ij->i", np.concatenate(normals), to_face))
    factor = np.where(depth > 0.0, 0.8 + 0.2 * facing / np.where(depth > 0.0, depth, 1.0), 1.0)
    rgb = np.concatenate(colors) * (factor * snapshot.lighting.brightness)[:, None]
    pts = cam.to_cam(world.reshape(-1, 3)).reshape(world.shape)
    inside = _frustum_distances(pts, cam) >= 0.0  # chunks × corners × planes
    culled = (~inside.any(axis=1)).any(axis=1)  # some plane has every corner outside
    whole = inside.all(axis=(1, 2))
    projected = _project(np.where(whole[:, None, None], pts, 1.0), cam)
    return [
        (float(depth[i]), 0, (pts[i], projected[i] if whole[i] else None, rgb[i]))
        for i in np.flatnonzero(~culled)
    ]


def render_camera(
    snapshot: WorldSnapshot,
    params: CameraParams = DEFAULT_CAMERA,
    rng: np.random.Generator | None = None,
) -> np.ndarray:
    """Render the robot's camera view: an ``H×W×3`` ``uint8`` RGB frame (1024×1280 default).

    ``rng`` drives the per-frame sensor noise; ``None`` renders a noise-free frame.
    """
    jitter_deg = 0.0
    if rng is not None and params.pitch_jitter_deg > 0.0:
        limit = min(3.0 * params.pitch_jitter_deg, _MAX_JITTER_DEG)
        jitter_deg = float(np.clip(rng.normal(0.0, params.pitch_jitter_deg), -limit, limit))
    cam = _make_cam(snapshot, params, jitter_deg)
    # Pitching up moves the horizon down the image: take the background rows higher up.
    f = params.focal_px
    p0 = math.radians(params.pitch_deg)
    shift = round(f * (math.tan(p0 + math.radians(jitter_deg)) - math.tan(p0)))
    top = _BG_MARGIN - shift
    frame = _background(params)[top:top + params.height_px].copy()
    lighting = snapshot.lighting
    cam_xy = cam.position[:2]
    items: list[tuple[float, int, object]] = []  # (depth, kind, payload)

    items.extend(_wall_items(snapshot, params, cam))

    for box in snapshot.boxes:
        fp = _box_footprint(box.x_m, box.y_m, box.yaw_rad, box.length_m, box.width_m)
        depth = float(np.linalg.norm(np.array([box.x_m, box.y_m]) - cam_xy))
        items.append((depth, 1, (fp, box.height_m, box.color)))

    for d in snapshot.distractors:
        depth = float(np.linalg.norm(np.array([d.x_m, d.y_m]) - cam_xy))
        if d.kind == "sphere":
            centre = np.array([d.x_m, d.y_m, d.radius_m])
            items.append((depth, 2, (centre, d.radius_m, d.color)))
        elif d.kind == "cylinder":
            fp = _circle_footprint(d.x_m, d.y_m, d.radius_m, params.cylinder_sides)
            items.append((depth, 1, (fp, d.height_m, d.color)))
        else:
            fp = _box_footprint(d.x_m, d.y_m, d.yaw_rad, d.length_m, d.width_m)
            items.append((depth, 1, (fp, d.height_m, d.color)))

    ball = snapshot.ball
    if ball is not None:
        depth = float(np.linalg.norm(np.array([ball.x_m, ball.y_m]) - cam_xy))
        centre = np.array([ball.x_m, ball.y_m, ball.radius_m])
        items.append((depth, 2, (centre, ball.radius_m, ball.color)))

    items.sort(key=lambda item: -item[0])
    for _depth, kind, payload in items:
        if kind == 0:
            pts, projected, rgb = payload  # type: ignore[misc]
            if projected is not None:
                _fill_projected(frame, projected, rgb)
            else:
                _fill_clipped(frame, cam, _clip_polygon(pts, cam), rgb)
        elif kind == 1:
            fp, height, color = payload  # type: ignore[misc]
            _draw_prism(frame, cam, fp, height, color, lighting.brightness)
        else:
            centre, radius, color = payload  # type: ignore[misc]
            _draw_sphere(frame, cam, centre, radius, color, params, lighting)

    if rng is not None:
        _add_noise(frame, params, rng)
    return frame
