"""What the camera sees, drawn for people: the subsampled image seekcolor reads, enlarged, with
the pixels that match the colour range marked and the five bins drawn (like the thesis's
figure 4.1). Pure functions on numpy arrays; the camera calls them in its worker thread.
"""

from __future__ import annotations

import itertools

import cv2
import numpy as np

from components.camera.seekcolor import (
    BIN_COUNT,
    PINK,
    SUBSAMPLE_STEP,
    ColorRange,
    SeekResult,
    color_mask,
    subsample,
)

__all__ = ["BIN_LINE_BGR", "DEFAULT_VIEW_SCALE", "JPEG_QUALITY", "MATCH_BGR", "draw_view",
           "encode_jpeg"]

BIN_LINE_BGR = (0, 200, 0)
MATCH_BGR = (255, 255, 0)
"""Matching pixels are marked in cyan: it stands out against pink and the arena's beige."""
DEFAULT_VIEW_SCALE = 4
JPEG_QUALITY = 80


def draw_view(frame_rgb: np.ndarray, result: SeekResult, *, color: ColorRange = PINK,
              scale: int = DEFAULT_VIEW_SCALE, mark_matches: bool = True) -> np.ndarray:
    """The ``SUBSAMPLE_STEP`` subsample of ``frame_rgb`` (the pixels seekcolor reads),
    ``scale`` times larger, as BGR: the bin boundaries as vertical green lines, each bin's
    count at its top, and (``mark_matches``) a cyan dot on each pixel in ``color``."""
    small = np.ascontiguousarray(subsample(frame_rgb, SUBSAMPLE_STEP))
    h, w = small.shape[:2]
    image = cv2.resize(cv2.cvtColor(small, cv2.COLOR_RGB2BGR), (w * scale, h * scale),
                       interpolation=cv2.INTER_NEAREST)
    if mark_matches and scale >= 2:
        # A dot in the middle of each matching pixel: which ones counted stays visible, and
        # so does their colour around the dot.
        ys, xs = np.nonzero(color_mask(small, color))
        dot = max(1, scale // 2)
        start = (scale - dot) // 2
        for dy in range(dot):
            for dx in range(dot):
                image[ys * scale + start + dy, xs * scale + start + dx] = MATCH_BGR
    edges = np.linspace(0, w, BIN_COUNT + 1).astype(int)
    for x in edges[1:-1]:
        cv2.line(image, (int(x) * scale, 0), (int(x) * scale, h * scale), BIN_LINE_BGR, 2)
    font_scale = 0.175 * scale
    for i, (a, b) in enumerate(itertools.pairwise(edges)):
        text = str(result.bins[i])
        (tw, th), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, font_scale, 1)
        origin = (int(a + b) * scale // 2 - tw // 2, th + 6)
        cv2.putText(image, text, origin, cv2.FONT_HERSHEY_SIMPLEX, font_scale, (0, 0, 0), 4,
                    cv2.LINE_AA)
        cv2.putText(image, text, origin, cv2.FONT_HERSHEY_SIMPLEX, font_scale,
                    (255, 255, 255), 1, cv2.LINE_AA)
    return image


def encode_jpeg(image_bgr: np.ndarray, *, quality: int = JPEG_QUALITY) -> bytes:
    """``image_bgr`` as JPEG bytes."""
    # Full-resolution colour (4:4:4): the one-pixel marks keep their colour.
    ok, data = cv2.imencode(".jpg", image_bgr, [
        cv2.IMWRITE_JPEG_QUALITY, quality,
        cv2.IMWRITE_JPEG_SAMPLING_FACTOR, cv2.IMWRITE_JPEG_SAMPLING_FACTOR_444])
    if not ok:
        raise ValueError(f"could not encode a {image_bgr.shape} image as JPEG")
    return data.tobytes()
