"""A run's outputs: trajectory samples, their CSV and annotated camera frames
(:mod:`.trajectory`), and the top-down trajectory plot drawn with matplotlib (:mod:`.plots`).
No bus: the runner calls them from worker threads.

May import: :mod:`components.sim.scenarios`, :mod:`components.sim.render`,
:mod:`components.sim.world`, ``components.camera``'s drawing; not the backends or the runs.
"""
