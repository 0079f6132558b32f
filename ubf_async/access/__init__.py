"""Access: who may say what on a robot's network in secure mode, above the transport.

* :mod:`~ubf_async.access.policy` — what each identity may do, named with the wire's keys, as
  :class:`~ubf_async.net.secure.Grant` data the transport turns into zenoh's access control;
* :mod:`~ubf_async.access.setup` — the identities of a robot file or a fleet, a set-up made
  (``secure init``) or an identity revoked with its grants, and what this process may send
  (the bus asks it when it opens).

Between the transport and the runtime because the policy is made of the protocol's keys, which
a transport does not know, and the bus below every tool checks its rights before each act.

May import: :mod:`ubf_async.net`, :mod:`ubf_async.wire` and the rooms below them (``core`` and
``clocks`` too, which it does not need). Not the runtime or anything above it.
"""
