"""Print the simulated camera's distance → pink-count table.

Run ``python -m components.sim.calibrate`` (``--help`` for options) to regenerate it.

The thesis's behaviour thresholds (flee from 100 pink pixels, comfortable at 140, see DESIGN.md
§3) depend on how many pixels of the ball seekcolor counts at each distance. This script places
the ball straight ahead of the camera at a range of distances (measured horizontally from the
camera to the ball's centre), renders frames with a few seeds (sensor noise, body bob and a small
sideways jitter of the ball) and reports the largest seekcolor bin, which is what chase/flee look
at. Tests import :func:`pink_counts` so the table and the tests agree.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from components.camera.seekcolor import SeekResult, seekcolor
from components.sim.camera_render import DEFAULT_CAMERA, CameraParams, render_camera
from components.sim.world import BallConfig, Distractor, Lighting, World, WorldConfig

DEFAULT_DISTANCES_M: tuple[float, ...] = (
    0.20, 0.25, 0.28, 0.30, 0.32, 0.35, 0.40, 0.45, 0.50, 0.60, 0.80, 1.00, 1.50, 2.00, 2.50,
    3.00, 3.60,
)


def ball_ahead_world(
    distance_m: float,
    *,
    lateral_m: float = 0.0,
    params: CameraParams = DEFAULT_CAMERA,
    lighting: Lighting | None = None,
    distractors: tuple[Distractor, ...] = (),
) -> World:
    """A world with the robot at the origin facing +x and the ball ``distance_m`` ahead of the
    camera (horizontal distance camera → ball centre), ``lateral_m`` to the left."""
    ball = BallConfig(x_m=params.mount_x_m + distance_m, y_m=params.mount_y_m + lateral_m)
    return World(
        WorldConfig(
            ball=ball, lighting=lighting if lighting is not None else Lighting(),
            distractors=distractors,
        )
    )


def pink_counts(
    distance_m: float,
    *,
    seed: int,
    params: CameraParams = DEFAULT_CAMERA,
    lighting: Lighting | None = None,
    lateral_m: float = 0.0,
    jitter_m: float = 0.005,
) -> SeekResult:
    """seekcolor result for one rendered frame of the ball ``distance_m`` ahead.

    ``seed`` drives the sensor noise, the body bob and a uniform ±``jitter_m`` sideways offset.
    """
    rng = np.random.default_rng(seed)
    offset = float(rng.uniform(-jitter_m, jitter_m)) if jitter_m > 0.0 else 0.0
    world = ball_ahead_world(
        distance_m, lateral_m=lateral_m + offset, params=params, lighting=lighting
    )
    return seekcolor(render_camera(world.snapshot(), params, rng))


@dataclass(frozen=True, slots=True)
class CalibrationRow:
    distance_m: float
    mean_max_bin: float
    min_max_bin: int
    max_max_bin: int
    mean_total: float


def calibration_table(
    distances_m: Sequence[float] = DEFAULT_DISTANCES_M,
    *,
    seeds: int = 8,
    params: CameraParams = DEFAULT_CAMERA,
    lighting: Lighting | None = None,
) -> list[CalibrationRow]:
    rows = []
    for d in distances_m:
        results = [pink_counts(d, seed=s, params=params, lighting=lighting) for s in range(seeds)]
        peaks = [max(r.bins) for r in results]
        rows.append(
            CalibrationRow(
                distance_m=d,
                mean_max_bin=float(np.mean(peaks)),
                min_max_bin=min(peaks),
                max_max_bin=max(peaks),
                mean_total=float(np.mean([r.total for r in results])),
            )
        )
    return rows


def _parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="python -m components.sim.calibrate",
        description=(
            "Render the pink ball straight ahead of the simulated camera at several distances "
            "and print the largest seekcolor bin (mean/min/max over seeds) and the total count."
        ),
    )
    parser.add_argument(
        "--distances", type=float, nargs="+", default=list(DEFAULT_DISTANCES_M), metavar="M",
        help="distances from the camera to the ball centre, in metres",
    )
    parser.add_argument("--seeds", type=int, default=8, help="frames (seeds) per distance")
    parser.add_argument("--brightness", type=float, default=1.0, help="Lighting.brightness")
    parser.add_argument("--glare", type=float, default=1.0, help="Lighting.glare")
    parser.add_argument(
        "--sky", type=float, default=None, help="override CameraParams.sky (ball shading)"
    )
    parser.add_argument(
        "--ambient", type=float, default=None, help="override CameraParams.ambient"
    )
    args = parser.parse_args(argv)
    if args.seeds < 1:
        parser.error("--seeds must be >= 1")
    if any(d <= 0.0 for d in args.distances):
        parser.error("--distances must be positive")
    return args


def main(argv: Sequence[str] | None = None) -> int:
    args = _parse_args(argv)
    params = DEFAULT_CAMERA
    if args.sky is not None:
        params = replace(params, sky=args.sky)
    if args.ambient is not None:
        params = replace(params, ambient=args.ambient)
    lighting = Lighting(brightness=args.brightness, glare=args.glare)
    start = time.perf_counter()
    rows = calibration_table(args.distances, seeds=args.seeds, params=params, lighting=lighting)
    elapsed = time.perf_counter() - start
    print(f"pink count vs distance ({args.seeds} seeds; brightness={args.brightness:g}, "
          f"glare={args.glare:g}, sky={params.sky:g}, ambient={params.ambient:g})")
    print(f"{'distance_m':>10} {'max_bin_mean':>12} {'min':>5} {'max':>5} {'total_mean':>10}")
    for row in rows:
        print(
            f"{row.distance_m:10.2f} {row.mean_max_bin:12.1f} {row.min_max_bin:5d} "
            f"{row.max_max_bin:5d} {row.mean_total:10.1f}"
        )
    frames = len(rows) * args.seeds
    print(f"{frames} frames in {elapsed:.2f} s ({1000 * elapsed / frames:.1f} ms per frame, "
          "incl. world setup and seekcolor)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
