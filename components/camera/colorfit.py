"""Fitting seekcolor's colour range to a ball under the user's light (``python -m
components.camera.calibrate``; docs/hardware.md, "The camera's colour").

The user marks the ball with a rectangle, the same on each frame (the ball and the camera held
still while the light flickers and the sensor's noise changes). The ball is round: its pixels
are those of the ellipse inscribed in the rectangle, whose corners are the background. Of
those, the ones that pass seekcolor's ordering rule R > B > G — the thesis's pink rule, which
the range keeps, in the same RGB space — are the ball as seekcolor can see it: its glare
(white) and its shadow (grey) fail the rule, and so does most of a room. The range is their
2nd to 98th percentile per channel (a stray pixel does not stretch it), widened by a margin
(the light moves between calibration and use).

:func:`coverage` says what a range counts: the share of the ball's pixels and of the rest of
the frames, at full resolution, and seekcolor's own count (every 8th pixel), the number the
behaviours' thresholds are in. :func:`draw_fit` draws it, the old range beside the new.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from components.camera.seekcolor import SUBSAMPLE_STEP, ColorRange, color_mask, seekcolor
from components.camera.view import draw_view

__all__ = ["DEFAULT_MARGIN", "MIN_RULE_SHARE", "TRIM_PERCENT", "Coverage", "Fit", "Rect",
           "ball_pixels", "coverage", "draw_fit", "fit_color"]

DEFAULT_MARGIN = 8
"""Levels (of 255) the fitted range is widened by on each side."""
TRIM_PERCENT = 2.0
"""The share of the ball's pixels left out at each end of each channel."""
MIN_RULE_SHARE = 0.2
"""Fewer of the ball's pixels than this passing R > B > G: the rectangle is not on a ball
seekcolor can see (the sim's pink ball: ≈77 %, its glare and shadow the rest)."""
RULE_ONLY = ColorRange(lo=(0, 0, 0), hi=(255, 255, 255))
"""Every level, with the rule: what seekcolor's R > B > G lets through (one definition of it,
:func:`~components.camera.seekcolor.color_mask`'s)."""
RECT_BGR = (0, 0, 255)
VIEW_SCALE = 4


@dataclass(frozen=True, slots=True)
class Rect:
    """A rectangle of a frame in pixels: ``x``, ``y`` its top left corner, ``w`` × ``h``."""

    x: int
    y: int
    w: int
    h: int

    @classmethod
    def parse(cls, text: str) -> Rect:
        """``X,Y,W,H`` (integers); ``ValueError`` saying the form otherwise."""
        parts = text.split(",")
        try:
            x, y, w, h = (int(part) for part in parts)
        except ValueError:
            raise ValueError(f"a rectangle is X,Y,W,H in pixels (e.g. 600,650,300,300), got "
                             f"{text!r}") from None
        return cls(x, y, w, h)

    def check(self, width: int, height: int) -> None:
        """``ValueError`` unless the rectangle is non-empty and inside a ``width`` ×
        ``height`` frame."""
        if self.w <= 0 or self.h <= 0:
            raise ValueError(f"the rectangle {self} is empty: give it a width and a height of "
                             f"at least 1 pixel")
        if self.x < 0 or self.y < 0 or self.x + self.w > width or self.y + self.h > height:
            raise ValueError(f"the rectangle {self} (x {self.x}..{self.x + self.w}, y "
                             f"{self.y}..{self.y + self.h}) is not inside the {width}×{height} "
                             f"frame")

    def ellipse(self, height: int, width: int) -> np.ndarray:
        """A ``height`` × ``width`` mask of the ellipse inscribed in the rectangle (pixel
        centres inside it; at least the centre pixel)."""
        ys, xs = np.ogrid[:height, :width]
        cx, cy = self.x + (self.w - 1) / 2, self.y + (self.h - 1) / 2
        inside = ((xs - cx) / (self.w / 2)) ** 2 + ((ys - cy) / (self.h / 2)) ** 2 <= 1.0
        return np.asarray(inside)

    def __str__(self) -> str:
        return f"{self.x},{self.y},{self.w},{self.h}"


@dataclass(frozen=True, slots=True)
class Fit:
    """A range fitted to the ball's pixels, and how many of them it was fitted to."""

    color: ColorRange
    sampled: int
    """The ball's pixels (the ellipse's, over every frame)."""
    passing: int
    """Those that pass R > B > G: the range is fitted to these."""


@dataclass(frozen=True, slots=True)
class Coverage:
    """What a range counts in frames with the ball in a rectangle."""

    ball: float
    """The share of the ball's pixels (the ellipse's) it counts, over every frame."""
    rest: float
    """The share of the pixels outside the rectangle it counts, over every frame."""
    seek_total: int
    """seekcolor's count in the first frame (every 8th pixel): what chase and flee see."""


def _checked(frames: Sequence[np.ndarray], rect: Rect) -> tuple[int, int]:
    if not frames:
        raise ValueError("no frames")
    height, width = frames[0].shape[:2]
    for frame in frames:
        if frame.shape != (height, width, 3):
            raise ValueError(f"frames differ in size ({frame.shape[1]}×{frame.shape[0]}, the "
                             f"first {width}×{height}): give frames of one camera")
    rect.check(width, height)
    return height, width


def ball_pixels(frames: Sequence[np.ndarray], rect: Rect) -> np.ndarray:
    """The RGB pixels (N × 3) of the ellipse in ``rect``, of every frame (H×W×3 RGB)."""
    inside = rect.ellipse(*_checked(frames, rect))
    return np.concatenate([frame[inside] for frame in frames])


def fit_color(pixels: np.ndarray, *, margin: int = DEFAULT_MARGIN) -> Fit:
    """The range (with the rule R > B > G) fitted to the ball's ``pixels``; ``ValueError``
    when too few of them pass the rule to be a ball seekcolor can see."""
    passing = pixels[color_mask(pixels, RULE_ONLY)]
    share = len(passing) / len(pixels) if len(pixels) else 0.0
    if share < MIN_RULE_SHARE:
        raise ValueError(f"only {share:.0%} of the {len(pixels)} pixels in the rectangle pass "
                         f"seekcolor's rule R > B > G: is it on the ball? (the rule counts "
                         f"pinks and magentas only)")
    low, high = np.percentile(passing, [TRIM_PERCENT, 100.0 - TRIM_PERCENT], axis=0)
    lo = np.clip(np.floor(low) - margin, 0, 255).astype(int)
    hi = np.clip(np.ceil(high) + margin, 0, 255).astype(int)
    color = ColorRange(lo=(int(lo[0]), int(lo[1]), int(lo[2])),
                       hi=(int(hi[0]), int(hi[1]), int(hi[2])))
    return Fit(color=color, sampled=len(pixels), passing=len(passing))


def coverage(frames: Sequence[np.ndarray], rect: Rect, color: ColorRange) -> Coverage:
    """What ``color`` counts of the ball (the ellipse in ``rect``) and of the rest."""
    height, width = _checked(frames, rect)
    ball = rect.ellipse(height, width)
    rest = np.ones((height, width), bool)
    rest[rect.y:rect.y + rect.h, rect.x:rect.x + rect.w] = False
    counted = [color_mask(frame, color) for frame in frames]
    in_ball = sum(int(np.count_nonzero(mask & ball)) for mask in counted)
    in_rest = sum(int(np.count_nonzero(mask & rest)) for mask in counted)
    return Coverage(ball=in_ball / (len(frames) * int(ball.sum())),
                    rest=in_rest / max(1, len(frames) * int(rest.sum())),
                    seek_total=seekcolor(frames[0], color).total)


def draw_fit(frame: np.ndarray, rect: Rect, *, before: ColorRange,
             after: ColorRange) -> np.ndarray:
    """What seekcolor counts in ``frame`` (RGB) with the range ``before`` (left) and ``after``
    (right): the camera's drawn view (:func:`~components.camera.view.draw_view`: a cyan dot
    on each pixel counted, the bins and their counts), the ball's ellipse in red, as BGR."""
    halves = []
    for title, color in (("before", before), ("after", after)):
        view = draw_view(frame, seekcolor(frame, color), color=color, scale=VIEW_SCALE)
        k = VIEW_SCALE / SUBSAMPLE_STEP
        centre = (round((rect.x + rect.w / 2) * k), round((rect.y + rect.h / 2) * k))
        axes = (max(1, round(rect.w / 2 * k)), max(1, round(rect.h / 2 * k)))
        cv2.ellipse(view, centre, axes, 0, 0, 360, RECT_BGR, 1, cv2.LINE_AA)
        label = f"{title}: {list(color.lo)}..{list(color.hi)}"
        (width, height), _ = cv2.getTextSize(label, cv2.FONT_HERSHEY_SIMPLEX, 0.6, 1)
        bottom = view.shape[0]
        cv2.rectangle(view, (0, bottom - height - 14), (width + 12, bottom), (0, 0, 0), -1)
        cv2.putText(view, label, (6, bottom - 7), cv2.FONT_HERSHEY_SIMPLEX, 0.6,
                    (255, 255, 255), 1, cv2.LINE_AA)
        halves.append(view)
    return np.hstack(halves)
