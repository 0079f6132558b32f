"""Keep the start-up's objects out of the cyclic garbage collector's way.

A running robot process holds tens of thousands of long-lived objects made while it started
(modules, the behaviour tree, zenoh declarations, the simulator's space and caches). CPython's
oldest-generation collection walks all of them: measured in a fleet's world process, one such
collection held the event loop for 30–40 ms, so every robot's clock stopped for as long
(``bench.fleet_scaling``; ``docs/fleet.md``). :func:`freeze_startup_objects`, called by the entry
points once everything has started, collects what start-up left behind and then moves every
surviving object into the collector's permanent generation (:func:`gc.freeze`), so later
collections walk only what the run itself allocates.

The price: an object made before the freeze that later becomes cyclic garbage is not
reclaimed (reference counting still frees everything that is not in a cycle). Start-up
objects live as long as the process, so that is rare and small.
"""

from __future__ import annotations

import gc

__all__ = ["freeze_startup_objects"]


def freeze_startup_objects() -> int:
    """Collect, then freeze every object that survives (see the module docstring); returns
    how many objects are frozen now. Harmless to call again: objects already frozen stay so,
    the ones made since join them."""
    gc.collect()
    gc.freeze()
    return gc.get_freeze_count()
