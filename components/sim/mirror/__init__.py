"""The world mirrored from the bus, in a process other than the simulator's: a fleet member's
world for its sim-backed devices (:mod:`.remote_world`) and the arena of a live view
(:mod:`.arena`), both built from the ``sim/world`` snapshots.

May import: :mod:`components.sim.world`, the framework's runtime (the bus), wire and live-view
service; not the renderer, scenarios, backends or runs.
"""
