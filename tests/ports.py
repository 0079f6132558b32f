"""Loopback ports for the tests' servers and subprocesses, one allocator per process.

It lives here, not in ``conftest.py``: pytest loads ``conftest.py`` as ``conftest`` while the
tests import ``tests.conftest``, two modules with two counters, so two callers of the same
worker were handed the same port (a robot told to ``--connect`` to its own ``--listen``).
"""

from __future__ import annotations

import os
import socket

__all__ = ["PORTS_FROM", "PORTS_PER_WORKER", "free_port"]

PORTS_PER_WORKER = 1500
PORTS_FROM = 20000
"""Under pytest-xdist each worker takes its loopback ports from its own block below the
kernel's ephemeral range (32768-): a port one worker just found free and handed to a
subprocess cannot be found free by another worker before the subprocess binds it."""
_next_port: dict[str, int] = {}


def free_port() -> int:
    worker = os.environ.get("PYTEST_XDIST_WORKER", "")
    if not worker.startswith("gw"):
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            s.bind(("127.0.0.1", 0))
            return s.getsockname()[1]
    first = PORTS_FROM + int(worker[2:]) % 8 * PORTS_PER_WORKER
    # In turn through the block (from a point set by the pid, so that a child process of
    # this worker starts elsewhere): a port handed out is not handed out again soon.
    for _ in range(PORTS_PER_WORKER):
        offset = _next_port.setdefault(worker, os.getpid() * 97 % PORTS_PER_WORKER)
        _next_port[worker] = (offset + 1) % PORTS_PER_WORKER
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            try:
                s.bind(("127.0.0.1", first + offset))
            except OSError:
                continue
            return first + offset
    raise RuntimeError(f"no free loopback port in {first}-{first + PORTS_PER_WORKER - 1}")
