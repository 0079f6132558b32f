"""``python -m ubf_async.monitor``: the public entry point, kept at this path. The program is
:mod:`ubf_async.tools.monitor`; the monitor itself is :mod:`ubf_async.services.monitor`."""

from ubf_async.tools.monitor import main

__all__ = []

if __name__ == "__main__":
    raise SystemExit(main())
