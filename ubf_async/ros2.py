"""``python -m ubf_async.ros2``: the public entry point, kept at this path. The program is
:mod:`ubf_async.tools.ros2`; the bridge itself :mod:`ubf_async.services.ros2`."""

from ubf_async.tools.ros2 import main

__all__ = []

if __name__ == "__main__":
    raise SystemExit(main())
