"""What the camera component captures from: a blocking frame source."""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from ubf_async.assembly.backend import Backend

__all__ = ["CameraBackend"]


class CameraBackend(Backend):
    """A frame source. :meth:`capture` blocks (the component calls it from a worker thread).

    Returns an ``H×W×3`` ``uint8`` RGB frame (1280×1024 for the OV9655 model).
    """

    renders_in_python: ClassVar[bool] = False
    """Whether capturing is CPU work in Python (rendering). Such a backend captures on the
    process's one render thread, so several such cameras take turns instead of contending for
    the GIL; others (the default) capture in a thread each."""

    def prepare(self) -> None:
        """Get ready to capture: called once, from a worker thread, before the first
        :meth:`capture`. May block (open a device, build caches); nothing by default."""

    def expose(self) -> None:
        """Mark the capture instant: called on the event loop at the moment the frame is
        stamped, right before :meth:`capture` runs in a worker thread. Must return at once.
        A camera that captures when asked has nothing to do (the default); a simulated one
        freezes the world's state here, so the frame shows the instant it is stamped with,
        however late the worker thread starts."""

    def capture(self) -> np.ndarray:
        raise NotImplementedError
