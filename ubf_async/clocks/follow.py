"""A process learning which clock its robot runs on, however long the robot takes to start,
and following it (:func:`follow_robot_clock`): ``--clock auto`` of the remote behaviours and of
``python -m components.<device>`` with a backend that needs no simulator, and every tool that
attaches to a robot. ``docs/protocol.md`` (*The robot clock*) shows the same in plain zenoh +
msgpack.
"""

from __future__ import annotations

import asyncio
import logging
import socket
from collections.abc import Callable
from typing import Any, Literal

from ubf_async.clocks.clock import Clock, SimClock
from ubf_async.clocks.hostclock import RobotTimeClock
from ubf_async.clocks.port import ClockBus, Closing
from ubf_async.clocks.simclock import follow_sim_clock
from ubf_async.errors import ProtocolError
from ubf_async.wire.protocol import decode
from ubf_async.wire.topics import CONTROLLER_STATUS, ROBOT_TIME

__all__ = ["DEFAULT_CLOCK_WAIT_S", "HOST", "WAITING_SAID_AFTER_S", "ClockMode", "describe",
           "follow_robot_clock"]

log = logging.getLogger(__name__)

ClockMode = Literal["auto", "wall", "sim", "robot"]
DEFAULT_CLOCK_WAIT_S = 10.0
"""How long ``auto`` waits for the robot to say which clock it runs on before taking this
host's. A robot started with ``python -m ubf_async.launch`` says so within about 0.5 s of its
controller starting (its status, and its clock or time samples), so this only runs out
against a robot that publishes none of them."""
HOST = socket.gethostname()[:253]
"""This host's name, as a robot's status and time samples name theirs."""
WAITING_SAID_AFTER_S = 1.0
"""A wait for the robot's clock says what it waits for once this long has passed without an
answer."""


async def follow_robot_clock(bus: ClockBus, *, mode: ClockMode = "auto",
                             wait_s: float = DEFAULT_CLOCK_WAIT_S,
                             say: Callable[[str], None] | None = None) -> Clock:
    """Put ``bus`` on the robot's clock and return it:

    * ``wall`` keeps ``bus.clock`` (this host's ``CLOCK_MONOTONIC``: right on the robot's
      host);
    * ``sim`` waits for ``ubf/<robot>/clock`` and follows it (under
      :class:`~ubf_async.clocks.timesource.ClockFollower`'s rules: the run of the robot at
      the ``connect`` endpoints first, whatever other run of this robot name reaches the
      bus);
    * ``robot`` waits for ``ubf/<robot>/time`` and follows the robot host's clock through its
      offset (:class:`~ubf_async.clocks.hostclock.RobotTimeClock`: for a process on another host);
    * ``auto`` waits until the robot says which clock it runs on, however long it takes to
      start: a sample on ``ubf/<robot>/clock`` (simulated time: follow it); a sample on
      ``ubf/<robot>/time`` (its host's clock: follow its offset from another host, else keep
      ``bus.clock``); or its controller's status (``status/controller``: ``clock`` and
      ``host``), which says so even while the robot's simulator is still starting — then it
      waits for the simulated time, or for the time samples of the robot's host. Only when
      the robot says nothing of the kind within ``wait_s`` (not a ubf_async robot, or an old
      one) does it keep ``bus.clock``, and says so.

    ``say`` gets a line for the user when the wait is long (after
    :data:`WAITING_SAID_AFTER_S`, in every mode) or ends without an answer (it is logged as
    well)."""
    if mode == "wall":
        return bus.clock
    # The robot's own run first, should another simulator of this robot name reach us too.
    robot_sessions = await bus.connected_sessions()
    wait = _ClockWait.listen(bus, mode=mode, wait_s=wait_s, say=say,
                             robot_sessions=robot_sessions)
    chosen: Clock | None = None
    try:
        while chosen is None:
            chosen = wait.answer()
            if chosen is None:
                await wait.news()
    finally:
        wait.close(keeping=chosen)
    if chosen is wait.sim or chosen is wait.robot_time:
        bus.clock = chosen
    return chosen


class _ClockWait:
    """One wait of :func:`follow_robot_clock`: the subscriptions that hear the robot's clock,
    and what the robot has said of it so far."""

    def __init__(self, bus: ClockBus, *, mode: ClockMode, wait_s: float,
                 say: Callable[[str], None] | None, robot_time: RobotTimeClock) -> None:
        self.bus = bus
        self.mode = mode
        self.wait_s = wait_s
        self.say = say
        self.sim = SimClock()
        self.robot_time = robot_time
        self.status: dict[str, Any] = {}
        """The controller's status, once heard: ``clock`` and ``host``."""
        self.heard_status = asyncio.Event()
        self.subscriptions: list[tuple[Closing, Clock | None]] = []
        """Each with the clock it feeds (kept open while that clock is followed)."""
        self.loop = asyncio.get_running_loop()
        self.started = self.loop.time()
        self.deadline = self.started + wait_s
        self.waiting_said = False

    @classmethod
    def listen(cls, bus: ClockBus, *, mode: ClockMode, wait_s: float,
               say: Callable[[str], None] | None,
               robot_sessions: frozenset[str] = frozenset()) -> _ClockWait:
        """Start listening for what ``mode`` waits for (simulated time: the run published by
        one of ``robot_sessions`` first, :class:`~ubf_async.clocks.timesource.ClockFollower`)."""
        wait = cls(bus, mode=mode, wait_s=wait_s, say=say, robot_time=RobotTimeClock())
        if mode in ("auto", "sim"):
            wait.subscriptions.append((follow_sim_clock(bus, wait.sim, {},
                                                        robot_sessions=robot_sessions),
                                       wait.sim))
        if mode in ("auto", "robot"):
            wait.subscriptions.append((wait.robot_time.follow(bus), wait.robot_time))
        if mode == "auto":
            wait.subscriptions.append(
                (bus.subscribe(CONTROLLER_STATUS.key_expr(bus.keys), wait.on_status), None))
        return wait

    def on_status(self, key: str, payload: bytes, received_ns: int) -> None:
        try:
            message = decode(payload)
        except ProtocolError:
            return  # not ours to count: the status keys are everyone's
        data = message.data
        if (message.schema == CONTROLLER_STATUS.schema and isinstance(data, dict)
                and data.get("clock") in ("simulated", "monotonic")):
            self.status.update(clock=data["clock"], host=data.get("host"))
            self.heard_status.set()

    def answer(self) -> Clock | None:
        """The clock to stamp with, once the robot has said which (or has said nothing for
        too long); None while waiting."""
        bus, robot = self.bus, self.bus.robot
        if self.sim.started.is_set():
            log.info("following the simulated time on %s", bus.keys.clock)
            return self.sim
        if self.robot_time.ready.is_set():
            if self.mode == "robot" or self.robot_time.host != HOST:
                log.info("following the clock of the robot's host %s on %s (offset %+.3f s)",
                         self.robot_time.host or "(unnamed)", ROBOT_TIME.key(bus.keys),
                         self.robot_time.estimator.offset_ns / 1e9)
                return self.robot_time
            log.info("robot %r runs on this host's CLOCK_MONOTONIC (%s)", robot,
                     ROBOT_TIME.key(bus.keys))
            return bus.clock
        if self.status.get("clock") == "monotonic" and self.status.get("host") == HOST:
            log.info("robot %r runs on this host's CLOCK_MONOTONIC (its status)", robot)
            return bus.clock
        if self.mode == "auto" and not self.status and self.loop.time() >= self.deadline:
            self.tell(f"robot {robot!r} said nothing of its clock within {self.wait_s:g} s (no "
                      f"sample on {bus.keys.clock} or {ROBOT_TIME.key(bus.keys)}, no status "
                      f"from its controller): stamping with this host's CLOCK_MONOTONIC",
                      warn=True)
            return bus.clock
        return None

    async def news(self) -> None:
        """Say once that the wait is long, then wait until the next news, or until there is
        something to say."""
        now = self.loop.time()
        if not self.waiting_said and now - self.started >= WAITING_SAID_AFTER_S:
            self.waiting_said = True
            self.tell(self.waiting_for())
        timeouts = []
        if not self.waiting_said:
            timeouts.append(self.started + WAITING_SAID_AFTER_S - now)
        if self.mode == "auto" and not self.status:
            timeouts.append(self.deadline - now)
        self.heard_status.clear()
        waits = [asyncio.ensure_future(event.wait())
                 for event in (self.sim.started, self.robot_time.ready, self.heard_status)]
        try:
            await asyncio.wait(waits, timeout=max(0.0, min(timeouts)) if timeouts else None,
                               return_when=asyncio.FIRST_COMPLETED)
        finally:
            for waiting in waits:
                waiting.cancel()

    def waiting_for(self) -> str:
        """What the wait is for: what ``sim`` and ``robot`` were told to follow, what ``auto``
        expects as far as the robot has said."""
        robot, keys = self.bus.robot, self.bus.keys
        if self.mode == "sim":
            return f"waiting for the simulation time on {keys.clock} ..."
        if self.mode == "robot":
            return (f"waiting for the time of robot {robot!r}'s host on "
                    f"{ROBOT_TIME.key(keys)} ...")
        if self.status.get("clock") == "simulated":
            return (f"robot {robot!r} runs on simulated time: waiting for its simulator's "
                    f"clock on {keys.clock} ...")
        if self.status:
            return (f"robot {robot!r} runs on the clock of host {self.status.get('host')}: "
                    f"waiting for its time on {ROBOT_TIME.key(keys)} ...")
        return f"waiting for robot {robot!r} to say which clock it runs on ..."

    def tell(self, line: str, *, warn: bool = False) -> None:
        (log.warning if warn else log.info)("%s", line)
        if self.say is not None:
            self.say(line)

    def close(self, *, keeping: Clock | None) -> None:
        """Close every subscription but the one feeding ``keeping``, the clock followed."""
        for subscription, feeds in self.subscriptions:
            if feeds is None or feeds is not keeping:
                subscription.close()


def describe(clock: Clock, *, robot: str) -> str:
    """Which clock a process stamps with, for its start-up line."""
    return clock.describe(robot)
