"""A radio backend on the process's terminal: lines typed in arrive, messages out are printed.

The thesis's radio was a socket to a serial line carrying plain text; standard input/output
is the same thing for a process started by hand.
"""

from __future__ import annotations

import queue
import sys
import threading
from typing import TextIO

from components.radio.backend import RadioBackend
from ubf_async.assembly.context import DeviceContext

__all__ = ["StdioRadioBackend", "stdio_backend"]


class StdioRadioBackend(RadioBackend):
    def __init__(self, *, stdin: TextIO | None = None, stdout: TextIO | None = None) -> None:
        self._in = stdin or sys.stdin
        self._out = stdout or sys.stdout
        self._queue: queue.SimpleQueue[str] = queue.SimpleQueue()
        # Reading a terminal blocks: a daemon thread does it so the event loop never waits.
        threading.Thread(target=self._read, name="radio-stdin", daemon=True).start()

    def _read(self) -> None:
        for line in self._in:
            text = line.rstrip("\n")
            if text:
                self._queue.put(text)

    def send(self, text: str) -> None:
        print(f"radio> {text}", file=self._out, flush=True)

    def receive(self) -> list[str]:
        out = []
        while True:
            try:
                out.append(self._queue.get_nowait())
            except queue.Empty:
                return out


def stdio_backend(*, context: DeviceContext) -> StdioRadioBackend:
    """``radio.stdio``: lines typed on the process's standard input arrive; messages sent are
    printed on its standard output."""
    return StdioRadioBackend()


stdio_backend.requires_simulator = None  # type: ignore[attr-defined]
