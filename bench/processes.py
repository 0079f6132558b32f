"""Child processes of the benchmarks."""

from __future__ import annotations

import subprocess
from typing import Any


def terminate(proc: subprocess.Popen[Any], *, timeout_s: float = 10.0) -> None:
    """Ask ``proc`` to stop (SIGTERM), kill it if it has not within ``timeout_s``; harmless
    if it already ended."""
    if proc.poll() is not None:
        return
    proc.terminate()
    try:
        proc.wait(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
