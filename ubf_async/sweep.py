"""``python -m ubf_async.sweep``: the public entry point. The program is
:mod:`ubf_async.tools.sweep`; the library :mod:`ubf_async.runs.sweep`."""

from ubf_async.tools.sweep import main

__all__ = []

if __name__ == "__main__":
    raise SystemExit(main())
