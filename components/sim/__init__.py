"""The Mini-WHEGS simulator, in rooms (high to low; a room imports only rooms below it, and
rooms of one line import none of each other — the ``sim-rooms`` contract in pyproject.toml):

* :mod:`components.sim.plugin` — the ``mini-whegs`` simulator plug-in (entry point
  ``ubf_async.simulators``); it reaches the rooms below lazily.
* :mod:`components.sim.runner` — runs: one simulated run as launch drives it, the simulator
  on the bus that steps the world and owns simulated time, a fleet's shared world.
* :mod:`components.sim.backends` | :mod:`components.sim.outputs` | :mod:`components.sim.mirror`
  — the ``<kind>.sim`` device backends; a run's outputs (trajectory, plot, annotated frames);
  the world mirrored from the bus in another process (a fleet member's world, the live view's
  arena).
* :mod:`components.sim.render` | :mod:`components.sim.scenarios` — the OpenCV-rendered camera
  (and its render process); scenarios and their file format.
* :mod:`components.sim.world` — the pymunk world, its configuration and snapshots, the radio
  air, ray casting.

Every room's ``__init__`` says what it holds and what it may import. Nothing outside the
simulator imports it but through the registry (the devices-without-simulator and
framework-alone contracts).
"""

from ubf_async import extras

# The simulator is the sim extra (ubf_async/extras.py): without it, whatever reaches this
# package — a simulated launch, a `sim` backend, experiment.run — says so in one line.
extras.check("sim", "pymunk", who="the simulator")
extras.check("sim", "matplotlib", who="the simulator")
