"""``python -m ubf_async.inspector``: the public entry point, kept at this path. The program is
:mod:`ubf_async.tools.inspector`; import from there."""

from ubf_async.tools.inspector import main

__all__ = []

if __name__ == "__main__":
    raise SystemExit(main())
