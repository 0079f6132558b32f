"""Scenarios and their formats: the scenario file's msgspec types (:mod:`.format`), loading and
scripting a scenario (:mod:`.scenario`), ready-made worlds (:mod:`.scenes`) and the built-in
scenario files (``files/*.json``).

May import: :mod:`components.sim.world`, the robot-file specs of ``ubf_async.assembly``, the
framework's errors; not the renderer, the backends or the runs.
"""
