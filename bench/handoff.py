"""The bridge hand-off: what it costs to get a sample from a transport thread to a handler on
the event loop, piece by piece, on the opt-in lending loop (:mod:`ubf_async.runtime.lending`,
``UBF_LOOP=lending``), on asyncio's plain loop (what every entry point runs on by default)
and on uvloop (when installed).

    python -m bench.handoff [--n 3000] [--baseline OLD_BUS_PY] [--json FILE]

Sections (medians, p99 and max in µs):

* ``call_soon_threadsafe`` — the call alone, from a foreign thread (an idle loop: each call
  writes the loop's wake-up byte);
* ``lock`` — acquire + release of an uncontended ``threading.Lock``;
* ``push()`` — :meth:`Subscription.push` from a foreign thread, the drain not yet scheduled
  (the call that pays for the wake-up) and already scheduled (a burst's later samples);
* ``hand-off, idle loop`` — from just before ``push()`` on a foreign thread to the handler on
  the loop, one sample at a time (the loop sleeps in between, as it does between sensor
  samples, :data:`PACE_S` apart): what the reflex path pays. The subscription is ``direct``
  (as the aggregator's): on the lending loop the handler then runs on the pushing thread at
  once;
* ``zenoh put → bus handler`` — a plain zenoh session puts, a :class:`Bus` on another session
  (loopback TCP) delivers to its handler: the hand-off with zenoh's own thread in front.

``--baseline`` loads another version of ``ubf_async/runtime/bus.py`` (e.g. ``git show
HEAD~1:ubf_async/runtime/bus.py > /tmp/old_bus.py``) and measures its ``Subscription`` in the same
run, so before/after figures share the machine's load.
"""

from __future__ import annotations

import argparse
import asyncio
import importlib.util
import json
import socket
import statistics
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from types import ModuleType
from typing import Any

import zenoh

from ubf_async.net.options import ConnectionOptions
from ubf_async.runtime import bus as current_bus
from ubf_async.runtime import lending
from ubf_async.runtime.bus import Bus

SAMPLE = bytes(60)
"""About the size of an encoded range sample."""
PACE_S = 0.002
"""Between two samples of the one-at-a-time measurements: a sensor's pace (500 Hz), under
the direct subscriptions' budget (``ubf_async.runtime.bus.DIRECT_RATE_HZ``), and the loop goes back
to sleep in between as it does between sensor samples."""
LoopFactory = Callable[[], asyncio.AbstractEventLoop]


def summarize(values_ns: list[int]) -> dict[str, float]:
    values = sorted(values_ns)
    if not values:
        return {"n": 0}
    return {"n": len(values), "median_us": statistics.median(values) / 1e3,
            "p99_us": values[min(len(values) - 1, int(len(values) * 0.99))] / 1e3,
            "max_us": values[-1] / 1e3}


def loops() -> dict[str, LoopFactory]:
    out: dict[str, LoopFactory] = {"lending": lending.new_event_loop,
                                   "asyncio": asyncio.new_event_loop}
    try:
        import uvloop
    except ImportError:
        print("uvloop not installed: asyncio's loop only", file=sys.stderr)
    else:
        out["uvloop"] = uvloop.new_event_loop
    return out


def run_on(factory: LoopFactory, main: Callable[[], Any]) -> Any:
    with asyncio.Runner(loop_factory=factory) as runner:
        return runner.run(main())


def load_bus(path: Path) -> ModuleType:
    spec = importlib.util.spec_from_file_location("baseline_bus", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


# ---------------------------------------------------------------------------------------------


async def micro(n: int) -> dict[str, dict[str, float]]:
    loop = asyncio.get_running_loop()
    lock = threading.Lock()

    def noop() -> None:
        pass

    def in_thread() -> tuple[list[int], list[int]]:
        soon, locked = [], []
        for _ in range(n):
            t0 = time.perf_counter_ns()
            loop.call_soon_threadsafe(noop)
            soon.append(time.perf_counter_ns() - t0)
            t0 = time.perf_counter_ns()
            with lock:
                pass
            locked.append(time.perf_counter_ns() - t0)
        return soon, locked

    soon, locked = await asyncio.to_thread(in_thread)
    return {"call_soon_threadsafe (foreign thread)": summarize(soon),
            "threading.Lock acquire+release": summarize(locked)}


async def push_costs(module: ModuleType, n: int) -> dict[str, dict[str, float]]:
    loop = asyncio.get_running_loop()
    sub = module.Subscription(loop, lambda k, p, t: None, latest=True)

    def in_thread() -> tuple[list[int], list[int]]:
        first, more = [], []
        for _ in range(n):
            while sub._scheduled:  # the previous drain ran: this push pays the wake-up
                time.sleep(0)
            t0 = time.perf_counter_ns()
            sub.push("k", SAMPLE)
            t1 = time.perf_counter_ns()
            sub.push("k", SAMPLE)  # the drain is scheduled: coalesces, no wake-up
            t2 = time.perf_counter_ns()
            first.append(t1 - t0)
            more.append(t2 - t1)
        return first, more

    first, more = await asyncio.to_thread(in_thread)
    return {"push(), schedules the drain": summarize(first),
            "push(), drain already scheduled": summarize(more)}


async def drain_costs(module: ModuleType, n: int) -> dict[str, dict[str, float]]:
    """The drain alone, called directly on the loop: one sample (latest mode), and a burst
    of 64 (every mode, per sample)."""
    loop = asyncio.get_running_loop()
    one, burst = [], []
    latest = module.Subscription(loop, lambda k, p, t: None, latest=True)
    every = module.Subscription(loop, lambda k, p, t: None, latest=False)
    for _ in range(n):
        latest.push("k", SAMPLE, on_loop=True)
        t0 = time.perf_counter_ns()
        latest._drain()
        one.append(time.perf_counter_ns() - t0)
        for _ in range(64):
            every.push("k", SAMPLE, on_loop=True)
        t0 = time.perf_counter_ns()
        every._drain()
        burst.append((time.perf_counter_ns() - t0) // 64)
        await asyncio.sleep(0)  # run the drains push() scheduled (now empty)
    return {"drain, 1 sample (latest)": summarize(one),
            "drain, burst of 64 (every), per sample": summarize(burst)}


async def idle_handoff(module: ModuleType, n: int, warm: int = 200) -> dict[str, float]:
    loop = asyncio.get_running_loop()
    lags: list[int] = []
    handled = threading.Event()
    sent = [0]

    def handler(key: str, payload: bytes, received_ns: int) -> None:
        lags.append(time.perf_counter_ns() - sent[0])
        handled.set()

    try:  # direct, as the aggregator's (a baseline bus.py may not know it)
        sub = module.Subscription(loop, handler, latest=True, direct=True)
    except TypeError:
        sub = module.Subscription(loop, handler, latest=True)

    def pusher() -> None:
        for _ in range(n + warm):
            handled.clear()
            sent[0] = time.perf_counter_ns()
            sub.push("k", SAMPLE)
            handled.wait(1.0)
            time.sleep(PACE_S)

    await asyncio.to_thread(pusher)
    return summarize(lags[warm:])


def free_endpoint() -> str:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


async def zenoh_handoff(n: int, warm: int = 200) -> dict[str, dict[str, float]]:
    endpoint = free_endpoint()
    robot = "handoff"
    bus = await Bus.open(ConnectionOptions(robot=robot, listen=[endpoint]))
    lags: list[int] = []
    bridge: list[int] = []
    handled = threading.Event()
    sent = [0]

    def handler(key: str, payload: bytes, received_ns: int) -> None:
        lags.append(time.perf_counter_ns() - sent[0])
        bridge.append(time.monotonic_ns() - received_ns)  # push() on zenoh's thread → here
        handled.set()

    bus.subscribe(f"ubf/{robot}/sensor/range/front", handler, direct=True)
    conf = ConnectionOptions(robot=robot, connect=[endpoint]).zenoh_config()
    session = await asyncio.to_thread(zenoh.open, conf)
    pub = session.declare_publisher(f"ubf/{robot}/sensor/range/front")
    try:
        def putter() -> None:
            deadline = time.monotonic() + 10
            while not pub.matching_status.matching:  # type: ignore[attr-defined]
                if time.monotonic() > deadline:
                    raise TimeoutError("the bus's subscriber never matched")
                time.sleep(0.01)
            for _ in range(n + warm):
                handled.clear()
                sent[0] = time.perf_counter_ns()
                pub.put(SAMPLE)
                handled.wait(1.0)
                time.sleep(PACE_S)

        await asyncio.to_thread(putter)
    finally:
        pub.undeclare()
        await asyncio.to_thread(session.close)
        await bus.aclose()
    return {"zenoh put → bus handler (loopback, 2 sessions)": summarize(lags[warm:]),
            "  of which bridge: zenoh callback → handler": summarize(bridge[warm:])}


def run(n: int, baseline: Path | None) -> dict[str, Any]:
    modules: dict[str, ModuleType] = {"current": current_bus}
    if baseline is not None:
        modules["baseline"] = load_bus(baseline)
    out: dict[str, Any] = {}
    for loop_name, factory in loops().items():
        section: dict[str, Any] = run_on(factory, lambda: micro(n))
        for rnd in range(2):  # alternate, so a slow patch of the machine hits both
            for name, module in modules.items():
                costs = run_on(factory, lambda m=module: push_costs(m, n))  # type: ignore[misc]
                costs.update(run_on(factory, lambda m=module: drain_costs(m, n)))  # type: ignore[misc]
                for what, figures in costs.items():
                    section.setdefault(f"{what} [{name}]", []).append(figures)
                figures = run_on(factory, lambda m=module: idle_handoff(m, n))  # type: ignore[misc]
                section.setdefault(f"hand-off, idle loop [{name}]", []).append(figures)
            del rnd
        section.update(run_on(factory, lambda: zenoh_handoff(n)))
        out[loop_name] = {k: (v if isinstance(v, dict) else min(v, key=lambda f: f["median_us"]))
                          for k, v in section.items()}
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--n", type=int, default=3000, help="samples per measurement")
    parser.add_argument("--baseline", type=Path, default=None, metavar="BUS_PY",
                        help="another ubf_async/runtime/bus.py to measure beside this one")
    parser.add_argument("--json", type=Path, default=None, metavar="FILE")
    args = parser.parse_args()
    results = run(args.n, args.baseline)
    for loop_name, section in results.items():
        print(f"\n{loop_name}")
        for what, f in section.items():
            print(f"  {what:58s} median {f['median_us']:7.2f} µs  p99 {f['p99_us']:7.2f} µs  "
                  f"max {f['max_us']:8.1f} µs  (n={f['n']})")
    if args.json is not None:
        args.json.write_text(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()
