"""seekcolor: the thesis's 1-D colour-concentration detector, vectorised with numpy.

The frame is subsampled (every 8th pixel in x and y: 1280×1024 → 160×128), each pixel is
tested against an RGB range, and the matching pixels are tallied in 5 vertical bins of equal
width. With the OV9655's ≈35° horizontal field of view each bin spans ≈7°, so the bin centres
sit at +14°, +7°, 0°, −7° and −14° (REP-103: positive to the robot's left, which is the left
side of the image).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

__all__ = ["BIN_ANGLES_DEG", "BIN_COUNT", "DEFAULT_HFOV_DEG", "MAX_HFOV_DEG", "MIN_HFOV_DEG",
           "PINK", "SUBSAMPLE_STEP",
           "ColorRange", "SeekResult", "color_mask", "seekcolor", "subsample"]

BIN_COUNT = 5
BIN_ANGLES_DEG: tuple[float, ...] = (14.0, 7.0, 0.0, -7.0, -14.0)
"""Bearing of each bin's centre, in image order (left to right)."""
SUBSAMPLE_STEP = 8
DEFAULT_HFOV_DEG = 35.0
MIN_HFOV_DEG = 20.0
MAX_HFOV_DEG = 120.0
"""The lenses a camera device may declare: what the simulator's pinhole renders honestly
(narrower is a telescope no robot here carries; wider, a pinhole stretches the edges past use
and a real lens of that width is a fisheye the pinhole does not model)."""


@dataclass(frozen=True, slots=True, kw_only=True)
class ColorRange:
    """An inclusive RGB box, optionally with the thesis's ordering rule R > B > G."""

    lo: tuple[int, int, int]
    hi: tuple[int, int, int]
    require_r_gt_b_gt_g: bool = True

    def __post_init__(self) -> None:
        for name, rgb in (("lo", self.lo), ("hi", self.hi)):
            if len(rgb) != 3 or any(not 0 <= int(c) <= 255 for c in rgb):
                raise ValueError(f"ColorRange.{name} must be three values in 0..255, got {rgb!r}")
        if any(lo > hi for lo, hi in zip(self.lo, self.hi, strict=True)):
            raise ValueError(f"ColorRange lo {self.lo} exceeds hi {self.hi}")


PINK = ColorRange(lo=(90, 20, 40), hi=(255, 120, 160))
"""The pink rule the robot used: R,G,B within [90,20,40]…[255,120,160] and R > B > G."""


@dataclass(frozen=True, slots=True)
class SeekResult:
    bins: tuple[int, ...]
    """Matching pixels per bin, image left to right."""
    total: int
    bearing_rad: float | None
    """Mean bearing of the matching pixels (positive left); None when there are none."""


def subsample(frame: np.ndarray, step: int = SUBSAMPLE_STEP) -> np.ndarray:
    """Every ``step``-th pixel in x and y (a view, no copy)."""
    return frame[::step, ::step]


def color_mask(image: np.ndarray, color: ColorRange = PINK) -> np.ndarray:
    """Boolean mask of the pixels of an ``H×W×3`` RGB image that fall in ``color``."""
    r = image[..., 0]
    g = image[..., 1]
    b = image[..., 2]
    mask = (
        (r >= color.lo[0]) & (r <= color.hi[0])
        & (g >= color.lo[1]) & (g <= color.hi[1])
        & (b >= color.lo[2]) & (b <= color.hi[2])
    )
    if color.require_r_gt_b_gt_g:
        mask &= (r > b) & (b > g)
    return mask


def seekcolor(
    frame: np.ndarray,
    color: ColorRange = PINK,
    *,
    step: int = SUBSAMPLE_STEP,
    hfov_deg: float = DEFAULT_HFOV_DEG,
) -> SeekResult:
    """Count ``color`` pixels of a full frame per bin after subsampling by ``step``."""
    if frame.ndim != 3 or frame.shape[2] != 3:
        raise ValueError(f"expected an H×W×3 RGB frame, got shape {frame.shape}")
    small = subsample(frame, step)
    per_column = color_mask(small, color).sum(axis=0)
    width = per_column.shape[0]
    edges = np.linspace(0, width, BIN_COUNT + 1).astype(int)
    bins = tuple(int(per_column[a:b].sum()) for a, b in itertools.pairwise(edges))
    total = int(per_column.sum())
    if total == 0:
        return SeekResult(bins=bins, total=0, bearing_rad=None)
    focal_px = (width / 2) / math.tan(math.radians(hfov_deg) / 2)
    centres = np.arange(width) + 0.5
    column_bearing = np.arctan((width / 2 - centres) / focal_px)
    bearing = float(np.dot(per_column, column_bearing) / total)
    return SeekResult(bins=bins, total=total, bearing_rad=bearing)
