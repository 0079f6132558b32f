"""The UBF core: pure Python, no I/O, no middleware.

* :mod:`~ubf_async.core.action` — ``Action`` (unset ≠ zero, validated), ``clamp_command``;
* :mod:`~ubf_async.core.state` — ``State``, the read-only snapshot a tick sees;
* :mod:`~ubf_async.core.behavior` — ``Behavior``, ``Composite``, ``Arbiter``, ``Trace``;
* :mod:`~ubf_async.core.arbiters` — the arbiters (the thesis's ``PriorityMerge`` and others).

May import: :mod:`ubf_async.wire` (a state holds wire messages), :mod:`ubf_async.errors`,
:mod:`ubf_async.throttle`. Never the network, the runtime or the plug-in registry.
"""
