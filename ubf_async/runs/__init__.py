"""Runs of a robot: the wiring launch runs behind its command line, the same run as a library
call in this process, and sweeps of many runs.

* :mod:`~ubf_async.runs.wiring` — one robot wired from a checked plan: its devices (through the
  plug-in registries), the state aggregator, the controller with the robot file's tree, the
  remote behaviours' slots, the live-tree service, the simulator when a device needs one; and
  the ordered end that saves the results and closes everything. ``launch`` (a zenoh session,
  a console) and :func:`~ubf_async.runs.inprocess.run` (the in-process transport, no console)
  both run exactly this, so a run is the same byte for byte either way.
* :mod:`~ubf_async.runs.inprocess` — ``run(robot, scenario, seed=…)``: one simulated run in the
  calling process, flat out, no sockets, returning its summary, verdicts and trajectory
  (public as :mod:`ubf_async.experiment`).
* :mod:`~ubf_async.runs.overrides` — a robot file with values replaced at paths
  (``tree.children[1].params.period_s``), checked as the robot file is.
* :mod:`~ubf_async.runs.sweep` — the product of robots, scenarios and seeds run on every
  core or on a Ray cluster, into one table (``python -m ubf_async.sweep``).

May import ``services`` and everything below it; only the tools and the entry modules import
it.
"""
