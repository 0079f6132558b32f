"""What the camera component captures from: a blocking frame source."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ubf_async.assembly.backend import Backend

__all__ = ["DEFAULT_MOUNT", "CameraBackend", "CameraMount"]


@dataclass(frozen=True, slots=True, kw_only=True)
class CameraMount:
    """Where a camera sits on the body and what it sees with: the camera device's parameters
    in the robot file (REP-103 body frame; yaw + to the left, pitch + up). The defaults are
    the Mini-WHEGS's OV9655: at its front, 4 cm up, tilted up 7°, ≈35° wide, 1280×1024."""

    name: str = "front"
    """The device's name: two cameras of one robot are two devices (``camera/left`` …)."""
    x_m: float = 0.05
    y_m: float = 0.0
    z_m: float = 0.04
    yaw_deg: float = 0.0
    pitch_deg: float = 7.0
    hfov_deg: float = 35.0
    width_px: int = 1280
    height_px: int = 1024


DEFAULT_MOUNT = CameraMount()


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

    def mount(self, mount: CameraMount) -> None:
        """Where the device says the camera sits and what its lens and frame are: called
        once, before :meth:`prepare`. A real camera is where it is (nothing to do, the
        default); a simulated one renders from there, through that lens."""

    def capture(self) -> np.ndarray:
        raise NotImplementedError
