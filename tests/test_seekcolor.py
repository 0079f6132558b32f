"""seekcolor (components.camera.seekcolor) on synthetic 1280×1024 RGB frames."""

from __future__ import annotations

import math

import numpy as np
import pytest

from components.camera.seekcolor import (
    BIN_ANGLES_DEG,
    BIN_COUNT,
    PINK,
    ColorRange,
    color_mask,
    seekcolor,
    subsample,
)

WIDTH, HEIGHT = 1280, 1024
BIN_WIDTH_PX = WIDTH // BIN_COUNT  # 256 px = 32 subsampled columns
PINK_RGB = (200, 60, 110)
BACKGROUND_RGB = (40, 120, 40)


def blank() -> np.ndarray:
    frame = np.empty((HEIGHT, WIDTH, 3), dtype=np.uint8)
    frame[:] = BACKGROUND_RGB
    return frame


def with_patch(
    rgb: tuple[int, int, int], *, x0: int = 576, x1: int = 704, y0: int = 448, y1: int = 576
) -> np.ndarray:
    frame = blank()
    frame[y0:y1, x0:x1] = rgb
    return frame


def test_empty_frame_has_no_bearing() -> None:
    result = seekcolor(blank())
    assert result.bins == (0, 0, 0, 0, 0)
    assert result.total == 0
    assert result.bearing_rad is None


@pytest.mark.parametrize("bin_index", range(BIN_COUNT))
def test_block_lands_in_its_bin(bin_index: int) -> None:
    x0 = bin_index * BIN_WIDTH_PX + 64
    frame = with_patch(PINK_RGB, x0=x0, x1=x0 + 128)
    result = seekcolor(frame)
    # 128×128 px subsampled by 8 → 16×16 = 256 pixels, all in one bin
    expected = [0] * BIN_COUNT
    expected[bin_index] = 256
    assert result.bins == tuple(expected)
    assert result.total == 256
    assert result.bearing_rad is not None
    # the block is centred in its bin, so the bearing is close to the bin's nominal angle
    assert math.degrees(result.bearing_rad) == pytest.approx(BIN_ANGLES_DEG[bin_index], abs=0.5)


def test_bearing_sign_left_is_positive() -> None:
    left = seekcolor(with_patch(PINK_RGB, x0=0, x1=200)).bearing_rad
    right = seekcolor(with_patch(PINK_RGB, x0=1080, x1=1280)).bearing_rad
    centre = seekcolor(with_patch(PINK_RGB, x0=576, x1=704)).bearing_rad
    assert left is not None and right is not None and centre is not None
    assert left > 0.0 > right
    assert centre == pytest.approx(0.0, abs=1e-12)
    assert left == pytest.approx(-right)
    # the outermost column is at most half the field of view off axis
    assert left < math.radians(35.0 / 2)


def test_only_the_subsampled_pixels_count() -> None:
    frame = blank()
    frame[1::8, 1::8] = PINK_RGB  # pink only where the every-8th-pixel subsample never looks
    assert seekcolor(frame).total == 0
    assert subsample(frame).shape == (128, 160, 3)


@pytest.mark.parametrize(
    "orange",
    [
        (255, 140, 0),  # pure orange: G and B outside the box
        (255, 165, 0),
        (230, 100, 20),
        (200, 80, 50),  # inside the RGB box, but G > B
        (255, 100, 60),
        (180, 90, 45),
    ],
)
def test_orange_is_not_pink(orange: tuple[int, int, int]) -> None:
    assert seekcolor(with_patch(orange)).total == 0


@pytest.mark.parametrize("orange", [(200, 80, 50), (255, 100, 60), (180, 90, 45)])
def test_orange_inside_the_box_is_rejected_by_the_ordering_rule(
    orange: tuple[int, int, int],
) -> None:
    box_only = ColorRange(lo=PINK.lo, hi=PINK.hi, require_r_gt_b_gt_g=False)
    assert seekcolor(with_patch(orange), box_only).total > 0
    assert seekcolor(with_patch(orange), PINK).total == 0


@pytest.mark.parametrize(
    "rgb",
    [
        (100, 50, 120),  # B > R
        (150, 60, 160),  # B > R at the top of the B box
        (150, 80, 80),  # B == G: the rule is strict
        (120, 90, 120),  # R == B
        (150, 110, 90),  # G > B
    ],
)
def test_ordering_rule_violations_are_rejected(rgb: tuple[int, int, int]) -> None:
    assert not color_mask(np.array([[rgb]], dtype=np.uint8), PINK)[0, 0]
    assert seekcolor(with_patch(rgb)).total == 0


@pytest.mark.parametrize("rgb", [(60, 20, 40), (255, 200, 230), (80, 25, 45), (255, 130, 170)])
def test_dark_or_glare_pink_is_rejected(rgb: tuple[int, int, int]) -> None:
    assert seekcolor(with_patch(rgb)).total == 0


@pytest.mark.parametrize("rgb", [(90, 21, 41), (255, 120, 160), (200, 60, 110), (130, 40, 70)])
def test_pink_shades_inside_the_rule_are_detected(rgb: tuple[int, int, int]) -> None:
    assert seekcolor(with_patch(rgb)).total == 256


def test_a_changed_range_detects_green() -> None:
    green = ColorRange(lo=(0, 150, 0), hi=(100, 255, 100), require_r_gt_b_gt_g=False)
    frame = with_patch((30, 200, 40), x0=0, x1=128)
    assert seekcolor(frame, PINK).total == 0
    result = seekcolor(frame, green)
    assert result.bins == (256, 0, 0, 0, 0)
    # the ordering rule would have rejected green (G is the largest channel)
    strict_green = ColorRange(lo=green.lo, hi=green.hi)
    assert seekcolor(frame, strict_green).total == 0


def test_count_grows_with_apparent_size() -> None:
    near = seekcolor(with_patch(PINK_RGB, x0=512, x1=768, y0=384, y1=640)).total
    far = seekcolor(with_patch(PINK_RGB, x0=608, x1=672, y0=480, y1=544)).total
    assert near == 4 * 4 * far


@pytest.mark.parametrize(
    ("lo", "hi", "match"),
    [
        ((0, 0, 0), (256, 255, 255), r"0\.\.255"),
        ((-1, 0, 0), (255, 255, 255), r"0\.\.255"),
        ((0, 0), (255, 255, 255), "three values"),
        ((100, 0, 0), (50, 255, 255), "exceeds"),
    ],
)
def test_invalid_color_range_raises(
    lo: tuple[int, ...], hi: tuple[int, ...], match: str
) -> None:
    with pytest.raises(ValueError, match=match):
        ColorRange(lo=lo, hi=hi)  # type: ignore[arg-type]


def test_non_rgb_frame_raises() -> None:
    with pytest.raises(ValueError, match="H×W×3"):
        seekcolor(np.zeros((HEIGHT, WIDTH), dtype=np.uint8))
