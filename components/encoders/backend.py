"""What the encoders component reads: raw quadrature phase states per wheel."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ubf_async.assembly.backend import Backend

__all__ = ["EdgeTiming", "EncoderBackend"]


@dataclass(frozen=True, slots=True, kw_only=True)
class EdgeTiming:
    """How long one wheel's edges of one :meth:`EncoderBackend.read_phases` batch took, by the
    edges' own time stamps (the pin factory's, the kernel's on lgpio).

    Only differences between edge stamps are used: the stamps' clock differs between pin
    factories and kernels (monotonic, real time, a wrapping µs counter), so they are never
    compared with the robot's clock."""

    edges: int
    """Edges in the batch."""
    span_s: float | None
    """Seconds the batch's edges took: from the newest edge before the batch (if the wheel
    was moving: at most :data:`components.encoders.gpio.MAX_EDGE_GAP_S` before the batch's
    first) or else from the batch's first edge, to its newest. ``None`` when unknown: no
    edges, a single edge after standing still, or edges dropped from the batch."""
    intervals: int
    """Edge-to-edge intervals ``span_s`` covers: ``edges``, or ``edges − 1`` when it starts at
    the batch's first edge."""


class EncoderBackend(Backend):
    """Source of quadrature A/B levels for the left and right encoders.

    ``read_phases()`` returns, for each wheel, a ``uint8`` array of the 2-bit states
    ``(A << 1) | B`` observed since the previous call, oldest first, one entry per observed
    level change (a real line may glitch: false edges appear as a state and its immediate
    reversal). The decoder remembers the last state of the previous batch, so an empty array
    simply means "no edges".
    """

    edge_timing: tuple[EdgeTiming, EdgeTiming] | None = None
    """For a backend that stamps its edges: one :class:`EdgeTiming` per wheel (left, right) for
    the batch the last :meth:`read_phases` returned — the encoders component turns it into each
    wheel's speed. None (the default): no stamps."""

    @property
    def overflowed(self) -> int | None:
        """The edges dropped so far because they came faster than they were read; None (the
        default) for a backend that cannot drop any."""
        return None

    def current_states(self) -> tuple[int, int] | None:
        """The lines' present 2-bit states (left, right), the decoders' start states; None
        (the default) when the backend cannot tell before its first batch."""
        return None

    def read_phases(self) -> tuple[np.ndarray, np.ndarray]:
        raise NotImplementedError
