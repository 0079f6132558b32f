"""The Mini-WHEGS simulator: a pymunk world plus device backends (no bus, no asyncio).

* :mod:`components.sim.world` — the 2-D world.
* :mod:`components.sim.world_config` — the scene description a world is built from.
* :mod:`components.sim.world_snapshot` — the immutable snapshots a world's readers see.
* :mod:`components.sim.camera_render` — the OpenCV-rendered OV9655 camera view.
* :mod:`components.sim.render_process` — the process the simulated cameras render in (off
  the GIL of the process that steps the world).
* :mod:`components.sim.ranging` — ray casting for the IR range finders.
* :mod:`components.sim.backends` — device backend implementations on top of a world.
* :mod:`components.sim.calibrate` — ``python -m components.sim.calibrate``: distance → pink table.
"""

from ubf_async import extras

# The simulator is the sim extra (ubf_async/extras.py): without it, whatever reaches this
# package — a simulated launch, a `sim` backend, experiment.run — says so in one line.
extras.require("sim", "pymunk", who="the simulator")
extras.require("sim", "matplotlib", who="the simulator")
