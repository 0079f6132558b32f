"""Safety margins measured end to end across processes: ``python -m bench.margins``.

(a) **Motor watchdog.** A motors device (the real :class:`MotorsComponent`, wall clock, a
    backend that only records the pulses) runs in its own process
    (``python -m bench.margins motors-device ...``). This process publishes drive commands at
    50 Hz for ``--burst-s``, stops, and waits for the ``motors.applied`` sample with reason
    ``timeout``. Per trial it reports *stop*: the applied sample's stamp (when the stop pulse
    was applied) − when the last command was sent, and *seen*: when that sample arrived back
    here − when the last command was sent (includes the report's own trip). The goal is
    :data:`~components.motors.component.STOP_GOAL_S` (200 ms).

(b) **Staleness.** A sensor in its own process (``python -m bench.margins sensor ...``)
    publishes ``range`` samples declaring ``period_s`` in bursts, with silences between them.
    Here a :class:`~ubf_async.runtime.aggregator.StateAggregator` (the robot's state) is polled
    every millisecond; each trial is the time from the last sample's stamp until the snapshot marks
    the source stale, in periods (the goal is 2).

Every time is ``CLOCK_MONOTONIC`` of this host, read in one process or carried in stamps.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from bench.latency_stats import percentile
from bench.processes import terminate
from components.motors.backend import MotorBackend
from ubf_async.net.options import ConnectionOptions
from ubf_async.runtime.bus import Bus
from ubf_async.wire.protocol import decode

ROOT = Path(__file__).resolve().parent.parent
ROBOT = "margins"


def free_endpoint() -> str:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


def child(*args: str) -> subprocess.Popen[bytes]:
    return subprocess.Popen([sys.executable, "-m", "bench.margins", *args], cwd=ROOT)


def stats_ms(values_s: list[float]) -> str:
    ms = sorted(v * 1e3 for v in values_s)
    return (f"median {percentile(ms, 50):.1f} ms, p99 {percentile(ms, 99):.1f} ms, "
            f"max {ms[-1]:.1f} ms (min {ms[0]:.1f} ms, n={len(ms)})")


# ---------------------------------------------------------------------------------------------
# Child processes


class RecordingBackend(MotorBackend):
    """Accepts pulses and remembers the last (no hardware on a bench machine)."""

    hold_s = 0.0

    def __init__(self) -> None:
        self.pulses: tuple[float, float] | None = None

    def apply_pulses(self, *, left_ms: float, right_ms: float) -> None:
        self.pulses = (left_ms, right_ms)


async def serve_motors(endpoint: str, timeout_s: float | None) -> None:
    from components.motors.component import DEFAULT_TIMEOUT_S, MotorsComponent

    bus = await Bus.open(ConnectionOptions(robot=ROBOT, connect=[endpoint]))
    motors = MotorsComponent(bus=bus, backend=RecordingBackend(),
                             timeout_s=timeout_s or DEFAULT_TIMEOUT_S)
    async with bus, motors:
        await asyncio.Event().wait()


async def serve_sensor(endpoint: str, period_s: float, bursts: int, burst_s: float,
                       pause_s: float) -> None:
    bus = await Bus.open(ConnectionOptions(robot=ROBOT, connect=[endpoint]))
    async with bus:
        pub = bus.publisher(bus.keys.sensor("range", "bench"), "range", period_s=period_s)
        await pub.wait_for_subscribers(timeout_s=30)
        for _ in range(bursts):
            start = time.monotonic()
            n = 0
            while time.monotonic() < start + burst_s:
                pub.publish({"range_mm": 500, "status": "ok"})
                n += 1
                await asyncio.sleep(max(0.0, start + n * period_s - time.monotonic()))
            await asyncio.sleep(pause_s)


# ---------------------------------------------------------------------------------------------
# Measurements


async def measure_watchdog(trials: int, burst_s: float, timeout_s: float | None) -> list[float]:
    from components.motors.component import DEFAULT_TIMEOUT_S, STOP_GOAL_S

    endpoint = free_endpoint()
    bus = await Bus.open(ConnectionOptions(robot=ROBOT, listen=[endpoint]))
    args = ["motors-device", endpoint] + ([f"--timeout-s={timeout_s}"] if timeout_s else [])
    proc = child(*args)
    applied: asyncio.Queue[tuple[int, int, str]] = asyncio.Queue()
    stops: list[float] = []
    seen: list[float] = []
    try:
        bus.subscribe(bus.keys.sensor("motors", "main"),
                      lambda k, p, t: applied.put_nowait((t, decode(p).stamp_ns,
                                                          decode(p).data.reason)),
                      latest=False)
        pub = bus.publisher(bus.keys.cmd("drive"), "drive", period_s=0.02)
        await pub.wait_for_subscribers(timeout_s=30)
        for _ in range(trials):
            start = time.monotonic_ns()
            n = 0
            last_sent = start
            while time.monotonic_ns() < start + burst_s * 1e9:
                pub.publish({"speed": 30.0, "turn": 0.0})
                last_sent = time.monotonic_ns()
                n += 1
                await asyncio.sleep(max(0.0, (start + n * 20_000_000 - time.monotonic_ns()) / 1e9))
            while True:
                received_ns, stamp_ns, reason = await asyncio.wait_for(applied.get(), 5)
                if reason == "timeout" and stamp_ns > last_sent:
                    break
            stops.append((stamp_ns - last_sent) / 1e9)
            seen.append((received_ns - last_sent) / 1e9)
    finally:
        terminate(proc)
        await bus.aclose()
    print(f"(a) motor watchdog, timeout {(timeout_s or DEFAULT_TIMEOUT_S) * 1e3:.0f} ms, "
          f"commands at 50 Hz from another process, {trials} trials:")
    print(f"    stop applied after the last command sent: {stats_ms(stops)}")
    print(f"    stop seen back by the sender:             {stats_ms(seen)}")
    verdict = "meets" if max(stops) <= STOP_GOAL_S else "MISSES"
    print(f"    {verdict} the {STOP_GOAL_S * 1e3:.0f} ms goal (judged on 'stop applied'; 'seen' "
          "adds the report's trip back and this process's own scheduling)")
    return stops


async def measure_staleness(trials: int, period_s: float) -> list[float]:
    from ubf_async.runtime.aggregator import StateAggregator

    endpoint = free_endpoint()
    bus = await Bus.open(ConnectionOptions(robot=ROBOT, listen=[endpoint]))
    aggregator = StateAggregator(bus=bus)
    burst_s, pause_s = 5 * period_s, 6 * period_s
    proc = child("sensor", endpoint, f"--period-s={period_s}", f"--bursts={trials + 1}",
                 f"--burst-s={burst_s}", f"--pause-s={pause_s}")
    periods: list[float] = []
    source = "range/bench"
    try:
        async with aggregator:
            deadline = time.monotonic() + 60 + trials * (burst_s + pause_s) * 2
            was_stale = True
            while len(periods) < trials and time.monotonic() < deadline:
                await asyncio.sleep(0.001)
                reading = aggregator.snapshot().get(source)
                if reading is None:
                    continue
                if reading.stale and not was_stale:
                    periods.append((time.monotonic_ns() - reading.stamp_ns) / 1e9 / period_s)
                was_stale = reading.stale
    finally:
        terminate(proc)
        await bus.aclose()
    if len(periods) < trials:
        raise RuntimeError(f"only {len(periods)} of {trials} staleness trials completed")
    ordered = sorted(periods)
    print(f"(b) staleness, a sensor in another process declaring period_s={period_s:g} s "
          f"stops; the aggregator's snapshot polled every 1 ms, {trials} trials:")
    print(f"    stale after the last sample's stamp: median {percentile(ordered, 50):.2f}, "
          f"p99 {percentile(ordered, 99):.2f}, max {ordered[-1]:.2f} periods "
          f"(max {ordered[-1] * period_s * 1e3:.0f} ms)")
    verdict = "meets" if ordered[-1] <= 2.0 else "MISSES"
    print(f"    {verdict} the goal of 2 periods")
    return periods


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.margins", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command")
    motors = sub.add_parser("motors-device", help="(child) a motors device on wall time")
    motors.add_argument("endpoint")
    motors.add_argument("--timeout-s", type=float, default=None)
    sensor = sub.add_parser("sensor", help="(child) a sensor publishing in bursts")
    sensor.add_argument("endpoint")
    sensor.add_argument("--period-s", type=float, required=True)
    sensor.add_argument("--bursts", type=int, required=True)
    sensor.add_argument("--burst-s", type=float, required=True)
    sensor.add_argument("--pause-s", type=float, required=True)
    parser.add_argument("--trials", type=int, default=20)
    parser.add_argument("--burst-s", type=float, default=0.5,
                        help="how long commands flow before each watchdog trial")
    parser.add_argument("--timeout-s", type=float, default=None,
                        help="the watchdog timeout to measure (default: the motors' default)")
    parser.add_argument("--period-s", type=float, default=0.11,
                        help="the sensor's declared period (0.11 s: the camera's)")
    parser.add_argument("--only", choices=("watchdog", "staleness"), default=None)
    args = parser.parse_args(argv)
    runs: dict[str, Any] = {
        "motors-device": lambda: serve_motors(args.endpoint, args.timeout_s),
        "sensor": lambda: serve_sensor(args.endpoint, args.period_s, args.bursts, args.burst_s,
                                       args.pause_s),
    }
    if args.command in runs:
        with contextlib.suppress(KeyboardInterrupt):
            asyncio.run(runs[args.command]())
        return 0

    async def both() -> None:
        if args.only in (None, "watchdog"):
            await measure_watchdog(args.trials, args.burst_s, args.timeout_s)
        if args.only in (None, "staleness"):
            await measure_staleness(args.trials, args.period_s)

    asyncio.run(both())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
