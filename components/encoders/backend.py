"""What the encoders component reads: raw quadrature phase states per wheel."""

from __future__ import annotations

from typing import Protocol

import numpy as np


class EncoderBackend(Protocol):
    """Source of quadrature A/B levels for the left and right encoders.

    ``read_phases()`` returns, for each wheel, a ``uint8`` array of the 2-bit states
    ``(A << 1) | B`` observed since the previous call, oldest first, one entry per observed
    level change (a real line may glitch: false edges appear as a state and its immediate
    reversal). The decoder remembers the last state of the previous batch, so an empty array
    simply means "no edges".
    """

    def read_phases(self) -> tuple[np.ndarray, np.ndarray]:
        ...
