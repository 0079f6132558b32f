"""The wire: what crosses the bus, and how.

* :mod:`~ubf_async.wire.keys` — key expressions ``ubf/<robot>/...`` and the ROS 2 keys beside
  them (string builders only: every key of the project is made with them);
* :mod:`~ubf_async.wire.topics` — every topic declared once: key, schema, typed message;
* :mod:`~ubf_async.wire.protocol` — the msgpack codec (untrusted input → ``ProtocolError``).

May import: :mod:`ubf_async.errors`, :mod:`ubf_async.throttle`. Nothing of the UBF core, the
network or the runtime (``[tool.importlinter]`` in pyproject.toml checks it).
"""
