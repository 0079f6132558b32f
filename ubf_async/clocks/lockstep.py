"""Lockstep simulated time across processes: participants the simulator waits for.

Within its own process the simulator steps only once everything of the current instant is
done (:meth:`ubf_async.runtime.lending.IdleEventLoop.idle`). A process that follows its clock
from elsewhere — a remote behaviour, a standalone device, a fleet's controller — is outside that
barrier unless it *takes part* (``--lockstep``). The protocol (``docs/protocol.md``,
"Lockstep"), per robot ``R``:

1. The participant follows ``ubf/R/clock`` like any follower, then declares a liveliness
   token on ``ubf/R/lockstep/<participant>``: from then on the simulator waits for it.
2. The simulator ends each instant ``T`` in this order: its own process's work of ``T`` is
   done (samples of ``T`` sent), then it sends the clock sample ``T``, then it waits until
   every participant has acknowledged ``T``.
3. The participant, on the clock sample of a new time ``T`` (the samples of ``T`` came
   before it: zenoh keeps a session's order), does everything it has to do at ``T`` —
   wakes its timers, reads, votes, publishes — and, once its own work is done, sends an
   acknowledgement on ``ubf/R/lockstep/<participant>`` stamped ``T``
   (:data:`~ubf_async.wire.topics.LOCKSTEP_ACK`: empty data). What it sent before the ack reaches
   the robot before it, so it counts at ``T``.
4. A participant whose token vanishes leaves the barrier at once. One that has not
   acknowledged within :data:`SILENCE_S` of wall time is dropped from it with a warning and
   the run goes on; its next acknowledgement admits it again.

Without ``--lockstep`` a process follows the clock as before: its messages land at whatever
simulated time they arrive.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Awaitable, Callable, Sequence
from dataclasses import dataclass, field

from ubf_async.clocks.port import ClockBus, Closing
from ubf_async.wire.protocol import Message
from ubf_async.wire.topics import LOCKSTEP_ACK, LockstepAck

__all__ = ["JOIN_WAIT_S", "RESEND_S", "SILENCE_S", "LockstepBarrier", "wait_resending"]

log = logging.getLogger(__name__)

SILENCE_S = 2.0
"""Wall seconds the simulator waits for a participant's acknowledgement before it drops the
participant from the barrier."""
JOIN_WAIT_S = 60.0
"""How long (wall time) a simulator told to wait for participants before time starts waits
for them; then it starts without those missing, with a warning."""
RESEND_S = 0.05
"""While it waits — for a hold, for participants — the simulator sends its clock sample
again this often (wall time): a participant that missed it (it joined just then) gets it,
and followers in other processes tell a simulator waiting on purpose from a dead one."""


async def wait_resending(done: Awaitable[object], resend: Callable[[], None]) -> None:
    """Await ``done``, calling ``resend()`` every :data:`RESEND_S` of wall time meanwhile."""
    task = asyncio.ensure_future(done)
    try:
        while not task.done():
            await asyncio.wait({task}, timeout=RESEND_S)
            if not task.done():
                resend()
        task.result()
    finally:
        task.cancel()


@dataclass(slots=True)
class _Participant:
    robot: str
    name: str
    acked_ns: int = -1
    dropped: bool = False


@dataclass(slots=True)
class LockstepBarrier:
    """The simulator's side: the participants of ``buses``' robots, and :meth:`wait`."""

    buses: Sequence[ClockBus]
    silence_s: float = SILENCE_S
    participants: dict[str, _Participant] = field(default_factory=dict)
    """By token key, the participants whose token is alive."""
    _acks: dict[str, int] = field(default_factory=dict)
    changed: asyncio.Event = field(default_factory=asyncio.Event)
    """Set whenever a participant joins, leaves or acknowledges."""
    malformed: dict[str, int] = field(default_factory=dict)

    def open(self) -> list[Closing]:
        """Watch the participants' tokens and acknowledgements (close what is returned)."""
        subs: list[Closing] = []
        for bus in self.buses:
            expr = LOCKSTEP_ACK.key_expr(bus.keys)
            subs.append(bus.watch_liveliness(expr, self._on_token(bus.robot)))
            subs.append(bus.subscribe_topic(expr, LOCKSTEP_ACK, self._on_ack, self.malformed,
                                            latest=False))
        return subs

    def has_participants(self, robot: str | None = None) -> bool:
        return any(robot is None or p.robot == robot for p in self.participants.values())

    def _on_token(self, robot: str) -> Callable[[str, bool], None]:
        def on_change(key: str, alive: bool) -> None:
            name = key.rsplit("/", 1)[-1]
            if alive and key not in self.participants:
                log.info("lockstep: %s of robot %s takes part", name, robot)
                self.participants[key] = _Participant(robot=robot, name=name,
                                                      acked_ns=self._acks.pop(key, -1))
            elif not alive and self.participants.pop(key, None) is not None:
                log.info("lockstep: %s of robot %s left", name, robot)
            self.changed.set()

        return on_change

    def _on_ack(self, key: str, message: Message[LockstepAck], received_ns: int) -> None:
        participant = self.participants.get(key)
        if participant is None:  # its token is not seen yet: kept for when it is
            self._acks[key] = max(self._acks.get(key, -1), message.stamp_ns)
            return
        participant.acked_ns = max(participant.acked_ns, message.stamp_ns)
        if participant.dropped:
            participant.dropped = False
            log.warning("lockstep: %s of robot %s answers again: waited for from now on",
                        participant.name, participant.robot)
        self.changed.set()

    def waiting_for(self, stamp_ns: int) -> list[_Participant]:
        """The participants that have not acknowledged ``stamp_ns`` yet (dropped ones
        aside)."""
        return [p for p in self.participants.values()
                if not p.dropped and p.acked_ns < stamp_ns]

    async def wait(self, stamp_ns: int, *, resend: Callable[[], None]) -> None:
        """Return once every participant has acknowledged ``stamp_ns``; drop those silent
        for :attr:`silence_s` of wall time meanwhile. ``resend()`` is called every
        :data:`RESEND_S` while it waits."""
        deadline = time.monotonic() + self.silence_s
        while missing := self.waiting_for(stamp_ns):
            left = deadline - time.monotonic()
            if left <= 0:
                for participant in missing:
                    participant.dropped = True
                    log.warning("lockstep: %s of robot %s did not acknowledge %.3f s within "
                                "%g s of wall time: dropped from the barrier, the run goes on "
                                "without waiting for it", participant.name, participant.robot,
                                stamp_ns / 1e9, self.silence_s)
                return
            self.changed.clear()
            try:
                await asyncio.wait_for(self.changed.wait(), min(left, RESEND_S))
            except TimeoutError:
                resend()
