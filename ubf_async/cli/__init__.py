"""What every command-line program shares.

* :mod:`~ubf_async.cli.run` — the main wrapper: stop signals, exit codes, the event loop;
* :mod:`~ubf_async.cli.ending` — how a program ends: ordered, bounded steps, safe streams;
* :mod:`~ubf_async.cli.trim` — freed memory handed back to the system every minute;
* :mod:`~ubf_async.cli.attach` — a tool attaching to a running robot from another process.

May import: :mod:`ubf_async.runtime` and everything below it. Not :mod:`ubf_async.assembly` (a
sibling), services or tools. ``SystemExit`` is raised by a program's ``main`` only.
"""
