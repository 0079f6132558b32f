"""A :class:`~components.camera.backend.CameraBackend` over ``cv2.VideoCapture``.

Lets the camera component run on a real camera (by index) or replay a recorded video file
(by path) instead of the simulator's renderer. Frames come out as the protocol requires:
``H×W×3`` ``uint8`` RGB at a fixed size (the OV9655's 1280×1024 by default), whatever the
source delivers. A video file loops back to its start at the end unless ``loop=False``.
"""

from __future__ import annotations

from types import TracebackType
from typing import Annotated

import cv2
import msgspec
import numpy as np

from components.camera.backend import CameraBackend
from ubf_async.assembly.context import DeviceContext
from ubf_async.errors import ConfigurationError, DeviceError

__all__ = ["CameraError", "VideoCaptureBackend", "video_backend"]


class CameraError(DeviceError):
    """The source cannot be opened, is closed, or yields no frame."""


class VideoCaptureBackend(CameraBackend):
    """Frames from a camera index or a video file, converted to RGB and resized to ``size``.

    ``size`` is ``(width, height)`` in pixels (OpenCV order). ``capture()`` blocks until a
    frame arrives, like the hardware; the component calls it from a worker thread.
    """

    def __init__(
        self,
        source: int | str,
        *,
        size: tuple[int, int] = (1280, 1024),
        loop: bool = True,
    ) -> None:
        width, height = size
        if width <= 0 or height <= 0:
            raise ValueError(f"size must be positive (width, height), got {size!r}")
        self.source = source
        self.size = (int(width), int(height))
        self.loop = loop
        self._is_file = isinstance(source, str)
        self._capture: cv2.VideoCapture | None = cv2.VideoCapture(source)
        if not self._capture.isOpened():
            self._capture.release()
            self._capture = None
            kind = "video file" if self._is_file else "camera"
            raise CameraError(f"cannot open {kind} {source!r}")

    def prepare(self) -> None:
        """Nothing to do: the source is opened by the constructor, so a bad one fails early."""

    def expose(self) -> None:
        """Nothing to do: the device delivers frames at its own pace."""

    def capture(self) -> np.ndarray:
        """The next frame as ``height×width×3`` ``uint8`` RGB.

        Raises :class:`CameraError` when closed, when a camera yields no frame, or when a file
        has ended (with ``loop=False``) or holds no frame at all.
        """
        if self._capture is None:
            raise CameraError(f"camera source {self.source!r} is closed")
        ok, frame = self._capture.read()
        if not ok and self._is_file and self.loop:
            self._capture.set(cv2.CAP_PROP_POS_FRAMES, 0)
            ok, frame = self._capture.read()
        if not ok or frame is None:
            reason = "reached its end" if self._is_file and not self.loop else "yielded no frame"
            raise CameraError(f"camera source {self.source!r} {reason}")
        if frame.ndim == 2:
            rgb = cv2.cvtColor(frame, cv2.COLOR_GRAY2RGB)
        elif frame.shape[2] == 4:
            rgb = cv2.cvtColor(frame, cv2.COLOR_BGRA2RGB)
        else:
            rgb = cv2.cvtColor(frame, cv2.COLOR_BGR2RGB)
        width, height = self.size
        if rgb.shape[1] != width or rgb.shape[0] != height:
            shrinking = rgb.shape[1] > width
            rgb = cv2.resize(
                rgb,
                (width, height),
                interpolation=cv2.INTER_AREA if shrinking else cv2.INTER_LINEAR,
            )
        return rgb

    def close(self) -> None:
        """Release the source; calling it again does nothing."""
        if self._capture is not None:
            self._capture.release()
            self._capture = None

    def __enter__(self) -> VideoCaptureBackend:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


def video_backend(
    *,
    context: DeviceContext,
    source: str = "0",
    width: Annotated[int, msgspec.Meta(gt=0)] = 1280,
    height: Annotated[int, msgspec.Meta(gt=0)] = 1024,
    loop: bool = True,
) -> VideoCaptureBackend:
    """``camera.video``: frames from ``source`` — digits are a camera index, anything else a
    video file — as ``width``×``height`` RGB; a file starts over at its end when ``loop``."""
    capture_source: int | str = int(source) if source.isdigit() else source
    try:
        return VideoCaptureBackend(capture_source, size=(width, height), loop=loop)
    except CameraError as exc:  # a source that cannot be opened is the user's to fix
        raise ConfigurationError(f"camera.video: {exc}") from exc


video_backend.requires_simulator = None  # type: ignore[attr-defined]
