"""Quadrature decoding in components.quadrature."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from components.miniwhegs import MINI_WHEGS, MiniWhegsGeometry
from components.quadrature import (
    FORWARD_SEQUENCE,
    DirectionMode,
    QuadratureDecoder,
    edges_to_counts,
    edges_to_radians,
)

FWD = list(FORWARD_SEQUENCE)  # 0, 1, 3, 2
BWD = FWD[::-1]  # 2, 3, 1, 0


def states(*values: int) -> np.ndarray:
    return np.array(values, dtype=np.uint8)


def cycle(order: list[int], n_edges: int, *, start: int = 0) -> np.ndarray:
    """``n_edges`` consecutive states after ``start`` stepping along ``order``."""
    i = order.index(start)
    return np.array([order[(i + k) % 4] for k in range(1, n_edges + 1)], dtype=np.uint8)


def test_forward_order_is_the_documented_gray_cycle() -> None:
    assert FORWARD_SEQUENCE == (0, 1, 3, 2)


def test_phase_mode_forward() -> None:
    dec = QuadratureDecoder(DirectionMode.PHASE, initial_state=0)
    assert dec.feed(states(1, 3, 2, 0, 1)) == 5
    assert dec.edges == 5
    assert dec.errors == 0


def test_phase_mode_backward() -> None:
    dec = QuadratureDecoder(DirectionMode.PHASE, initial_state=0)
    assert dec.feed(states(2, 3, 1, 0)) == -4
    assert dec.feed(states(2, 3)) == -2
    assert dec.edges == -6


def test_phase_mode_reversal_mid_batch() -> None:
    dec = QuadratureDecoder(DirectionMode.PHASE, initial_state=0)
    # 3 forward, then 5 back: net -2
    assert dec.feed(states(1, 3, 2, 3, 1, 0, 2, 3)) == -2


def test_first_state_without_initial_state_is_only_a_reference() -> None:
    dec = QuadratureDecoder(DirectionMode.PHASE)
    assert dec.last_state is None
    assert dec.feed(states(3)) == 0
    assert dec.last_state == 3
    assert dec.feed(states(2, 0)) == 2


def test_repeated_states_are_not_edges() -> None:
    dec = QuadratureDecoder(DirectionMode.PHASE, initial_state=0)
    assert dec.feed(states(0, 0, 1, 1, 1, 3, 3)) == 2
    dec_cmd = QuadratureDecoder(DirectionMode.COMMANDED, initial_state=0)
    dec_cmd.set_commanded_direction(1)
    assert dec_cmd.feed(states(0, 0, 1, 1, 1, 3, 3)) == 2


def test_empty_batch_means_no_edges() -> None:
    dec = QuadratureDecoder(DirectionMode.PHASE, initial_state=2)
    assert dec.feed(np.array([], dtype=np.uint8)) == 0
    assert dec.last_state == 2


def test_commanded_mode_takes_the_sign_from_the_command() -> None:
    dec = QuadratureDecoder(DirectionMode.COMMANDED, initial_state=0)
    dec.set_commanded_direction(1)
    assert dec.feed(cycle(FWD, 8)) == 8
    dec.set_commanded_direction(-1)
    # the phase order says forward, but the command says reverse: the command wins
    assert dec.feed(cycle(FWD, 4)) == -4
    assert dec.feed(cycle(BWD, 4)) == -4
    assert dec.edges == 0
    assert dec.commanded_direction == -1


def test_commanded_mode_with_zero_command_does_not_attribute_edges() -> None:
    dec = QuadratureDecoder(DirectionMode.COMMANDED, initial_state=0)
    assert dec.commanded_direction == 0
    assert dec.feed(cycle(FWD, 6)) == 0
    assert dec.edges == 0
    assert dec.unattributed_edges == 6


def test_false_edge_phase_vs_commanded() -> None:
    """A glitch 0, 1, 0 is +1 then −1.

    PHASE mode cancels it (net 0). COMMANDED mode counts both edges with the commanded sign,
    +2: every glitch inflates the distance. That is the thesis's trade-off — it took the sign
    from the command because phase-based direction was unreliable on its noisy lines.
    """
    phase = QuadratureDecoder(DirectionMode.PHASE)
    assert phase.feed(states(0, 1, 0)) == 0
    commanded = QuadratureDecoder(DirectionMode.COMMANDED)
    commanded.set_commanded_direction(1)
    assert commanded.feed(states(0, 1, 0)) == 2
    assert phase.errors == commanded.errors == 0


def test_commanded_mode_miscounts_motion_against_the_command() -> None:
    """What COMMANDED mode gets wrong: a wheel pushed back while commanded forward."""
    dec = QuadratureDecoder(DirectionMode.COMMANDED, initial_state=0)
    dec.set_commanded_direction(1)
    assert dec.feed(cycle(BWD, 12)) == 12  # truly -12


@pytest.mark.parametrize("mode", list(DirectionMode))
def test_split_batches_equal_one_batch(mode: DirectionMode) -> None:
    rng = np.random.default_rng(7)
    # a random walk along the Gray cycle with pauses and a few glitches and jumps
    position = np.cumsum(rng.choice([-1, 0, 1, 1, 2], size=500))
    seq = np.array(FWD, dtype=np.uint8)[position % 4]
    whole = QuadratureDecoder(mode, initial_state=0)
    whole.set_commanded_direction(1)
    total = whole.feed(seq)
    split = QuadratureDecoder(mode, initial_state=0)
    split.set_commanded_direction(1)
    cuts = [0, 1, 2, 57, 58, 200, 499, 500]
    deltas = [split.feed(seq[a:b]) for a, b in itertools.pairwise(cuts)]
    assert sum(deltas) == total == whole.edges == split.edges
    assert split.errors == whole.errors > 0


def test_invalid_jumps_counted_and_ignored() -> None:
    dec = QuadratureDecoder(DirectionMode.PHASE, initial_state=0)
    # 0→1 (+1), 1→2 (invalid), 2→0 (+1), 0→3 (invalid), 3→2 (+1)
    assert dec.feed(states(1, 2, 0, 3, 2)) == 3
    assert dec.errors == 2
    cmd = QuadratureDecoder(DirectionMode.COMMANDED, initial_state=0)
    cmd.set_commanded_direction(-1)
    assert cmd.feed(states(1, 2, 0, 3, 2)) == -3
    assert cmd.errors == 2


def test_one_revolution_is_two_pi() -> None:
    assert MINI_WHEGS.edges_per_rev == 4096
    for mode in DirectionMode:
        dec = QuadratureDecoder(mode, initial_state=0)
        dec.set_commanded_direction(1)
        assert dec.feed(cycle(FWD, 4096)) == 4096
        assert edges_to_counts(dec.edges) == 1024
        assert edges_to_radians(dec.edges, MINI_WHEGS) == pytest.approx(2 * math.pi)
    back = QuadratureDecoder(DirectionMode.PHASE, initial_state=0)
    assert edges_to_radians(back.feed(cycle(BWD, 4096))) == pytest.approx(-2 * math.pi)


def test_conversions_use_the_geometry() -> None:
    coarse = MiniWhegsGeometry(counts_per_rev=100)
    assert edges_to_counts(40, coarse) == 10
    assert edges_to_radians(200, coarse) == pytest.approx(math.pi)
    assert edges_to_radians(1024) == pytest.approx(math.pi / 2)


def test_reset_keeps_the_last_state() -> None:
    dec = QuadratureDecoder(DirectionMode.PHASE, initial_state=0)
    dec.feed(states(1, 2, 0))
    dec.reset()
    assert (dec.edges, dec.errors, dec.unattributed_edges) == (0, 0, 0)
    assert dec.feed(states(1)) == 1


def test_bad_input_rejected() -> None:
    dec = QuadratureDecoder(DirectionMode.PHASE)
    with pytest.raises(ValueError, match=r"0\.\.3"):
        dec.feed(states(0, 4))
    with pytest.raises(ValueError, match=r"0\.\.3"):
        dec.feed(np.array([0.0, 1.0]))
    with pytest.raises(ValueError, match="1-D"):
        dec.feed(np.zeros((2, 2), dtype=np.uint8))
    with pytest.raises(ValueError, match="direction"):
        dec.set_commanded_direction(2)
    with pytest.raises(ValueError, match="initial_state"):
        QuadratureDecoder(DirectionMode.PHASE, initial_state=5)
    with pytest.raises(ValueError, match="DirectionMode"):
        QuadratureDecoder("phase")  # type: ignore[arg-type]
