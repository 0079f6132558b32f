"""Following a simulator's clock: a :class:`~ubf_async.clocks.clock.SimClock` driven by the
samples on ``ubf/<robot>/clock``, as the :class:`~ubf_async.clocks.timesource.ClockFollower`
policy allows."""

from __future__ import annotations

from ubf_async.clocks.clock import SimClock
from ubf_async.clocks.port import ClockBus, Closing
from ubf_async.clocks.timesource import ClockAction, ClockFollower
from ubf_async.wire.protocol import Message
from ubf_async.wire.topics import CLOCK, SimTime

__all__ = ["follow_sim_clock"]


def follow_sim_clock(
    bus: ClockBus, clock: SimClock, malformed: dict[str, int], *,
    follower: ClockFollower | None = None, robot_sessions: frozenset[str] = frozenset(),
) -> Closing:
    """Drive ``clock`` from the simulator's samples on ``ubf/<robot>/clock``.

    Malformed samples are counted in ``malformed``. What a valid sample may do is decided by
    ``follower`` (a new :class:`~ubf_async.clocks.timesource.ClockFollower` if not given, which
    prefers the run of ``robot_sessions`` — pass one to pin an epoch or to read its counters):
    advance the clock, reset it to a new run's time, or nothing (refused, counted and logged
    by the follower). The first sample taken resets the clock (``clock.resets``) if nothing
    had started it yet.
    """
    key = CLOCK.key(bus.keys)
    policy = follower if follower is not None else ClockFollower(
        name=f"{bus.robot} clock", robot_sessions=robot_sessions)

    def on_sample(key: str, message: Message[SimTime], received_ns: int) -> None:
        verdict = policy.offer(stamp_ns=message.stamp_ns, epoch=message.data.epoch,
                               wall_ns=received_ns, zid=message.data.zid)
        if verdict.action is ClockAction.ADVANCE and clock.started.is_set():
            clock.advance_to(message.stamp_ns)
        elif verdict.action is ClockAction.ADVANCE:
            # The first time heard starts this process's time, as a new run does: joining a
            # run (or a replay) mid-way is not seconds of missed ticks since 0.
            clock.reset_to(message.stamp_ns)
        elif verdict.action is ClockAction.RESET:
            clock.reset_to(message.stamp_ns)

    # Direct, as the state aggregator's samples are: on an ordered bus the clock is then
    # handled in the order it was sent among them, not after samples sent later.
    return bus.subscribe_topic(key, CLOCK, on_sample, malformed, direct=True)
