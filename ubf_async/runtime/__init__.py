"""The runtime: one robot process's bus, clocks, components and controller.

Clocks (:mod:`~ubf_async.clocks.clock`, :mod:`~ubf_async.clocks.timesource`,
:mod:`~ubf_async.clocks.hostclock`, :mod:`~ubf_async.clocks.clockdomain`,
:mod:`~ubf_async.clocks.lockstep`), the event loop (:mod:`~ubf_async.runtime.lending`), the
zenoh-thread → asyncio bridge (:mod:`~ubf_async.runtime.bus`), supervised components
(:mod:`~ubf_async.runtime.component`), the latest sample per source
(:mod:`~ubf_async.runtime.aggregator`), the controller that ticks the tree
(:mod:`~ubf_async.runtime.controller`), refusals told to their sender
(:mod:`~ubf_async.runtime.refusals`), and small shared mechanisms (ordering, the token bucket
in :mod:`~ubf_async.runtime.ratelimit`, :mod:`~ubf_async.runtime.gcfreeze`).

May import: :mod:`ubf_async.wire`, :mod:`ubf_async.core`, :mod:`ubf_async.net`, and below.
Never the assembly (robot files, plug-ins by name), the command line, services or tools.
"""
