"""Camera rendering: the OpenCV-rendered OV9655 view of a world snapshot (:mod:`.camera`), the
worker process simulated cameras render in, off the GIL of the process stepping the world
(:mod:`.process`), and ``python -m components.sim.render.calibrate`` (distance → pink table).

May import: :mod:`components.sim.world`, ``components.camera``'s pure colour model; nothing of
the bus.
"""
