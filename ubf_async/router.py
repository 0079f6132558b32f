"""``python -m ubf_async.router``: the public entry point, kept at this path. The program is
:mod:`ubf_async.tools.router`; import from there."""

from ubf_async.tools.router import main

__all__ = []

if __name__ == "__main__":
    raise SystemExit(main())
