"""Run an entry point as ``python -m MODULE ARGS`` would, then record the threads still alive
when it returned: ``python -m tests.exit_probe OUT.json MODULE ARGS...``.

Its exit status is the entry point's. ``OUT.json`` lists each live thread other than the main
one (name, daemon); a non-daemon one would keep the process from exiting. Faults injected
(before MODULE): ``--fault-aclose DOTTED.Class`` makes that component class's ``aclose`` raise
after closing, to show that one failing step does not skip the rest of the end;
``--slow-fsync S`` makes each ``fsync`` of an MCAP file wait S seconds first (a busy disk)."""

from __future__ import annotations

import contextlib
import importlib
import json
import os
import runpy
import sys
import threading
import time
from pathlib import Path
from typing import Any


def fault_aclose(dotted: str) -> None:
    module_name, _, class_name = dotted.rpartition(".")
    cls: Any = getattr(importlib.import_module(module_name), class_name)
    closing = cls.aclose

    async def aclose(self: Any) -> None:
        await closing(self)
        raise RuntimeError(f"{class_name}.aclose failed (a fault injected by the test)")

    cls.aclose = aclose


def slow_fsync(seconds: float) -> None:
    fsync = os.fsync

    def slowly(fd: Any) -> None:
        with contextlib.suppress(OSError):
            if os.readlink(f"/proc/self/fd/{int(fd)}").endswith(".mcap"):
                time.sleep(seconds)
        fsync(fd)

    os.fsync = slowly


def run_as_main(module: str, args: list[str]) -> Any:
    """``python -m MODULE ARGS`` in this process; the exit code its ``SystemExit`` carried."""
    sys.argv = [module, *args]
    try:
        runpy.run_module(module, run_name="__main__", alter_sys=True)
    except SystemExit as exc:
        return exc.code
    return 0


def main() -> int:
    args = sys.argv[1:]
    out = Path(args.pop(0))
    while args[0] in ("--fault-aclose", "--slow-fsync"):
        fault = args.pop(0)
        if fault == "--fault-aclose":
            fault_aclose(args.pop(0))
        else:
            slow_fsync(float(args.pop(0)))
    code = run_as_main(args.pop(0), args)
    threads = [{"name": t.name, "daemon": t.daemon} for t in threading.enumerate()
               if t is not threading.main_thread() and t.is_alive()]
    out.write_text(json.dumps(threads))
    return code if isinstance(code, int) else (0 if code is None else 1)


if __name__ == "__main__":
    sys.exit(main())
