"""A safety limit's message states the measure that passed it, in the clock it was measured
in (issue 28, item 2): "no drive command for 0 ms (robot time)" from a 110 ms watchdog, or a
source shown ``age 15 ms STALE`` for a 20 ms period, contradicted themselves."""

from __future__ import annotations

import time

import pytest

from ubf_async.clocks.clock import SilenceLimit, SimClock, WallClock

MS = 1_000_000


def test_in_robot_time_it_says_robot_time_and_the_limit() -> None:
    limit = SilenceLimit(limit_s=0.11)
    clock = WallClock()
    now = clock.now_ns()
    assert limit.overdue(clock, since_ns=now - 100 * MS, since_wall_ns=now - 100 * MS,
                         now_ns=now, wall_now_ns=now) is None
    said = limit.overdue(clock, since_ns=now - 112 * MS, since_wall_ns=now - 112 * MS,
                         now_ns=now, wall_now_ns=now)
    assert said == "112 ms of robot time (limit 110 ms)"


def test_a_silent_simulator_is_said_in_wall_time_with_the_robot_time_beside_it() -> None:
    """Simulated time stood still 3 ms after the last command; its simulator (in another
    process) has been silent for 0.8 s of wall time: the limit passed in wall time, and the
    message says so — not "3 ms"."""
    clock = SimClock()
    clock.advance_to(1_000 * MS)
    heard = time.monotonic_ns()
    limit = SilenceLimit(limit_s=0.11)  # its wall-time rule waits max(0.11, 0.5) s
    since = 1_000 * MS - 3 * MS
    assert limit.overdue(clock, since_ns=since, since_wall_ns=heard - 10 * MS,
                         wall_now_ns=heard + 300 * MS) is None  # the simulator may be busy
    said = limit.overdue(clock, since_ns=since, since_wall_ns=heard - 10 * MS,
                         wall_now_ns=heard + 800 * MS)
    assert said is not None
    assert said.startswith("0.81 s of wall time with the clock's source silent for 0.80 s")
    assert "limit 0.5 s" in said and "3 ms of robot time" in said


@pytest.mark.parametrize("ms, expected", [(29, False), (31, True)])
def test_expired_is_overdue(ms: int, expected: bool) -> None:
    limit = SilenceLimit(limit_s=0.03)
    clock = WallClock()
    now = clock.now_ns()
    assert limit.expired(clock, since_ns=now - ms * MS, since_wall_ns=now - ms * MS,
                         now_ns=now, wall_now_ns=now) is expected
