"""Device backends on a simulated world: the ``<kind>.sim`` (and ``radio.air``) backends the
registry builds (:mod:`.devices`), each implementing its device package's backend protocol.

May import: :mod:`components.sim.render`, :mod:`components.sim.world`, the device packages'
backend protocols and pure models, ``ubf_async.assembly.context``; not the scenarios, runs,
outputs or mirror.
"""
