"""Time seekcolor on a 1280×1024 synthetic frame against a per-pixel pure-Python loop.

Run ``python -m bench.seekcolor [--frames N]``. The frame is a noisy green-grey background
with a shaded pink disc (a ball ≈240 px across, about 1 m away for the OV9655). The vectorised
:func:`components.camera.seekcolor.seekcolor` is timed over ``--frames`` calls; the baseline,
the thesis's algorithm written as a plain Python loop over the 160×128 subsample (converting
the subsample to Python lists is included in its time), runs only ``--baseline-frames`` times
because it is slow. Both must find the same bins, which the script checks.
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable

import numpy as np

from components.camera.seekcolor import (
    BIN_COUNT,
    PINK,
    SUBSAMPLE_STEP,
    ColorRange,
    seekcolor,
)

WIDTH, HEIGHT = 1280, 1024


def synthetic_frame(*, seed: int = 0, radius_px: int = 120) -> np.ndarray:
    """A ``1024×1280×3`` RGB frame with a shaded pink disc right of centre."""
    rng = np.random.default_rng(seed)
    frame = np.empty((HEIGHT, WIDTH, 3), dtype=np.int16)
    frame[:] = (70, 110, 80)
    yy, xx = np.mgrid[0:HEIGHT, 0:WIDTH]
    cx, cy = 800, 560
    r = np.hypot(xx - cx, yy - cy) / radius_px
    disc = r <= 1.0
    # brighter in the middle, darker towards the rim, every shade still inside the pink rule
    shade = 1.0 - 0.35 * r[disc]
    frame[disc] = np.stack([230 * shade, 70 * shade, 130 * shade], axis=-1).astype(np.int16)
    frame += rng.integers(-6, 7, size=frame.shape, dtype=np.int16)
    return np.clip(frame, 0, 255).astype(np.uint8)


def seekcolor_pure_python(
    frame: np.ndarray, color: ColorRange = PINK, step: int = SUBSAMPLE_STEP
) -> tuple[int, ...]:
    """The thesis's loop: test every ``step``-th pixel and tally matches per vertical bin."""
    rows = frame[::step, ::step].tolist()
    width = len(rows[0])
    (r_lo, g_lo, b_lo), (r_hi, g_hi, b_hi) = color.lo, color.hi
    ordered = color.require_r_gt_b_gt_g
    bins = [0] * BIN_COUNT
    for row in rows:
        for x, (r, g, b) in enumerate(row):
            if not (r_lo <= r <= r_hi and g_lo <= g <= g_hi and b_lo <= b <= b_hi):
                continue
            if ordered and not r > b > g:
                continue
            bins[x * BIN_COUNT // width] += 1
    return tuple(bins)


def time_ms(fn: Callable[[], object], repeats: int) -> list[float]:
    """Wall time of each of ``repeats`` calls of ``fn``, in milliseconds."""
    times = []
    for _ in range(repeats):
        start = time.perf_counter_ns()
        fn()
        times.append((time.perf_counter_ns() - start) / 1e6)
    return times


def p99(values: list[float]) -> float:
    return float(np.percentile(values, 99))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m bench.seekcolor",
        description="Time the vectorised seekcolor against a pure-Python per-pixel loop.",
    )
    parser.add_argument(
        "--frames", type=int, default=200, help="seekcolor calls to time (default 200)"
    )
    parser.add_argument(
        "--baseline-frames",
        type=int,
        default=10,
        help="pure-Python loop calls to time (slow; default 10)",
    )
    parser.add_argument("--seed", type=int, default=0, help="noise seed for the frame")
    args = parser.parse_args(argv)
    if args.frames < 1 or args.baseline_frames < 1:
        parser.error("--frames and --baseline-frames must be at least 1")

    frame = synthetic_frame(seed=args.seed)
    fast_result = seekcolor(frame)
    slow_bins = seekcolor_pure_python(frame)
    if fast_result.bins != slow_bins:
        raise SystemExit(f"mismatch: numpy bins {fast_result.bins} != pure Python {slow_bins}")

    for _ in range(5):  # warm up caches and numpy's dispatch
        seekcolor(frame)
    fast = time_ms(lambda: seekcolor(frame), args.frames)
    slow = time_ms(lambda: seekcolor_pure_python(frame), args.baseline_frames)

    sub_h, sub_w = frame[::SUBSAMPLE_STEP, ::SUBSAMPLE_STEP].shape[:2]
    print(
        f"seekcolor on a {WIDTH}×{HEIGHT} RGB frame, subsample every {SUBSAMPLE_STEP}th pixel "
        f"→ {sub_w}×{sub_h}"
    )
    print(f"pink pixels found: {fast_result.total}, bins {fast_result.bins}")
    print()
    print(f"{'implementation':<28}{'frames':>8}{'median ms':>12}{'p99 ms':>10}")
    print("-" * 58)
    rows = (("numpy (seekcolor)", fast), ("pure-Python per-pixel loop", slow))
    for name, times in rows:
        print(f"{name:<28}{len(times):>8}{statistics.median(times):>12.3f}{p99(times):>10.3f}")
    print("-" * 58)
    ratio = statistics.median(slow) / statistics.median(fast)
    print(f"speed-up of seekcolor over the loop (median / median): {ratio:.0f}×")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
