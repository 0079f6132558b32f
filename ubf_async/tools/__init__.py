"""The command-line tools: each a ``main(argv) -> int``, run by ``python -m ubf_async.<tool>``
(a thin module at the package's top level) and by its console script.

``launch`` (the composition root of one robot), ``fleet``, ``inspector``, ``record``,
``replay``, ``liveview``, ``router``, ``secure`` and ``robotfile_check``
(``python -m ubf_async.robotfile``); and ``remote_host``, what a remote behaviour's own program
(``examples/avoid_obstacles.py``) runs.

May import anything of the framework; nothing imports it but the top-level entry modules (and
tests).
"""
