"""Test helper: a robot without a simulator, in its own process, that accepts remote behaviours.

    python -m tests.remote_robot --listen tcp/127.0.0.1:7450 --robot r1

It opens a bus, runs a state aggregator, the controller with the thesis's seek_pink_ball tree,
:class:`~ubf_async.services.remote.RemoteBehaviors`, a stand-in camera that publishes fixed
seekcolor bins every 0.11 s (pink in the centre by default, so seek-the-pink-ball chases:
speed +40, turn 0) and, as a robot on wall time does, its clock on ``ubf/<robot>/time``; it
tells senders what it refuses (``ubf/<robot>/refused/...``), as launch does. It prints
``ready`` once everything runs and stops on SIGTERM.

Also importable (``tests.remote_robot``) for the helpers the subprocess tests share.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import os
import queue
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path

from ubf_async.behaviors.pink_ball import seek_pink_ball
from ubf_async.cli.args import add_connection_arguments, connection_options
from ubf_async.runtime.aggregator import StateAggregator
from ubf_async.runtime.bus import Bus
from ubf_async.runtime.component import Component
from ubf_async.runtime.controller import Controller
from ubf_async.runtime.timekeepers import RobotTimeBeacon
from ubf_async.services.remote import RemoteBehaviors, remote_spec

ROOT = Path(__file__).resolve().parent.parent


class StandInCamera(Component):
    """Publishes the same seekcolor bins on ``sensor/camera/front`` every ``period_s``."""

    def __init__(self, *, bus: Bus, bins: Sequence[int], period_s: float = 0.11) -> None:
        super().__init__(bus=bus, name="camera-front")
        self.bins = list(bins)
        self.period_s = period_s

    async def run(self) -> None:
        pub = self.publisher(self.bus.keys.sensor("camera", "front"), "camera.seekcolor",
                             period_s=self.period_s)
        while True:
            pub.publish({"bins": self.bins, "total": sum(self.bins)})
            await asyncio.sleep(self.period_s)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m tests.remote_robot", description=__doc__)
    add_connection_arguments(parser)
    parser.add_argument("--bins", default="0,0,60,0,0", help="camera bins, comma-separated")
    parser.add_argument("--no-camera", action="store_true")
    parser.add_argument("--rate-hz", type=float, default=50.0)
    parser.add_argument("--remote", type=remote_spec, action="append", default=[],
                        metavar="NAME=PRIORITY[:WEIGHT]")
    return parser


async def run(args: argparse.Namespace) -> int:
    bus = await Bus.open(connection_options(args))
    root = seek_pink_ball()
    aggregator = StateAggregator(bus=bus, notify_refusals=True)
    components: list[Component] = [
        aggregator,
        Controller(bus=bus, aggregator=aggregator, root=root, rate_hz=args.rate_hz),
        RemoteBehaviors(bus=bus, root=root, config=dict(args.remote), notify_refusals=True),
        RobotTimeBeacon(bus=bus),
    ]
    if not args.no_camera:
        bins = [int(b) for b in args.bins.split(",")]
        components.append(StandInCamera(bus=bus, bins=bins))
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    loop.add_signal_handler(signal.SIGTERM, stop.set)
    loop.add_signal_handler(signal.SIGINT, stop.set)
    try:
        for component in components:
            await component.start()
        for component in components:
            await asyncio.wait_for(component.running.wait(), 10)
        print("ready", flush=True)
        await stop.wait()
        return 0
    finally:
        for component in reversed(components):
            await component.aclose()
        await bus.aclose()
        print("stopped", flush=True)


def main(argv: Sequence[str] | None = None) -> int:
    return asyncio.run(run(build_parser().parse_args(argv)))


# ---------------------------------------------------------------------------------------------
# Helpers for the subprocess tests


def cpu_wait_s(pid: int) -> float:
    """How long process ``pid``'s live threads have waited for a CPU while ready to run
    (Linux's run-queue wait, the second field of ``/proc/PID/task/TID/schedstat``): on a busy
    machine, what its wall times owe to the machine rather than to the process. 0 where that
    is not available."""
    waited = 0
    for stat in Path(f"/proc/{pid}/task").glob("*/schedstat"):
        with contextlib.suppress(OSError, IndexError, ValueError):
            waited += int(stat.read_text().split()[1])
    return waited / 1e9


class Process:
    """A child process whose stdout lines are collected by a reader thread: Python running
    ``argv``, or ``program`` (a compiled example) with ``argv`` as its arguments."""

    def __init__(self, *argv: str, program: str = sys.executable) -> None:
        self.argv = argv
        self.proc = subprocess.Popen(
            [program, *argv], cwd=ROOT, stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT, text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"},
        )
        self.lines: list[str] = []
        self._queue: queue.Queue[str | None] = queue.Queue()
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        with self.proc.stdout:
            for line in self.proc.stdout:
                self.lines.append(line.rstrip("\n"))
                self._queue.put(line)
        self._queue.put(None)

    def wait_for_line(self, text: str, *, timeout_s: float = 15.0) -> str:
        """Block until a line containing ``text`` is printed (AssertionError on timeout/EOF)."""
        return self._wait(lambda line: text in line, text, timeout_s)

    def wait_for_match(self, pattern: str, *, timeout_s: float = 15.0) -> str:
        """Block until a line in which the regular expression ``pattern`` is found is printed
        (AssertionError on timeout/EOF)."""
        return self._wait(re.compile(pattern).search, pattern, timeout_s)

    def _wait(self, found: Callable[[str], object], text: str, timeout_s: float) -> str:
        for line in self.lines:
            if found(line):
                return line
        deadline = time.monotonic() + timeout_s
        while True:
            remaining = deadline - time.monotonic()
            try:
                line = self._queue.get(timeout=max(0.0, remaining))
            except queue.Empty:
                raise AssertionError(
                    f"{self.argv[:2]}: no line with {text!r} within {timeout_s}s; output:\n"
                    + "\n".join(self.lines)) from None
            if line is None:
                raise AssertionError(f"{self.argv[:2]} exited ({self.proc.poll()}) before "
                                     f"printing {text!r}; output:\n" + "\n".join(self.lines))
            if found(line):
                return line.rstrip("\n")  # as the lines already read are kept

    @property
    def pid(self) -> int:
        return self.proc.pid

    def kill(self) -> None:
        """SIGKILL (idempotent) and reap."""
        with contextlib.suppress(ProcessLookupError):
            self.proc.kill()
        self.proc.wait(timeout=10)
        self._reader.join(timeout=5)

    def terminate(self, timeout_s: float = 10.0) -> int:
        """SIGTERM, wait for a clean exit (SIGKILL if it does not come); the exit code."""
        with contextlib.suppress(ProcessLookupError):
            self.proc.send_signal(signal.SIGTERM)
        try:
            code = self.proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            self.kill()
            raise
        self._reader.join(timeout=5)
        return code

    def output(self) -> str:
        return "\n".join(self.lines)


def start_robot(endpoint: str, robot: str, *extra: str) -> Process:
    """Start this module as a robot listening on ``endpoint``; returns once it is ready."""
    proc = Process("-m", "tests.remote_robot", "--listen", endpoint, "--robot", robot, *extra)
    try:
        proc.wait_for_line("ready")
    except BaseException:
        proc.kill()
        raise
    return proc


if __name__ == "__main__":
    sys.exit(main())
