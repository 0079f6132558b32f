"""The network below the bus: how a process reaches zenoh.

* :mod:`~ubf_async.net.transport` — the transport seam: zenoh, or in-process for tests;
* :mod:`~ubf_async.net.secure` — secure mode's mechanism: a set-up's identities and files,
  the ACL as zenoh's section from the grants :mod:`ubf_async.access` hands it (the policy:
  made of the wire's keys, above this room), applying a set-up to a zenoh configuration over
  mutual TLS, an identity's rights against its grants, and why a robot refused this process
  (its command line is :mod:`ubf_async.tools.secure`);
* :mod:`~ubf_async.net.pki` — the set-up's certificate authority and certificates;
* :mod:`~ubf_async.net.tlsprobe` — a TLS handshake of this process's own, to tell why a TLS
  endpoint refused it.

May import: :mod:`ubf_async.errors`, :mod:`ubf_async.throttle`. Not the wire, the core or the
runtime: a transport moves bytes under key expressions it is given, and spells none out
(``tests/test_access.py``).
"""
