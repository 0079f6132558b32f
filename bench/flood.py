"""A valid sample flood on a reflex source, and a junk-key flood, against a running robot.

The robot (state aggregator + controller at 50 Hz with ``range/`` reflexes and the
seek-the-pink-ball tree) runs in this process on a loopback zenoh endpoint; the flooders are
separate processes publishing plain zenoh + msgpack. Three phases, measured in the same run:

1. baseline: no flood, ``--baseline-s`` seconds;
2. flood: ``--rate`` valid ``range`` samples a second on ``range/front`` for ``--seconds``;
3. junk: 1024 distinct junk sensor keys, then the tick cost with them in the table.

Printed: drive commands/s, periodic tick rate, their ratios to the baseline, tick cost
(median, p99, max), and what the aggregator refused. Goals (issue 13): commands ≤ 2× the
configured rate, periodic tick rate within 5 % of the baseline.

    python -m bench.flood [--rate 10000] [--seconds 10] [--baseline-s 5] [--json FILE]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import statistics
import sys
import time
from typing import Any

from tests.conftest import free_port
from ubf_async.behaviors.pink_ball import seek_pink_ball
from ubf_async.net.options import ConnectionOptions
from ubf_async.runtime.aggregator import StateAggregator
from ubf_async.runtime.bus import Bus
from ubf_async.runtime.controller import Controller
from ubf_async.wire.protocol import Message

RATE_HZ = 50.0

FLOODER = r'''
import json, sys, time
import msgpack, zenoh

endpoint, robot, mode, rate, duration = sys.argv[1:]
rate, duration = float(rate), float(duration)
conf = zenoh.Config()
conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
conf.insert_json5("scouting/multicast/enabled", "false")
session = zenoh.open(conf)
pub = session.declare_publisher(f"ubf/{robot}/sensor/range/front")
while not pub.matching_status.matching:
    time.sleep(0.01)
print("start", flush=True)
RANGE = {"range_mm": 300, "status": "ok"}
start = time.monotonic()
n = 0
while (now := time.monotonic()) < start + duration:
    while n < min(int((now - start) * rate) + 1, int(rate * duration)):
        n += 1
        payload = msgpack.packb({"schema": "range", "v": 1, "stamp_ns": time.monotonic_ns(),
                                 "seq": n, "data": RANGE})
        if mode == "flood":
            pub.put(payload)
        else:
            session.put(f"ubf/{robot}/sensor/junk/k{n}", payload)
    time.sleep(0.0005)
print(f"done {n}", flush=True)
session.close()
'''


async def flooder(endpoint: str, robot: str, mode: str, rate: float,
                  duration_s: float) -> asyncio.subprocess.Process:
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-c", FLOODER, endpoint, robot, mode, str(rate), str(duration_s),
        stdout=asyncio.subprocess.PIPE)
    assert proc.stdout is not None
    line = await asyncio.wait_for(proc.stdout.readline(), 20)
    assert line.startswith(b"start"), line
    return proc


def tick_costs_us(ctl: Controller, ticks: int) -> dict[str, float]:
    recent = sorted(list(ctl.stats.tick_ns)[-min(ticks, 1000):])
    if not recent:
        return {}
    return {"median_us": statistics.median(recent) / 1e3,
            "p99_us": recent[int(0.99 * (len(recent) - 1))] / 1e3,
            "max_us": recent[-1] / 1e3}


async def window(ctl: Controller, seconds: float | None = None,
                 until: asyncio.subprocess.Process | None = None) -> dict[str, Any]:
    """Commands and periodic ticks over a window of ``seconds`` or until ``until`` ends."""
    t0, ticks0, periodic0 = time.monotonic(), ctl.stats.ticks, ctl.stats.periodic
    limited0 = ctl.stats.reflex_limited
    if until is not None:
        assert until.stdout is not None
        await until.stdout.readline()  # "done N"
        await until.wait()
    else:
        await asyncio.sleep(seconds or 0)
    elapsed = time.monotonic() - t0
    ticks = ctl.stats.ticks - ticks0
    return {"seconds": elapsed, "commands_per_s": ticks / elapsed,
            "periodic_hz": (ctl.stats.periodic - periodic0) / elapsed,
            "reflex_limited": ctl.stats.reflex_limited - limited0,
            "tick": tick_costs_us(ctl, ticks)}


def in_process_tick_cost(sources: int) -> dict[str, float]:
    """Tick cost with ``sources`` sources in the table, without zenoh (for comparison)."""

    class FakeBus:
        from ubf_async.clocks.clock import WallClock
        clock = WallClock()

    agg = StateAggregator(bus=FakeBus(), max_sources=max(sources, 1))  # type: ignore[arg-type]
    for i in range(sources):
        agg.ingest(f"junk/k{i}", Message(schema="range", stamp_ns=time.monotonic_ns(), seq=1,
                                         data={"range_mm": 300, "status": "ok"}), 0)
    root = seek_pink_ball()
    costs = []
    for _ in range(500):
        t0 = time.perf_counter_ns()
        root.evaluate(agg.snapshot())
        agg.newest()
        costs.append(time.perf_counter_ns() - t0)
    costs.sort()
    return {"median_us": statistics.median(costs) / 1e3, "max_us": costs[-1] / 1e3}


async def main_async(args: argparse.Namespace) -> dict[str, Any]:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    robot = f"flood{free_port()}"
    bus = await Bus.open(ConnectionOptions(robot=robot, listen=[endpoint]))
    agg = StateAggregator(bus=bus)
    ctl = Controller(bus=bus, aggregator=agg, root=seek_pink_ball(), rate_hz=RATE_HZ,
                     reflex_sources=("range/",))
    results: dict[str, Any] = {"rate_hz": RATE_HZ, "flood_msg_per_s": args.rate}
    try:
        await agg.start()
        await ctl.start()
        await asyncio.sleep(1.0)  # warm-up
        results["baseline"] = await window(ctl, args.baseline_s)
        proc = await flooder(endpoint, robot, "flood", args.rate, args.seconds)
        results["flood"] = await window(ctl, until=proc)
        results["flood"]["samples_taken"] = agg.entries["range/front"].version
        proc = await flooder(endpoint, robot, "junk", 2000, 1024 / 2000)
        await proc.wait()
        await asyncio.sleep(0.5)
        results["junk"] = await window(ctl, 3.0)
        results["junk"]["sources_held"] = len(agg.entries)
        results["refused"] = agg.refusals()
        results["dropped"] = agg.dropped()
        results["restarts"] = ctl.restarts + agg.restarts
    finally:
        await ctl.aclose()
        await agg.aclose()
        await bus.aclose()
    results["in_process_tick"] = {str(n): in_process_tick_cost(n) for n in (1, 256, 1024)}
    base, flood = results["baseline"], results["flood"]
    results["commands_ratio_to_rate"] = flood["commands_per_s"] / RATE_HZ
    results["periodic_ratio_to_baseline"] = flood["periodic_hz"] / base["periodic_hz"]
    return results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rate", type=float, default=10_000.0, help="flood msg/s")
    parser.add_argument("--seconds", type=float, default=10.0, help="flood duration")
    parser.add_argument("--baseline-s", type=float, default=5.0)
    parser.add_argument("--json", default=None, metavar="FILE")
    args = parser.parse_args()
    r = asyncio.run(main_async(args))
    base, flood, junk = r["baseline"], r["flood"], r["junk"]
    print(f"controller at {RATE_HZ:g} Hz, reflex range/; flood {args.rate:g} msg/s for "
          f"{flood['seconds']:.1f} s on range/front")
    for name, w in (("baseline", base), ("flood", flood), ("1024 junk keys", junk)):
        t = w["tick"]
        print(f"  {name:15s} commands {w['commands_per_s']:6.1f}/s  periodic "
              f"{w['periodic_hz']:5.1f} Hz  reflex limited {w['reflex_limited']:6d}  tick "
              f"median {t['median_us']:.0f} µs p99 {t['p99_us']:.0f} µs max {t['max_us']:.0f} µs")
    print(f"  commands under flood: {r['commands_ratio_to_rate']:.2f}× the configured rate "
          f"(goal ≤ 2); periodic tick rate {r['periodic_ratio_to_baseline']:.3f}× the "
          f"baseline (goal within 5 %)")
    print(f"  flood samples taken by the aggregator: {flood['samples_taken']}; sources held "
          f"after 1024 junk keys: {junk['sources_held']}; refused: {r['refused']}; "
          f"dropped: {r['dropped']}; restarts {r['restarts']}")
    print("  tick cost in process (evaluate + snapshot) with N sources: " + ", ".join(
        f"{n}: {c['median_us']:.0f} µs" for n, c in r["in_process_tick"].items()))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(r, f, indent=2)


if __name__ == "__main__":
    main()
