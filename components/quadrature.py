"""Quadrature decoding of the Mini-WHEGS wheel encoders (pure, vectorised with numpy).

Each encoder gives two square waves A and B, 90° apart; the HAL sees the 2-bit state
``(A << 1) | B``. Valid motion steps one place along the Gray cycle ``0 → 1 → 3 → 2 → 0``.

Direction convention: stepping **along** that cycle (``0→1``, ``1→3``, ``3→2``, ``2→0``: B
changes first, i.e. B leads A) is **forward** (+1 edge); stepping against it is reverse (−1).
An encoder backend must emit the forward cycle when the wheel drives the robot forward.
A change of both bits at once (``0↔3``, ``1↔2``) cannot be attributed to a direction: it means
a level change was missed, and it is counted in :attr:`QuadratureDecoder.errors` and ignored.

Two ways to sign the edges (:class:`DirectionMode`):

* ``PHASE`` — the textbook way: the sign comes from the transition itself. A false edge (a
  glitch: a state and its immediate reversal, ``0, 1, 0``) contributes ``+1 − 1 = 0``.
* ``COMMANDED`` — the thesis's way: every valid edge counts one and the sign is the direction
  last commanded to the motor. The thesis found phase-based direction unreliable on its noisy
  lines and took the sign from the command instead. The price: a glitch ``0, 1, 0`` counts
  **+2** instead of 0 (both edges are valid, both get the commanded sign), so noise always
  inflates the distance; and when the wheel moves against the command (coasting after a
  reversal, being pushed, slipping back) its edges are counted with the wrong sign. While the
  commanded direction is 0 edges are not attributed at all; they go to
  :attr:`QuadratureDecoder.unattributed_edges` so the loss stays visible.

Beside the device packages (like :mod:`components.miniwhegs`), not in ``components.encoders``:
the encoders decode with it, and so does the motors' wiring check (``python -m components.motors
--check``, which reads the encoder lines itself); device packages import none of each other.
"""

from __future__ import annotations

import math
from enum import Enum

import numpy as np

from components.miniwhegs import MINI_WHEGS, MiniWhegsGeometry

__all__ = ["FORWARD_SEQUENCE", "DirectionMode", "QuadratureDecoder", "edges_to_counts",
           "edges_to_radians"]

FORWARD_SEQUENCE: tuple[int, ...] = (0, 1, 3, 2)
"""States in the order a forward-turning wheel produces them (then back to 0)."""

_INVALID = 2
"""Marker in :data:`_TRANSITIONS` for a two-bit jump."""


def _transition_table() -> np.ndarray:
    table = np.full((4, 4), _INVALID, dtype=np.int8)
    np.fill_diagonal(table, 0)
    for i, state in enumerate(FORWARD_SEQUENCE):
        nxt = FORWARD_SEQUENCE[(i + 1) % 4]
        table[state, nxt] = 1
        table[nxt, state] = -1
    table.setflags(write=False)
    return table


_TRANSITIONS = _transition_table()
"""``_TRANSITIONS[previous, current]``: 0 no change, +1 forward, −1 reverse, 2 invalid."""


class DirectionMode(Enum):
    """Where the sign of an edge comes from."""

    COMMANDED = "commanded"
    """The last commanded motor direction (thesis behaviour; see the module docstring)."""
    PHASE = "phase"
    """The A/B phase order of the transition itself."""


class QuadratureDecoder:
    """Counts signed edges of one encoder from batches of 2-bit states.

    ``initial_state`` is the level of the lines before the first batch; when ``None`` the
    first state ever fed only sets the reference and is not an edge.
    """

    def __init__(
        self,
        mode: DirectionMode = DirectionMode.COMMANDED,
        *,
        initial_state: int | None = None,
    ) -> None:
        if not isinstance(mode, DirectionMode):
            raise ValueError(f"mode must be a DirectionMode, got {mode!r}")
        if initial_state is not None and initial_state not in range(4):
            raise ValueError(f"initial_state must be 0..3 or None, got {initial_state!r}")
        self.mode = mode
        self._last_state = initial_state
        self._commanded_direction = 0
        self.edges = 0
        """Total signed edges since construction (or :meth:`reset`)."""
        self.errors = 0
        """Invalid transitions (both bits changed at once) seen and ignored."""
        self.unattributed_edges = 0
        """Valid edges seen in COMMANDED mode while the commanded direction was 0."""

    @property
    def commanded_direction(self) -> int:
        return self._commanded_direction

    @property
    def last_state(self) -> int | None:
        """The most recent state fed (``None`` before any)."""
        return self._last_state

    def set_commanded_direction(self, direction: int) -> None:
        """Record the direction the motor was last commanded: −1, 0 or +1."""
        if direction not in (-1, 0, 1):
            raise ValueError(f"commanded direction must be -1, 0 or +1, got {direction!r}")
        self._commanded_direction = int(direction)

    def reset(self) -> None:
        """Zero the counters; the last state is kept so the next batch continues from it."""
        self.edges = 0
        self.errors = 0
        self.unattributed_edges = 0

    def feed(self, states: np.ndarray) -> int:
        """Decode a batch of states (oldest first) and return its signed edge delta.

        Repeated identical states are not edges. The last state is remembered for the next
        batch, so splitting a sequence across calls gives the same total as one call.
        """
        current = np.asarray(states)
        if current.ndim != 1:
            raise ValueError(f"states must be a 1-D array, got shape {current.shape}")
        if current.size == 0:
            return 0
        if not np.issubdtype(current.dtype, np.integer):
            raise ValueError(f"states must be integers 0..3, got dtype {current.dtype}")
        if current.min() < 0 or current.max() > 3:
            raise ValueError(
                f"states must be 2-bit values 0..3, got range {current.min()}..{current.max()}"
            )
        current = current.astype(np.intp, copy=False)
        if self._last_state is None:
            self._last_state = int(current[0])  # reference only: compares equal, no edge
        previous = np.concatenate(([self._last_state], current[:-1]))
        self._last_state = int(current[-1])
        steps = _TRANSITIONS[previous, current]
        invalid = steps == _INVALID
        n_invalid = int(np.count_nonzero(invalid))
        self.errors += n_invalid
        if self.mode is DirectionMode.PHASE:
            delta = int(steps[~invalid].sum(dtype=np.int64))
        else:
            n_edges = int(np.count_nonzero(steps)) - n_invalid
            if self._commanded_direction == 0:
                self.unattributed_edges += n_edges
                delta = 0
            else:
                delta = self._commanded_direction * n_edges
        self.edges += delta
        return delta


def edges_to_counts(edges: float, geometry: MiniWhegsGeometry = MINI_WHEGS) -> float:
    """Encoder counts (full quadrature cycles) for ``edges`` edges: ``edges / 4``."""
    return edges / geometry.edges_per_count


def edges_to_radians(edges: float, geometry: MiniWhegsGeometry = MINI_WHEGS) -> float:
    """Wheel rotation in radians for ``edges`` edges (4096 edges = one revolution = 2π)."""
    return 2.0 * math.pi * edges / geometry.edges_per_rev
