"""``python -m ubf_async.launch``: the public entry point, kept at this path. The program is
:mod:`ubf_async.tools.launch`; import from there."""

from ubf_async.tools.launch import main

__all__ = []

if __name__ == "__main__":
    raise SystemExit(main())
