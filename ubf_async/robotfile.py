"""``python -m ubf_async.robotfile``: the public entry point, kept at this path. The program is
:mod:`ubf_async.tools.robotfile_check`; import from there."""

from ubf_async.tools.robotfile_check import main

__all__ = []

if __name__ == "__main__":
    raise SystemExit(main())
