"""The runtime: one robot process — its bus, components and controller.

What a component, a device or a behaviour's host needs is importable from here::

    from ubf_async.runtime import Bus, Component

* the bus (:mod:`~ubf_async.runtime.bus`): the transport's threads → asyncio bridge,
  publishers, subscriptions (screened ones decode on the transport's thread), queries
  (:mod:`~ubf_async.runtime.queries`); a :class:`Bus` opens its session through a transport of
  :mod:`ubf_async.net` and stamps with a clock of :mod:`ubf_async.clocks`;
* supervised components and the robot's health (:mod:`~ubf_async.runtime.component`), and the
  components keeping other processes on the robot's time (:mod:`~ubf_async.runtime.timekeepers`);
* the latest sample per source (:mod:`~ubf_async.runtime.aggregator`) and the controller that
  ticks the tree (:mod:`~ubf_async.runtime.controller`);
* refusals told to their sender (:mod:`~ubf_async.runtime.refusals`), sample ordering
  (:mod:`~ubf_async.runtime.ordering`), the token bucket (:mod:`~ubf_async.runtime.ratelimit`),
  hooks (:mod:`~ubf_async.runtime.hooks`);
* the event loop (:mod:`~ubf_async.runtime.lending`: asyncio's, telling when it is idle;
  lending itself to the transport's threads is opt-in) and the start-up's objects frozen out
  of the garbage collector's walk (:mod:`~ubf_async.runtime.gcfreeze`).

May import: :mod:`ubf_async.core`, :mod:`ubf_async.net`, :mod:`ubf_async.clocks`,
:mod:`ubf_async.wire`, and the floor. Never the assembly (robot files, plug-ins by name), the
command line, services or tools.
"""

from ubf_async.runtime.aggregator import StateAggregator
from ubf_async.runtime.bus import (
    Bus,
    Publisher,
    RawPublisher,
    SampleHandler,
    Screen,
    Subscription,
    TopicScreen,
)
from ubf_async.runtime.component import (
    Component,
    EveryMessageComponent,
    HealthMonitor,
    ensure_name_free,
)
from ubf_async.runtime.controller import Controller, TickMode
from ubf_async.runtime.queries import Queryable, QueryHandler
from ubf_async.runtime.timekeepers import LockstepParticipant, RobotTimeBeacon

__all__ = [
    "Bus",
    "Component",
    "Controller",
    "EveryMessageComponent",
    "HealthMonitor",
    "LockstepParticipant",
    "Publisher",
    "QueryHandler",
    "Queryable",
    "RawPublisher",
    "RobotTimeBeacon",
    "SampleHandler",
    "Screen",
    "StateAggregator",
    "Subscription",
    "TickMode",
    "TopicScreen",
    "ensure_name_free",
]
