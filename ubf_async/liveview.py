"""``python -m ubf_async.liveview``: the public entry point, kept at this path. The program is
:mod:`ubf_async.tools.liveview`; import from there."""

from ubf_async.tools.liveview import main

__all__ = []

if __name__ == "__main__":
    raise SystemExit(main())
