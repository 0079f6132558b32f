"""Time: the clock a process stamps with, and following another process's clock.

* :mod:`~ubf_async.clocks.clock` — the :class:`Clock` protocol, wall time
  (:class:`WallClock`), simulated time (:class:`SimClock`), periodic schedules
  (:func:`every`) and the one rule safety deadlines follow (:class:`SilenceLimit`);
* :mod:`~ubf_async.clocks.timesource` — which clock samples may move simulated time
  (:class:`ClockFollower`, pure);
* :mod:`~ubf_async.clocks.simclock` — a :class:`SimClock` following a simulator's samples;
* :mod:`~ubf_async.clocks.hostclock` — the robot host's clock seen from another host
  (:class:`RobotTimeClock`);
* :mod:`~ubf_async.clocks.clockdomain` — the pure rule telling samples stamped on another
  clock, and the per-bus table reporting them (what the state aggregator uses: no follower);
* :mod:`~ubf_async.clocks.follow` — learning which clock a robot runs on and following it
  (:func:`follow_robot_clock`);
* :mod:`~ubf_async.clocks.lockstep` — the simulator's barrier for participants in other
  processes;
* :mod:`~ubf_async.clocks.port` — the few members of a bus the followers use
  (:class:`ClockBus`).

The components that publish the robot host's time and take part in lockstep are in
:mod:`ubf_async.runtime.timekeepers`.

May import: :mod:`ubf_async.wire`, :mod:`ubf_async.errors`, :mod:`ubf_async.throttle`. Not the
runtime (the bus stamps with a clock: the clocks are below it), the core or the network.
"""

from ubf_async.clocks.clock import Clock, Hold, SilenceLimit, SimClock, WallClock, every
from ubf_async.clocks.follow import ClockMode, follow_robot_clock
from ubf_async.clocks.hostclock import RobotTimeClock
from ubf_async.clocks.port import ClockBus
from ubf_async.clocks.simclock import follow_sim_clock
from ubf_async.clocks.timesource import ClockFollower

__all__ = [
    "Clock",
    "ClockBus",
    "ClockFollower",
    "ClockMode",
    "Hold",
    "RobotTimeClock",
    "SilenceLimit",
    "SimClock",
    "WallClock",
    "every",
    "follow_robot_clock",
    "follow_sim_clock",
]
