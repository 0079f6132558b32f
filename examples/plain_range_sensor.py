"""A range sensor written from docs/protocol.md alone: plain zenoh + msgpack, no ubf_async.

    python examples/plain_range_sensor.py --connect tcp/127.0.0.1:7447 --robot mini

It waits for the robot to say which clock it is on (docs/protocol.md, "The robot clock"):
a sample on ``ubf/<robot>/clock`` (a simulator: it stamps every sample with the newest
simulated time heard there) or on ``ubf/<robot>/time`` (a robot on wall time: it stamps with
this host's ``CLOCK_MONOTONIC``), and says which; a robot that says neither within
``--clock-wait-s`` gets ``CLOCK_MONOTONIC`` too. Then it declares its liveliness token and
publishes a fixed IR range reading on ``ubf/<robot>/sensor/range/<name>`` at ``--rate-hz``
until interrupted. Whatever the robot refuses of it, it prints on stderr, as the robot's
notices on ``ubf/<robot>/refused/sensor/range/<name>`` say (docs/protocol.md, "Refusal
notices").
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import threading
import time

import msgpack
import zenoh


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--connect", "-e", action="append", default=[], metavar="ENDPOINT")
    parser.add_argument("--listen", "-l", action="append", default=[], metavar="ENDPOINT")
    parser.add_argument("--mode", "-m", default="peer", choices=("peer", "client"))
    parser.add_argument("--robot", default="mini")
    parser.add_argument("--name", default="plain", help="sensor name: source range/<name>")
    parser.add_argument("--range-mm", type=int, default=250)
    parser.add_argument("--rate-hz", type=float, default=20.0)
    parser.add_argument("--count", type=int, default=0, help="stop after N samples (0: never)")
    parser.add_argument("--clock-wait-s", type=float, default=30.0,
                        help="how long to wait for the robot to say which clock it is on "
                             "before stamping with CLOCK_MONOTONIC")
    args = parser.parse_args()

    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps(args.mode))
    conf.insert_json5("scouting/multicast/enabled", "false")
    if args.connect:
        conf.insert_json5("connect/endpoints", json.dumps(args.connect))
    if args.listen:
        conf.insert_json5("listen/endpoints", json.dumps(args.listen))

    stop = False

    def on_signal(*_: object) -> None:
        nonlocal stop
        stop = True

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)

    period_s = 1.0 / args.rate_hz
    with zenoh.open(conf) as session:
        prefix = f"ubf/{args.robot}"
        # The robot clock: the newest simulated time on ubf/<robot>/clock if a simulator
        # publishes one (a sample every 5 ms of simulated time), CLOCK_MONOTONIC if the robot
        # publishes its host's time on ubf/<robot>/time. Wait for whichever speaks: a robot
        # may still be starting.
        sim_ns = [0]
        simulated = threading.Event()
        told = threading.Event()

        def on_clock(sample: zenoh.Sample) -> None:
            try:
                stamp = msgpack.unpackb(sample.payload.to_bytes())["stamp_ns"]
            except (ValueError, TypeError, KeyError):
                return  # not a clock sample: ignore it
            if isinstance(stamp, int):
                sim_ns[0] = stamp
                simulated.set()
                told.set()

        clock_sub = session.declare_subscriber(f"{prefix}/clock", on_clock)
        time_sub = session.declare_subscriber(f"{prefix}/time", lambda sample: told.set())
        if not told.wait(args.clock_wait_s):
            print(f"nothing on {prefix}/clock or {prefix}/time within {args.clock_wait_s:g}s: "
                  f"stamping with CLOCK_MONOTONIC", flush=True)
        elif simulated.is_set():
            print(f"stamping with the simulated time on {prefix}/clock", flush=True)
        else:
            print(f"the robot is on wall time ({prefix}/time): stamping with CLOCK_MONOTONIC",
                  flush=True)
        time_sub.undeclare()
        if not simulated.is_set():
            clock_sub.undeclare()

        # What the robot refuses of ours, and why (its notices, at most one a second).
        def on_refused(sample: zenoh.Sample) -> None:
            try:
                data = msgpack.unpackb(sample.payload.to_bytes())["data"]
                print(f"the robot refuses our samples ({data['count']} so far, "
                      f"{data['reason']}): {data['detail']}", file=sys.stderr, flush=True)
            except (ValueError, TypeError, KeyError):
                return  # not a notice: ignore it

        refused_sub = session.declare_subscriber(
            f"{prefix}/refused/sensor/range/{args.name}", on_refused)

        def now_ns() -> int:
            return sim_ns[0] if simulated.is_set() else time.monotonic_ns()

        token = session.liveliness().declare_token(f"{prefix}/alive/{args.name}")
        pub = session.declare_publisher(f"{prefix}/sensor/range/{args.name}")
        print(f"publishing {prefix}/sensor/range/{args.name}", flush=True)
        seq = 0
        while not stop and (args.count == 0 or seq < args.count):
            seq += 1
            payload = msgpack.packb({
                "schema": "range",            # a schema the robot knows (docs/protocol.md)
                "v": 1,                       # protocol version
                "stamp_ns": now_ns(),         # the robot clock (above)
                "seq": seq,
                "period_s": period_s,         # lets the robot decide when we are stale
                "data": {"range_mm": args.range_mm, "status": "ok", "model": "ir-10-80"},
            })
            pub.put(payload)
            time.sleep(period_s)
        refused_sub.undeclare()
        token.undeclare()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
