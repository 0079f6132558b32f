"""Services a running robot offers over the bus, beside its controller.

* :mod:`~ubf_async.services.remote` — behaviours in other processes voting into a composite;
* :mod:`~ubf_async.services.live` — live tree changes over a zenoh queryable;
* :mod:`~ubf_async.services.status` — the status line;
* :mod:`~ubf_async.services.liveview` — the robot in Foxglove (converters, the server).

May import: :mod:`ubf_async.assembly`, :mod:`ubf_async.cli`, and everything below them. Never
:mod:`ubf_async.tools`.
"""
