"""Render a robot camera's view of a :class:`~components.sim.world.snapshot.WorldSnapshot`.

A pinhole camera (no lens distortion: a wide lens is rendered as an ideal rectilinear one) sits
where its device's mount says (:meth:`CameraParams.mounted`); by default the Mini-WHEGS's: at
the robot's front (``mount_x_m`` ahead of the body centre), 4 cm above the floor, looking
forward and pitched up slightly, with the OV9655's 1280×1024 frame, ≈35° horizontal field of
view and square pixels. The picture is painted back to front (painter's
algorithm): a cached floor/backdrop, then walls (cut into short chunks), boxes and cylinders
(shaded prisms) and spheres (the ball and ball-like distractors, shaded per pixel), each sorted
by distance, and finally a little sensor noise from a pre-generated noise field shifted by a
random offset per frame.

Calibration (regenerate the table with ``python -m components.sim.render.calibrate``): the ball
is lit mostly from above (a hemispherical "sky" term that is full on its top and falls to
nothing at its bottom, plus an optional Lambert key light) and the camera is exposed for the
room, so the top of the ball rolls off to a washed-out pale pink and carries a white glare
patch, the bottom rim sits in the ball's own shadow, and only a band just above that shadow
passes the thesis's pink rule. With the defaults the largest seekcolor bin reads ≈140 with the
ball ≈45 cm in front of the camera, falls steadily with distance and still averages a couple of
pixels at 3.6 m (the body's bob, ``pitch_jitter_deg``, moves the thin far band across the
subsampling grid). The band is at the bottom of the ball, the first part to leave the view (at
≈31 cm); but by then the ball covers enough of the view for the auto exposure
(``auto_exposure_coverage``, from ≈40 cm) to turn the gain of the whole picture down, and the
glare with it, so the band moves up the ball and the count keeps growing down to contact (the
whole view pink).

``render_camera(..., grid=8)`` renders only the pixels seekcolor's subsampler reads (every 8th
in x and y) into a 160×128 image — the camera device's sparse frames — with the same colours
as the full frame at those pixels (same noise, same bob; polygons are shrunk so they cover the
grid pixels they cover in the full frame). Static geometry (wall chunks), the background rows
and the noise field's grid phases are cached.

Neutral colours (floor, backdrop, default walls and boxes) keep their green channel above the pink
rule's limit of 120 or well above their blue channel, so noise cannot make them read pink; an
orange object can never pass either (its blue stays below its green).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, replace
from typing import Any

import cv2
import numpy as np

from components.camera.backend import DEFAULT_MOUNT, CameraMount
from components.sim.world.config import Color, Lighting, Wall
from components.sim.world.snapshot import WorldSnapshot

__all__ = ["DEFAULT_CAMERA", "FRAME_HEIGHT_PX", "FRAME_WIDTH_PX", "CameraParams",
           "auto_exposure_gain", "camera_pose", "render_camera", "warm_up"]

FRAME_WIDTH_PX = DEFAULT_MOUNT.width_px
FRAME_HEIGHT_PX = DEFAULT_MOUNT.height_px


@dataclass(frozen=True, slots=True, kw_only=True)
class CameraParams:
    """Camera model, scene colours and the ball-shading calibration."""

    width_px: int = FRAME_WIDTH_PX
    height_px: int = FRAME_HEIGHT_PX
    hfov_deg: float = DEFAULT_MOUNT.hfov_deg
    mount_x_m: float = DEFAULT_MOUNT.x_m
    """Camera position ahead of the robot's centre (robot frame)."""
    mount_y_m: float = DEFAULT_MOUNT.y_m
    height_m: float = DEFAULT_MOUNT.z_m
    yaw_deg: float = DEFAULT_MOUNT.yaw_deg
    """Where the optical axis points, + to the left of the robot's heading."""
    pitch_deg: float = DEFAULT_MOUNT.pitch_deg
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
    glare_exposure_power: float = 3.0
    """The glare patch is the lamp's reflection saturating the sensor: with the auto
    exposure's gain ``g`` < 1 its whiteness is ``glare_strength · g ** glare_exposure_power``
    (at the ≈30 % gain of a ball at contact the highlight no longer saturates and the ball
    reads pink across)."""

    auto_exposure_coverage: float = 0.07
    """Auto exposure: the camera is exposed for the room until bright, shiny objects (the
    spheres: the ball, ball-like distractors) cover more than this fraction of the view; then
    it turns the gain of the whole picture down (see ``auto_exposure_power``). With the
    defaults that starts with the ball ≈40 cm in front of the camera."""
    auto_exposure_power: float = 0.45
    """Gain at coverage ``c`` above ``auto_exposure_coverage`` = ``(coverage_limit / c) **
    power``: a ball filling the view (contact) is shown at ≈30 % gain, so its lit top is no
    longer washed out and the pink band moves up the ball as its bottom leaves the view."""

    noise_sigma: float = 2.0
    """Standard deviation of the per-pixel sensor noise (8-bit levels)."""
    noise_clip: int = 5
    """Noise is clipped to ±noise_clip levels."""

    wall_chunk_m: float = 0.2
    """Walls are painted as chunks of at most this length (keeps depth sorting sane)."""
    cylinder_sides: int = 16
    max_sphere_samples: int = 250_000
    """Spheres larger than this many pixels are shaded at a coarser grid and upscaled (a ball
    closer than ≈27 cm in a full frame; a grid image never has that many)."""

    def __post_init__(self) -> None:
        if self.width_px <= 0 or self.height_px <= 0:
            raise ValueError("frame size must be positive")
        if not 1.0 < self.hfov_deg < 170.0:
            raise ValueError(f"hfov_deg must be within (1, 170), got {self.hfov_deg}")
        if self.height_m <= 0.0 or self.near_m <= 0.0:
            raise ValueError("height_m and near_m must be positive")
        if self.noise_sigma < 0.0 or self.noise_clip < 0:
            raise ValueError("noise_sigma and noise_clip must be >= 0")
        if not 0.0 < self.auto_exposure_coverage <= 1.0 or self.auto_exposure_power < 0.0:
            raise ValueError("auto_exposure_coverage must be in (0, 1], auto_exposure_power >= 0")
        if self.glare_exposure_power < 0.0:
            raise ValueError("glare_exposure_power must be >= 0")
        if self.cylinder_sides < 3 or self.wall_chunk_m <= 0.0 or self.max_sphere_samples < 1:
            raise ValueError("cylinder_sides >= 3, wall_chunk_m > 0, max_sphere_samples >= 1")

    def mounted(self, mount: CameraMount) -> CameraParams:
        """These parameters with a camera device's mount, lens and frame."""
        return replace(self, mount_x_m=mount.x_m, mount_y_m=mount.y_m, height_m=mount.z_m,
                       yaw_deg=mount.yaw_deg, pitch_deg=mount.pitch_deg,
                       hfov_deg=mount.hfov_deg, width_px=mount.width_px,
                       height_px=mount.height_px)

    @property
    def focal_px(self) -> float:
        """Focal length in pixels (square pixels: same in x and y)."""
        return (self.width_px / 2) / math.tan(math.radians(self.hfov_deg) / 2)



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
    grid: int = 1
    """Pixel pitch of the rendered image in full-frame pixels: 1 renders every pixel, 8
    renders only the full frame's pixels ``(8·i, 8·j)`` (what seekcolor's subsampler reads)
    into an image 8× smaller each way. ``f``, ``cx`` and ``cy`` stay in full-frame pixels."""

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
    if params.yaw_deg:  # a camera turned on its mount looks off the robot's heading
        look = r.heading_rad + math.radians(params.yaw_deg)
        c, s = math.cos(look), math.sin(look)
    fwd = np.array([c, s, 0.0])
    left = np.array([-s, c, 0.0])
    up = np.array([0.0, 0.0, 1.0])
    p = math.radians(params.pitch_deg + pitch_offset_deg)
    z_axis = math.cos(p) * fwd + math.sin(p) * up
    y_axis = math.sin(p) * fwd - math.cos(p) * up
    x_axis = -left
    return pos, np.stack([x_axis, y_axis, z_axis])


def _make_cam(
    snapshot: WorldSnapshot, params: CameraParams, pitch_offset_deg: float, grid: int = 1
) -> _Cam:
    pos, rot = camera_pose(snapshot, params, pitch_offset_deg=pitch_offset_deg)
    f = params.focal_px
    return _Cam(
        position=pos, rot=rot, f=f, cx=params.width_px / 2, cy=params.height_px / 2,
        tan_x=(params.width_px / 2) / f * 1.02, tan_y=(params.height_px / 2) / f * 1.02,
        near=params.near_m, grid=grid,
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
    """Camera-frame points (…×3, z > 0) to fixed-point pixel vertices for fillConvexPoly.

    On a grid image (``cam.grid`` = g > 1) full-frame pixel (g·i, g·j) is image pixel (i, j),
    so the vertices are divided by g, and each polygon (the last two axes: corners × uv) is
    shrunk by :func:`_erode` so it covers the grid pixels it covers in the full frame."""
    u = cam.cx + cam.f * pts[..., 0] / pts[..., 2]
    v = cam.cy + cam.f * pts[..., 1] / pts[..., 2]
    uv = np.stack([u, v], axis=-1)
    if cam.grid > 1:
        uv = _erode(uv / cam.grid, 0.5 - 0.5 / cam.grid)
    return np.round(uv * float(1 << _SUBPIXEL_SHIFT)).astype(np.int32)


_GONE = -1000.0
"""Where an eroded-away polygon's corners go: off the image, so nothing is drawn."""


def _erode(poly: np.ndarray, delta: float) -> np.ndarray:
    """Convex polygons (…×N×2, image pixels) moved in by ``delta`` pixels along x and y.

    fillConvexPoly fills a pixel whose centre lies within about half a pixel *outside* a
    polygon's edge. In the full frame that is half a full pixel; on a grid image it would be
    half a grid pixel (``g/2`` full pixels), so the grid image's polygons are shrunk by the
    difference first: each edge moves in by ``delta·(|n_x| + |n_y|)`` (the erosion by a
    ``2·delta`` square). A polygon thinner than that vanishes (its corners go off-image)."""
    n = poly.shape[-2]
    after = (np.arange(n) + 1) % n
    before = (np.arange(n) - 1) % n
    nxt = poly[..., after, :]
    edge = nxt - poly
    length = np.hypot(edge[..., 0], edge[..., 1])
    area2 = np.sum(poly[..., 0] * nxt[..., 1] - nxt[..., 0] * poly[..., 1], axis=-1)
    sign = np.where(area2 >= 0.0, 1.0, -1.0)[..., None, None]
    safe = np.where(length > 1e-9, length, 1.0)
    # Inward unit normals (image axes: x right, y down; for positive area2 the inside is to
    # the right of each edge when walking it, i.e. at (-e_y, e_x)).
    normal = np.stack([-edge[..., 1], edge[..., 0]], axis=-1) * (sign / safe[..., None])
    normal = np.where((length > 1e-9)[..., None], normal, 0.0)
    offset = delta * (np.abs(normal[..., 0]) + np.abs(normal[..., 1]))
    # Corner k joins edge k-1 (before) and edge k (after): solve x·n1 = d1, x·n2 = d2.
    n1, d1 = normal[..., before, :], offset[..., before]
    n2, d2 = normal, offset
    det = n1[..., 0] * n2[..., 1] - n1[..., 1] * n2[..., 0]
    ok = np.abs(det) > 1e-6
    safe_det = np.where(ok, det, 1.0)
    x = (d1 * n2[..., 1] - d2 * n1[..., 1]) / safe_det
    y = (n1[..., 0] * d2 - n2[..., 0] * d1) / safe_det
    # Parallel (or missing) neighbours: move along whichever normal there is.
    has1 = (np.abs(n1[..., 0]) + np.abs(n1[..., 1])) > 0.0
    fx = np.where(has1, d1 * n1[..., 0], d2 * n2[..., 0])
    fy = np.where(has1, d1 * n1[..., 1], d2 * n2[..., 1])
    moved = poly + np.stack([np.where(ok, x, fx), np.where(ok, y, fy)], axis=-1)
    nxt2 = moved[..., after, :]
    area2_new = np.sum(moved[..., 0] * nxt2[..., 1] - nxt2[..., 0] * moved[..., 1], axis=-1)
    gone = (area2_new * area2 <= 0.0) | (np.abs(area2_new) < 1e-9)
    return np.where(gone[..., None, None], _GONE, moved)


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


@functools.lru_cache(maxsize=4 * (2 * _BG_MARGIN + 1))
def _background_grid(params: CameraParams, top: int, grid: int) -> np.ndarray:
    """The background's rows ``top … top + height`` at the grid pixels (cached: the body's
    bob only ever picks one of ``2·_BG_MARGIN + 1`` offsets)."""
    image = np.ascontiguousarray(_background(params)[top:top + params.height_px:grid, ::grid])
    image.setflags(write=False)
    return image


def warm_up(params: CameraParams = DEFAULT_CAMERA, *, grid: int = 1) -> None:
    """Build the cached background and noise field for ``params`` now (they take a few hundred
    milliseconds the first time; every frame after reuses them), and for a grid image
    (``grid`` > 1) the noise field's grid phases too."""
    _background(params)
    if params.noise_sigma > 0.0 and params.noise_clip > 0:
        _noise_planes(params.height_px, params.width_px, params.noise_sigma, params.noise_clip)
        if grid > 1:
            for phase_y in range(grid):
                for phase_x in range(grid):
                    _noise_grid(params.height_px, params.width_px, params.noise_sigma,
                                params.noise_clip, grid, phase_y, phase_x)


@functools.lru_cache(maxsize=512)
def _noise_grid(
    h: int, w: int, sigma: float, clip: int, grid: int, phase_y: int, phase_x: int
) -> tuple[np.ndarray, np.ndarray]:
    """The noise field's pixels ``(phase_y + grid·j, phase_x + grid·i)``, contiguous: a grid
    image at offset ``(oy, ox)`` reads rows/columns ``oy // grid …`` of phase
    ``(oy % grid, ox % grid)``."""
    pos, neg = _noise_planes(h, w, sigma, clip)
    out = (np.ascontiguousarray(pos[phase_y::grid, phase_x::grid]),
           np.ascontiguousarray(neg[phase_y::grid, phase_x::grid]))
    for plane in out:
        plane.setflags(write=False)
    return out


def _add_noise(
    frame: np.ndarray, params: CameraParams, rng: np.random.Generator, grid: int = 1
) -> None:
    """Add the noise field at a random offset; on a grid image (``grid`` > 1) the field's
    values at the full frame's grid pixels, so both see the same noise."""
    if params.noise_sigma <= 0.0 or params.noise_clip == 0:
        return
    h, w = frame.shape[:2]
    oy, ox, oy2, ox2 = (int(v) for v in rng.integers(0, _NOISE_PAD + 1, size=4))
    full_h, full_w = params.height_px, params.width_px
    if grid == 1:
        pos, neg = _noise_planes(full_h, full_w, params.noise_sigma, params.noise_clip)
    else:
        pos = _noise_grid(full_h, full_w, params.noise_sigma, params.noise_clip, grid,
                          oy % grid, ox % grid)[0]
        neg = _noise_grid(full_h, full_w, params.noise_sigma, params.noise_clip, grid,
                          oy2 % grid, ox2 % grid)[1]
        oy, ox, oy2, ox2 = oy // grid, ox // grid, oy2 // grid, ox2 // grid
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


def _sphere_disk(cam: _Cam, centre: np.ndarray, radius: float) -> tuple[float, float, float] | None:
    """The sphere's outline in the full frame: centre ``(u, v)`` and radius in pixels (None
    when it is behind the camera or the camera is inside it)."""
    xc, yc, zc = cam.to_cam(centre[None, :])[0]
    dist = math.sqrt(xc * xc + yc * yc + zc * zc)
    if zc <= cam.near or dist <= radius:
        return None
    rad_px = cam.f * math.tan(math.asin(radius / dist))
    return cam.cx + cam.f * xc / zc, cam.cy + cam.f * yc / zc, rad_px


_COVERAGE_SAMPLES = 48


def _disk_in_frame_px(u0: float, v0: float, rad_px: float, width: int, height: int) -> float:
    """Area (full-frame pixels) of the disk that lies within the frame, by sampling the part
    of its bounding box inside the frame on a 48 × 48 grid."""
    x0, x1 = max(0.0, u0 - rad_px), min(float(width), u0 + rad_px)
    y0, y1 = max(0.0, v0 - rad_px), min(float(height), v0 + rad_px)
    if x0 >= x1 or y0 >= y1:
        return 0.0
    n = _COVERAGE_SAMPLES
    xs = x0 + (np.arange(n) + 0.5) * ((x1 - x0) / n) - u0
    ys = y0 + (np.arange(n) + 0.5) * ((y1 - y0) / n) - v0
    inside = np.count_nonzero(xs[None, :] ** 2 + ys[:, None] ** 2 < rad_px * rad_px)
    return float(inside) / (n * n) * (x1 - x0) * (y1 - y0)


def auto_exposure_gain(
    disks: list[tuple[float, float, float]], params: CameraParams = DEFAULT_CAMERA
) -> float:
    """The auto exposure's gain (≤ 1) for spheres seen as ``disks`` (``(u, v, radius_px)`` in
    the full frame): 1 while they cover at most ``auto_exposure_coverage`` of the view (the
    camera is exposed for the room), ``(limit / coverage) ** auto_exposure_power`` above.
    Overlaps are counted twice (a second sphere close enough to matter is rare)."""
    frame_px = float(params.width_px * params.height_px)
    limit_px = params.auto_exposure_coverage * frame_px
    if sum(math.pi * r * r for _, _, r in disks) <= limit_px:
        return 1.0  # cannot exceed the limit: no need to measure
    covered = sum(_disk_in_frame_px(u, v, r, params.width_px, params.height_px)
                  for u, v, r in disks)
    if covered <= limit_px:
        return 1.0
    return float((limit_px / covered) ** params.auto_exposure_power)


def _draw_sphere(
    frame: np.ndarray, cam: _Cam, centre: np.ndarray, radius: float, color: Color,
    params: CameraParams, lighting: Lighting, exposure_gain: float = 1.0,
) -> None:
    """A shaded sphere: overhead + key light + ambient, over-exposure roll-off, glare patch."""
    disk = _sphere_disk(cam, centre, radius)
    if disk is None:
        return
    u0, v0, rad_px = disk
    # Image pixel (i, j) is full-frame pixel (g·i, g·j); the disk's bounding box in full-frame
    # pixels, then the image pixels inside it.
    g = cam.grid
    h, w = frame.shape[:2]
    x0 = max(0, -(-math.floor(u0 - rad_px) // g))
    x1 = min(w, -(-(math.ceil(u0 + rad_px) + 1) // g))
    y0 = max(0, -(-math.floor(v0 - rad_px) // g))
    y1 = min(h, -(-(math.ceil(v0 + rad_px) + 1) // g))
    if x0 >= x1 or y0 >= y1:
        return
    step = max(1, math.ceil(math.sqrt((x1 - x0) * (y1 - y0) / params.max_sphere_samples)))
    # Normalised disk coordinates of the sample pixels' centres (x right, y down).
    xs = ((np.arange(x0, x1, step, dtype=np.float32) * g + 0.5 - u0) / rad_px)[None, :]
    ys = ((np.arange(y0, y1, step, dtype=np.float32) * g + 0.5 - v0) / rad_px)[:, None]
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
        strength = params.glare_strength * exposure_gain ** params.glare_exposure_power
        weight = (weight * np.float32(strength))[..., None]
        lin = lin + (np.float32(255.0) - lin) * weight
    sprite: np.ndarray = np.clip(lin, 0.0, 255.0).astype(np.uint8)
    mask: np.ndarray = inside.astype(np.uint8)
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


@functools.lru_cache(maxsize=16)
def _wall_chunks(
    walls: tuple[Wall, ...], chunk_m: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The walls cut into chunks (static geometry, cached per set of walls): world corners
    (chunks × 4 × xyz), unit normals (chunks × 2) and colours (chunks × 3); None without
    walls."""
    quads, normals, colors = [], [], []
    for wall in walls:
        a = np.array([wall.x1_m, wall.y1_m])
        b = np.array([wall.x2_m, wall.y2_m])
        n = max(1, math.ceil(wall.length_m / chunk_m))
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
        return None
    out = (np.concatenate(quads), np.concatenate(normals), np.concatenate(colors))
    for array in out:
        array.setflags(write=False)
    return out


def _wall_items(
    snapshot: WorldSnapshot, params: CameraParams, cam: _Cam, brightness: float | None = None
) -> list[tuple[float, int, object]]:
    """Paint items (kind 0) for the wall chunks in view, computed for all chunks at once.

    A chunk wholly outside one frustum plane is dropped; one wholly inside is projected here;
    only the few that straddle the frustum's edge are clipped polygon by polygon. Each item's
    payload is ``(camera-frame quad, projected vertices or None, colour)``."""
    chunks = _wall_chunks(snapshot.walls, params.wall_chunk_m)
    if chunks is None:
        return []
    world, normals, colors = chunks
    to_face = 0.5 * (world[:, 0, :2] + world[:, 1, :2]) - cam.position[:2]
    depth = np.linalg.norm(to_face, axis=1)
    # Flat shading, brighter the more squarely a chunk faces the camera (either side).
    facing = np.abs(np.einsum("ij,ij->i", normals, to_face))
    factor = np.where(depth > 0.0, 0.8 + 0.2 * facing / np.where(depth > 0.0, depth, 1.0), 1.0)
    if brightness is None:
        brightness = snapshot.lighting.brightness
    rgb = colors * (factor * brightness)[:, None]
    pts = cam.to_cam(world.reshape(-1, 3)).reshape(world.shape)
    inside: np.ndarray = _frustum_distances(pts, cam) >= 0.0  # chunks × corners × planes
    culled: np.ndarray = np.any(~np.any(inside, axis=1), axis=1)  # a plane has all outside
    whole: np.ndarray = np.all(inside, axis=(1, 2))
    projected = _project(np.where(whole[:, None, None], pts, 1.0), cam)
    return [
        (float(depth[i]), 0, (pts[i], projected[i] if whole[i] else None, rgb[i]))
        for i in np.flatnonzero(~culled)
    ]


def _pitch_jitter_deg(params: CameraParams, rng: np.random.Generator | None) -> float:
    """This frame's pitch jitter (the body's bob), drawn from ``rng``; 0 without noise."""
    if rng is None or not params.pitch_jitter_deg > 0.0:
        return 0.0
    limit = min(3.0 * params.pitch_jitter_deg, _MAX_JITTER_DEG)
    return float(np.clip(rng.normal(0.0, params.pitch_jitter_deg), -limit, limit))


def _background_frame(params: CameraParams, jitter_deg: float, grid: int) -> np.ndarray:
    """A fresh frame holding the background for the jittered pitch."""
    # Pitching up moves the horizon down the image: take the background rows higher up.
    f = params.focal_px
    p0 = math.radians(params.pitch_deg)
    shift = round(f * (math.tan(p0 + math.radians(jitter_deg)) - math.tan(p0)))
    top = _BG_MARGIN - shift
    if grid == 1:
        return _background(params)[top:top + params.height_px].copy()
    return _background_grid(params, top, grid).copy()


def _auto_expose(
    frame: np.ndarray, snapshot: WorldSnapshot, params: CameraParams, cam: _Cam
) -> tuple[float, Lighting]:
    """Auto exposure: a sphere filling much of the view turns the whole picture's gain down.

    Darkens the background already in ``frame``; returns the gain and the lighting to draw
    the objects with."""
    spheres = [np.array([d.x_m, d.y_m, d.radius_m]) for d in snapshot.distractors
               if d.kind == "sphere"]
    if snapshot.ball is not None:
        spheres.append(np.array([snapshot.ball.x_m, snapshot.ball.y_m, snapshot.ball.radius_m]))
    disks = [disk for c in spheres if (disk := _sphere_disk(cam, c, float(c[2]))) is not None]
    gain = auto_exposure_gain(disks, params)
    lighting = snapshot.lighting
    if gain < 1.0:
        lighting = Lighting(brightness=lighting.brightness * gain, glare=lighting.glare)
        # A per-channel scalar, typed Any: OpenCV 4's stubs take only arrays here, 5's take it.
        per_channel: Any = (gain, gain, gain, 0.0)
        cv2.multiply(frame, per_channel, dst=frame)
    return gain, lighting


def _scene_items(
    snapshot: WorldSnapshot, params: CameraParams, cam: _Cam, brightness: float
) -> list[tuple[float, int, Any]]:
    """Everything to draw as ``(depth, kind, payload)``, farthest first: kind 0 a wall chunk
    (:func:`_wall_items`), 1 a prism ``(footprint, height, colour)`` (box, cylinder, box-shaped
    distractor), 2 a sphere ``(centre, radius, colour)`` (spherical distractor, ball)."""
    cam_xy = cam.position[:2]
    items: list[tuple[float, int, Any]] = []  # (depth, kind, payload: by kind)

    items.extend(_wall_items(snapshot, params, cam, brightness))

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
    return items


def _draw_items(
    frame: np.ndarray, cam: _Cam, items: list[tuple[float, int, Any]], params: CameraParams,
    lighting: Lighting, gain: float,
) -> None:
    """Paint :func:`_scene_items`'s items in their order (far to near) over ``frame``."""
    for _depth, kind, payload in items:
        if kind == 0:
            pts, projected, rgb = payload
            if projected is not None:
                _fill_projected(frame, projected, rgb)
            else:
                _fill_clipped(frame, cam, _clip_polygon(pts, cam), rgb)
        elif kind == 1:
            fp, height, color = payload
            _draw_prism(frame, cam, fp, height, color, lighting.brightness)
        else:
            centre, radius, color = payload
            _draw_sphere(frame, cam, centre, radius, color, params, lighting, gain)


def render_camera(
    snapshot: WorldSnapshot,
    params: CameraParams = DEFAULT_CAMERA,
    rng: np.random.Generator | None = None,
    *,
    grid: int = 1,
) -> np.ndarray:
    """Render the robot's camera view: an ``H×W×3`` ``uint8`` RGB frame (1024×1280 default).

    ``rng`` drives the per-frame sensor noise (and the body's bob); ``None`` renders a
    noise-free frame. ``grid`` > 1 renders only the full frame's pixels ``(grid·i, grid·j)``
    into an image ``grid`` times smaller each way (``ceil(H/grid)×ceil(W/grid)``): with
    ``grid = SUBSAMPLE_STEP`` exactly the pixels seekcolor's subsampler reads, at a fraction of
    the cost. Those pixels get the same colours as in the full frame (same noise, same bob for
    the same ``rng``), except that a polygon's edge may fall a pixel apart (rounding).
    """
    if grid < 1:
        raise ValueError(f"grid must be >= 1, got {grid}")
    jitter_deg = _pitch_jitter_deg(params, rng)
    cam = _make_cam(snapshot, params, jitter_deg, grid)
    frame = _background_frame(params, jitter_deg, grid)
    gain, lighting = _auto_expose(frame, snapshot, params, cam)
    items = _scene_items(snapshot, params, cam, lighting.brightness)
    _draw_items(frame, cam, items, params, lighting, gain)
    if rng is not None:
        _add_noise(frame, params, rng, grid)
    return frame
