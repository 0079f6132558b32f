"""Assembly: building a robot from data.

* :mod:`~ubf_async.assembly.registry` — plug-ins by entry point (behaviours, arbiters,
  predicates, device kinds, backends, simulators);
* :mod:`~ubf_async.assembly.plugins` — plug-ins by name where the core takes objects (a
  predicate by name for ``Conditional``);
* :mod:`~ubf_async.assembly.body` — the robot's body as data (the robot file's ``body``) and
  its devices' mounts checked against its footprint;
* :mod:`~ubf_async.assembly.context` — ``DeviceContext``, what a backend factory is handed;
* :mod:`~ubf_async.assembly.backend` — ``Backend``, what every device backend is (its one
  closing contract, ``aclose``);
* :mod:`~ubf_async.assembly.devices` — building a device and its backend by name;
* :mod:`~ubf_async.assembly.robotfile` — robot files (typed YAML, ``FILE:LINE`` errors);
* :mod:`~ubf_async.assembly.simulation` — the typed seam between launch and a simulator.

May import: :mod:`ubf_async.runtime` and everything below it. Not :mod:`ubf_async.cli` (a
sibling), services or tools.
"""
