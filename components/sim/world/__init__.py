"""World and physics: the 2-D pymunk world (:mod:`.physics`), what it is built from
(:mod:`.config`), the immutable snapshots its readers see (:mod:`.snapshot`) and those as plain
data for the bus (:mod:`.snapshot_data`), the radio air between a fleet's robots (:mod:`.air`),
ray casting for the range finders (:mod:`.ranging`), and ``python -m
components.sim.world.steady_drive`` (the steady motion for fixed pulses).

May import: the framework's lower rooms, ``components.miniwhegs`` and the device packages'
pure models (``components.motors.pwm``, ``components.range.backend``); no other room of the
simulator, no bus, no asyncio.
"""
