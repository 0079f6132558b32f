"""The components that keep other processes on this robot's time: the robot host's clock
published for other hosts (:class:`RobotTimeBeacon`, :mod:`ubf_async.clocks.hostclock`) and a
process's part in a simulation's lockstep (:class:`LockstepParticipant`,
:mod:`ubf_async.clocks.lockstep`). The clocks and the rules are in :mod:`ubf_async.clocks`;
these are components, so they live on the runtime above it."""

from __future__ import annotations

import asyncio
import socket

from ubf_async.clocks.clock import SimClock
from ubf_async.clocks.hostclock import BEACON_PERIOD_S
from ubf_async.errors import ConfigurationError
from ubf_async.runtime import lending
from ubf_async.runtime.bus import Bus
from ubf_async.runtime.component import Component
from ubf_async.wire.topics import LOCKSTEP_ACK, ROBOT_TIME

__all__ = ["LockstepParticipant", "RobotTimeBeacon"]


class RobotTimeBeacon(Component):
    """Publishes the robot's clock on ``ubf/<robot>/time`` every ``period_s`` (a wall-time
    robot's launch starts it; module docstring)."""

    def __init__(self, *, bus: Bus, name: str = "robot-time",
                 period_s: float = BEACON_PERIOD_S) -> None:
        super().__init__(bus=bus, name=name)
        if not period_s > 0:
            raise ValueError(f"period_s must be > 0, got {period_s}")
        self.period_s = period_s
        self.host = socket.gethostname()[:253] or None

    async def run(self) -> None:
        publisher = self.publisher(ROBOT_TIME, period_s=self.period_s)
        while True:
            publisher.publish({"host": self.host})
            await self.bus.clock.sleep(self.period_s)


class LockstepParticipant(Component):
    """A process's part in its robot's lockstep (module docstring): a component named
    ``<participant>-lockstep`` that declares the participant's token and acknowledges each
    new simulated time of the bus clock (a :class:`~ubf_async.clocks.clock.SimClock` following the
    robot's) once this process's event loop has nothing left to run.

    Lifecycle: :meth:`run` (from :meth:`start`) declares the token and acknowledges until
    the component is closed; the token goes with the run attempt. Needs ubf_async's event
    loop, which tells when the work of an instant is done."""

    def __init__(self, *, bus: Bus, participant: str, **component_options: float) -> None:
        """Raises :class:`~ubf_async.errors.ConfigurationError` unless ``bus`` follows a
        simulator's clock."""
        super().__init__(bus=bus, name=f"{participant}-lockstep", **component_options)
        if not isinstance(bus.clock, SimClock):
            raise ConfigurationError(f"--lockstep takes part in a simulated run: nothing "
                                     f"here follows a simulator's clock on {bus.keys.clock}")
        self.clock = bus.clock
        self.participant = participant
        self.key = LOCKSTEP_ACK.key(bus.keys, participant)  # validates the name
        self.acks = 0

    async def run(self) -> None:
        clock = self.clock
        idle = lending.idle_waiter(asyncio.get_running_loop())
        if idle is None:
            raise ConfigurationError(
                "--lockstep needs ubf_async's event loop (the default, or UBF_LOOP=lending; "
                "not uvloop): it tells when the work of a simulated instant is done")
        publisher = self.publisher(LOCKSTEP_ACK, self.participant)
        token = self.bus.declare_token(self.key)
        try:
            # The simulator's barrier subscribes to these acknowledgements for as long as its
            # session lives (zenoh's matching status): while it does, the simulator is alive
            # and simulated time waits for this process, so the clock's silence — however long
            # a busy machine keeps its samples from arriving — is no reason for a safety limit
            # of this process (SilenceLimit) to act in wall time and change the run.
            with clock.source_alive_while(publisher.has_subscribers):
                await clock.started.wait()
                while True:
                    # The time whose work the idle loop proves done. A later sample that
                    # arrives meanwhile is acknowledged on the next round, once its own work
                    # is.
                    now = clock.now_ns()
                    await idle()
                    publisher.publish({}, stamp_ns=now)
                    self.acks += 1
                    await clock.sleep_until_ns(now + 1)
        finally:
            token.undeclare()
