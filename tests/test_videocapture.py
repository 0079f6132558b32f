"""VideoCaptureBackend on a synthetic video file written with cv2.VideoWriter."""

from __future__ import annotations

import itertools
from pathlib import Path

import cv2
import numpy as np
import pytest

from components.camera.backend import CameraBackend
from components.camera.seekcolor import seekcolor
from components.camera.videocapture import CameraError, VideoCaptureBackend

WIDTH, HEIGHT = 320, 256
FRAMES = 10
SQUARE = 64
PINK_RGB = (200, 60, 110)  # well inside the pink rule: R>B>G, each channel in its box
BACKGROUND_RGB = (40, 120, 40)


def square_left_x(i: int) -> int:
    """Left edge of the square in frame ``i``: from the left border to the right border."""
    return round(i * (WIDTH - SQUARE) / (FRAMES - 1))


@pytest.fixture
def video(tmp_path: Path) -> Path:
    path = tmp_path / "pink_square.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (WIDTH, HEIGHT))
    assert writer.isOpened(), "OpenCV cannot write MJPG/AVI here"
    try:
        for i in range(FRAMES):
            rgb = np.empty((HEIGHT, WIDTH, 3), dtype=np.uint8)
            rgb[:] = BACKGROUND_RGB
            x = square_left_x(i)
            rgb[96 : 96 + SQUARE, x : x + SQUARE] = PINK_RGB
            writer.write(cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    finally:
        writer.release()
    return path


def test_reads_rgb_frames_at_the_requested_size(video: Path) -> None:
    with VideoCaptureBackend(str(video), size=(WIDTH, HEIGHT)) as cam:
        frame = cam.capture()
    assert frame.shape == (HEIGHT, WIDTH, 3)
    assert frame.dtype == np.uint8
    # RGB, not OpenCV's BGR: the square is red-dominant, the background green-dominant
    inside = frame[96 + SQUARE // 2, SQUARE // 2].astype(int)
    assert np.abs(inside - PINK_RGB).max() <= 12
    assert np.abs(frame[10, 200].astype(int) - BACKGROUND_RGB).max() <= 12


def test_default_size_is_the_ov9655_resolution(video: Path) -> None:
    with VideoCaptureBackend(str(video)) as cam:
        frame = cam.capture()
    assert frame.shape == (1024, 1280, 3)


def test_pink_square_moves_across_the_seekcolor_bins(video: Path) -> None:
    cam: CameraBackend = VideoCaptureBackend(str(video))
    try:
        results = [seekcolor(cam.capture()) for _ in range(FRAMES)]
    finally:
        cam.close()
    peaks = [int(np.argmax(r.bins)) for r in results]
    assert peaks[0] == 0
    assert peaks[-1] == 4
    assert peaks == sorted(peaks)
    assert set(peaks) == {0, 1, 2, 3, 4}
    bearings = [r.bearing_rad for r in results]
    assert all(b is not None for b in bearings)
    assert bearings[0] > 0 > bearings[-1]  # left of centre is positive
    assert all(a > b for a, b in itertools.pairwise(bearings))
    # the square's area is the same in every frame
    totals = [r.total for r in results]
    assert max(totals) - min(totals) <= 0.1 * max(totals)


def test_file_loops_back_to_the_start(video: Path) -> None:
    with VideoCaptureBackend(str(video), size=(WIDTH, HEIGHT)) as cam:
        first = cam.capture()
        for _ in range(FRAMES - 1):
            cam.capture()
        again = cam.capture()
    np.testing.assert_array_equal(again, first)


def test_without_loop_the_end_of_the_file_is_an_error(video: Path) -> None:
    with VideoCaptureBackend(str(video), loop=False) as cam:
        for _ in range(FRAMES):
            cam.capture()
        with pytest.raises(CameraError, match="end"):
            cam.capture()


def test_missing_file_is_a_clear_error(tmp_path: Path) -> None:
    missing = tmp_path / "no_such_video.avi"
    with pytest.raises(CameraError, match="cannot open video file"):
        VideoCaptureBackend(str(missing))


def test_close_is_idempotent_and_final(video: Path) -> None:
    cam = VideoCaptureBackend(str(video))
    cam.close()
    cam.close()
    with pytest.raises(CameraError, match="closed"):
        cam.capture()


def test_bad_size_rejected(video: Path) -> None:
    with pytest.raises(ValueError, match="size"):
        VideoCaptureBackend(str(video), size=(0, 100))
