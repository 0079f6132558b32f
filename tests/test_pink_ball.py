"""The thesis's seek-the-pink-ball behaviours with the thesis's own numbers."""

from __future__ import annotations

import random

import pytest

from ubf_async import Action, State
from ubf_async.behaviors.pink_ball import Chase, Flee, Search, seek_pink_ball

S = 1_000_000_000


def camera(bins: list[int], *, now_ns: int = 0, previous: Action | None = None) -> State:
    return State.of(
        now_ns=now_ns, previous_action=previous, camera__front={"bins": bins, "total": sum(bins)}
    )


@pytest.mark.parametrize(
    ("centre", "speed"),
    [(140, 0), (180, -40), (200, -40), (400, -40), (120, 20), (100, 40), (60, 40)],
)
def test_chase_plus_flee_speed(centre: int, speed: float) -> None:
    tree = seek_pink_ball(rng=random.Random(0))
    action = tree.act(camera([0, 0, centre, 0, 0]))
    assert action.speed == pytest.approx(speed)
    assert action.turn == 0


def test_flee_numbers() -> None:
    flee = Flee()
    assert flee.act(camera([0, 0, 99, 0, 0])) is None
    assert flee.act(camera([0, 0, 100, 0, 0])).speed == 0
    assert flee.act(camera([0, 0, 150, 0, 0])).speed == -50
    assert flee.act(camera([0, 0, 500, 0, 0])).speed == -80


@pytest.mark.parametrize(
    ("bins", "turn"),
    [
        ([50, 0, 0, 0, 0], 60),
        ([0, 50, 0, 0, 0], 30),
        ([0, 0, 50, 0, 0], 0),
        ([0, 0, 0, 50, 0], -30),
        ([0, 0, 0, 0, 50], -60),
        ([5, 20, 20, 0, 0], 0),  # tie between centre and inner: the centre wins
    ],
)
def test_chase_turns_toward_bin(bins: list[int], turn: float) -> None:
    action = Chase().act(camera(bins))
    assert action.speed == 40 and action.turn == turn


def test_pink_in_left_outer_bin_turns_left_60() -> None:
    action = seek_pink_ball().act(camera([30, 0, 0, 0, 0]))
    assert (action.speed, action.turn) == (40, 60)


def test_no_pink_search_acts_chase_and_flee_abstain() -> None:
    tree = seek_pink_ball(rng=random.Random(0))
    trace = tree.evaluate(camera([0, 0, 0, 0, 0], previous=Action(speed=40, turn=-30)))
    by_name = {t.name: t for t in trace.children}
    assert by_name["chase"].action is None and by_name["flee"].action is None
    assert by_name["search"].won
    assert (trace.action.speed, trace.action.turn) == (10, -80)  # keeps turning right


def test_search_without_prior_turn_sits_still_until_counter_elapses() -> None:
    search = Search(period_s=3.0, rng=random.Random(4))
    idle = [search.act(camera([0] * 5, now_ns=t * S // 10)) for t in range(30)]  # 0 … 2.9 s
    assert all((a.speed, a.turn) == (0, 0) for a in idle)
    after = search.act(camera([0] * 5, now_ns=3 * S))
    assert after.speed == 10 and abs(after.turn) == 80


def test_search_keeps_previous_turn_then_draws_random_direction() -> None:
    rng = random.Random(11)
    expected = random.Random(11)
    search = Search(period_s=2.0, rng=rng)
    previous = Action(speed=40, turn=30)
    first = search.act(camera([0] * 5, now_ns=0, previous=previous))
    assert first.turn == 80
    still = search.act(camera([0] * 5, now_ns=int(1.9 * S), previous=first))
    assert still.turn == 80
    picked = search.act(camera([0] * 5, now_ns=2 * S, previous=still))
    assert picked.turn == 80 * expected.choice((-1, 1))


def test_search_counter_restarts_after_pink_seen() -> None:
    search = Search(period_s=2.0, rng=random.Random(0))
    search.act(camera([0] * 5, now_ns=0))
    assert search.act(camera([0, 0, 5, 0, 0], now_ns=1 * S)) is None
    again = search.act(camera([0] * 5, now_ns=int(2.5 * S)))
    assert (again.speed, again.turn) == (0, 0)  # new counter: elapses at 4.5 s


def test_missing_or_stale_camera_all_abstain() -> None:
    tree = seek_pink_ball()
    assert tree.act(State.of(now_ns=0)) is None
    stale = State.of(camera__front={"bins": [0, 0, 200, 0, 0], "total": 200})
    reading = stale["camera/front"]
    stale_state = State(
        {"camera/front": type(reading)(value=reading.value, stamp_ns=0, stale=True)}
    )
    assert tree.act(stale_state) is None
