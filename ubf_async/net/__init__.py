"""The network below the bus: how a process reaches zenoh.

* :mod:`~ubf_async.net.transport` — the transport seam: zenoh, or in-process for tests;
* :mod:`~ubf_async.net.secure` — secure mode: identities, the ACL, and applying them to a zenoh
  configuration (its command line is :mod:`ubf_async.tools.secure`).

May import: :mod:`ubf_async.errors`, :mod:`ubf_async.throttle`. Not the wire, the core or the
runtime: a transport moves bytes under key expressions it is given.
"""
