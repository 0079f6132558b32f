"""A lab's traffic against the default robot: garbage on a sensor's key, visiting sessions, and
bursts of malformed messages — what it does to the drive commands and to the robot's memory.

Run ``python -m bench.visitors [--only flood,visits,malformed]``. It starts the real main job
(``python -m ubf_async.launch``: the shipped Mini-WHEGS robot and the default scenario, on a
loopback endpoint) and, as the baseline measured in the same run, a **plain zenoh subscriber**
(``ubf/**``, zenoh's default configuration, no code of ours). The visitors are separate
processes publishing plain zenoh (no ubf_async), as an outsider would. Three situations:

1. **flood** — ``--flood-rate`` messages a second that are not msgpack, for ``--flood-s``, on
   ``ubf/<robot>/sensor/camera/front`` while the real camera goes on publishing: the share of
   the controller's drive commands without a winner (an empty ``winners``: the tree had
   nothing to act on), beside the same figure over ``--baseline-s`` before the flood.
2. **visits** — ``--visits`` sessions one after the other, each connecting (to the robot and
   to the plain subscriber), sending ``--visit-messages`` messages of ``--visit-bytes`` random
   bytes at ``--visit-rate`` a second on a sensor key, and closing: the RSS of both after
   each visit, against their RSS before the first.
3. **malformed** — ``--malformed`` malformed messages at ``--malformed-rate`` a second in one
   session, spread over every key the robot subscribes to (bytes that are not msgpack, maps
   of the wrong schema, out-of-range commands, ``--big`` payloads of 1 MiB among them), sent
   in ``--bursts`` bursts: the RSS of both after each burst.

Printed: the figures, and whether the robot still ticks (drive commands in the last second of
each phase). ``--json FILE`` writes them too.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import msgpack
import zenoh

from bench.processes import terminate
from bench.soak import rss_bytes
from tests.conftest import free_port

ROOT = Path(__file__).resolve().parent.parent
MIB = 1024 * 1024
SETTLE_S = 2.0
"""Wall seconds after a visitor leaves before the RSS is read (zenoh closes its transport)."""

PLAIN = r'''
import json, sys, zenoh
conf = zenoh.Config()
conf.insert_json5("listen/endpoints", json.dumps([sys.argv[1]]))
conf.insert_json5("scouting/multicast/enabled", "false")
session = zenoh.open(conf)
received = 0
def on_sample(sample):
    global received
    received += 1
sub = session.declare_subscriber("ubf/**", on_sample)
print("ready", flush=True)
sys.stdin.read()  # until the bench closes it
'''

VISITOR = r'''
import json, os, sys, time, zenoh
endpoints, mode, robot, *args = sys.argv[1:]
conf = zenoh.Config()
conf.insert_json5("connect/endpoints", endpoints)
conf.insert_json5("scouting/multicast/enabled", "false")
session = zenoh.open(conf)
head = f"ubf/{robot}/"

def paced(items, rate):
    start = time.monotonic()
    for i, item in enumerate(items):
        yield item
        wait = start + (i + 1) / rate - time.monotonic()
        if wait > 0.0005:
            time.sleep(wait)

def wait_matched(pub):
    deadline = time.monotonic() + 10
    while not pub.matching_status.matching:
        if time.monotonic() > deadline:
            sys.exit(f"nothing subscribes to {pub.key_expr}")
        time.sleep(0.01)

if mode == "flood":  # garbage on one key: rate, seconds
    rate, seconds = float(args[0]), float(args[1])
    pub = session.declare_publisher(head + "sensor/camera/front")
    wait_matched(pub)
    print("go", flush=True)
    junk = b"\xc1 not msgpack"
    sent = 0
    start = time.monotonic()
    while (now := time.monotonic()) < start + seconds:
        due = int((now - start) * rate)
        while sent < due:
            pub.put(junk)
            sent += 1
        time.sleep(0.0005)
    print(f"sent {sent}", flush=True)
elif mode == "visit":  # messages, bytes, rate
    count, size, rate = int(args[0]), int(args[1]), float(args[2])
    pub = session.declare_publisher(head + "sensor/range/visitor")
    wait_matched(pub)
    payload = os.urandom(size)
    for _ in paced(range(count), rate):
        pub.put(payload)
    print("sent", flush=True)
elif mode == "malformed":  # total, rate, big, bursts; waits for a line between bursts
    total, rate, big, bursts = int(args[0]), float(args[1]), int(args[2]), int(args[3])
    keys = ["sensor/camera/front", "sensor/range/front", "sensor/range/left",
            "sensor/encoders/left", "sensor/motors/wheels", "cmd/drive", "cmd/seek_color",
            "cmd/leds", "cmd/radio", "vote/root/intruder", "heartbeat/intruder", "clock",
            "time", "sim/pulses", "lockstep/intruder"]
    pubs = [session.declare_publisher(head + k) for k in keys]
    wait_matched(pubs[0])
    bad = [b"\xc1 not msgpack", os.urandom(600),
           __import__("msgpack").packb({"schema": "drive", "v": 1, "seq": 1, "stamp_ns": 1,
                                        "data": {"speed": 1e9, "turn": -1e9}}),
           __import__("msgpack").packb({"schema": "camera.seekcolor", "v": 1, "seq": 2,
                                        "stamp_ns": 1, "data": {"bins": "x" * 4000}}),
           __import__("msgpack").packb({"v": 99, "data": [[[[[[[[[[[]]]]]]]]]]]})]
    huge = os.urandom(1 << 20)
    big_every = max(1, total // big) if big else 0
    per_burst = total // bursts
    n = 0
    for burst in range(bursts):
        for i in paced(range(per_burst), rate):
            n += 1
            pub = pubs[n % len(pubs)]
            pub.put(huge if big_every and n % big_every == 0 else bad[n % len(bad)])
        print(f"burst {burst + 1} {n}", flush=True)
        sys.stdin.readline()
print("done", flush=True)
session.close()
'''


@dataclass
class Drives:
    """The robot's drive commands as a plain zenoh subscriber sees them."""

    lock: threading.Lock = field(default_factory=threading.Lock)
    times: list[float] = field(default_factory=list)
    no_winner: list[float] = field(default_factory=list)

    def on_sample(self, sample: zenoh.Sample) -> None:
        now = time.monotonic()
        try:
            message = msgpack.unpackb(sample.payload.to_bytes())
            empty = not message["data"].get("winners") and not message["data"].get("hold")
        except (ValueError, KeyError, TypeError, AttributeError):
            return
        with self.lock:
            self.times.append(now)
            if empty:
                self.no_winner.append(now)

    def window(self, start: float, end: float) -> tuple[int, int]:
        with self.lock:
            return (sum(start <= t < end for t in self.times),
                    sum(start <= t < end for t in self.no_winner))


class Lab:
    """The robot, the plain subscriber and an observer session, for the whole run."""

    def __init__(self, args: argparse.Namespace) -> None:
        self.args = args
        self.robot_endpoint = f"tcp/127.0.0.1:{free_port()}"
        self.plain_endpoint = f"tcp/127.0.0.1:{free_port()}"
        self.robot = subprocess.Popen(
            [sys.executable, "-m", "ubf_async.launch", "--listen", self.robot_endpoint,
             "--robot", args.robot, "--log-level", "ERROR"],
            cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
            stdin=subprocess.DEVNULL)
        self.plain = subprocess.Popen([sys.executable, "-c", PLAIN, self.plain_endpoint],
                                      stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        assert self.plain.stdout is not None
        self.plain.stdout.readline()
        conf = zenoh.Config()
        conf.insert_json5("connect/endpoints", json.dumps([self.robot_endpoint]))
        conf.insert_json5("scouting/multicast/enabled", "false")
        self.session = zenoh.open(conf)
        self.drives = Drives()
        self._sub = self.session.declare_subscriber(f"ubf/{args.robot}/cmd/drive",
                                                    self.drives.on_sample)

    def wait_ticking(self, timeout_s: float = 60.0) -> None:
        deadline = time.monotonic() + timeout_s
        while not self.drives.times:
            if time.monotonic() > deadline or self.robot.poll() is not None:
                raise SystemExit("the robot never published a drive command")
            time.sleep(0.1)

    def rss_mib(self) -> tuple[float, float]:
        return ((rss_bytes(self.robot.pid) or 0) / MIB, (rss_bytes(self.plain.pid) or 0) / MIB)

    def ticking(self) -> int:
        now = time.monotonic()
        return self.drives.window(now - 1.0, now)[0]

    def visitor(self, mode: str, *args: object, both: bool = True) -> subprocess.Popen[str]:
        endpoints = [self.robot_endpoint] + ([self.plain_endpoint] if both else [])
        return subprocess.Popen(
            [sys.executable, "-c", VISITOR, json.dumps(endpoints), mode, self.args.robot,
             *map(str, args)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)

    def close(self) -> None:
        self._sub.undeclare()
        self.session.close()
        terminate(self.robot)
        if self.plain.stdin is not None:
            self.plain.stdin.close()
        terminate(self.plain)


def flood(lab: Lab, args: argparse.Namespace) -> dict[str, Any]:
    start = time.monotonic()
    time.sleep(args.baseline_s)
    before = lab.drives.window(start, time.monotonic())
    proc = lab.visitor("flood", args.flood_rate, args.flood_s, both=False)
    assert proc.stdout is not None
    proc.stdout.readline()  # "go"
    flood_start = time.monotonic()
    sent = proc.stdout.readline().split()
    flood_end = time.monotonic()
    proc.wait()
    during = lab.drives.window(flood_start, flood_end)
    seconds = flood_end - flood_start
    count = int(sent[1]) if len(sent) > 1 else 0
    baseline = {"drive_per_s": before[0] / args.baseline_s,
                "no_winner_pct": 100 * before[1] / max(1, before[0])}
    flooded = {"sent": count, "rate_per_s": count / seconds,
               "drive_per_s": during[0] / seconds,
               "no_winner_pct": 100 * during[1] / max(1, during[0])}
    ticking = lab.ticking()
    print(f"flood: {flooded['rate_per_s']:.0f} garbage msg/s on the camera's key for "
          f"{seconds:.1f} s")
    print(f"  drive commands without a winner: baseline {baseline['no_winner_pct']:.1f} % "
          f"({baseline['drive_per_s']:.0f}/s), under the flood {flooded['no_winner_pct']:.1f} % "
          f"({flooded['drive_per_s']:.0f}/s); ticking after: {ticking} commands in the last "
          f"second")
    return {"baseline": baseline, "flood": flooded, "ticking_after": ticking}


def visits(lab: Lab, args: argparse.Namespace) -> dict[str, Any]:
    robot0, plain0 = lab.rss_mib()
    rows = []
    print(f"visits: {args.visits} sessions, each {args.visit_messages} × {args.visit_bytes} B "
          f"at {args.visit_rate:g}/s, then closing; RSS growth (MiB) since before the first:")
    print(f"  {'visit':>5}  {'robot':>8}  {'plain zenoh':>11}")
    for i in range(args.visits):
        proc = lab.visitor("visit", args.visit_messages, args.visit_bytes, args.visit_rate)
        proc.wait()
        time.sleep(SETTLE_S)
        robot, plain = lab.rss_mib()
        rows.append({"visit": i + 1, "robot_mib": robot - robot0, "plain_mib": plain - plain0})
        print(f"  {i + 1:>5}  {robot - robot0:+8.1f}  {plain - plain0:+11.1f}", flush=True)
    return {"start_mib": {"robot": robot0, "plain": plain0}, "visits": rows,
            "ticking_after": lab.ticking()}


def malformed(lab: Lab, args: argparse.Namespace) -> dict[str, Any]:
    robot0, plain0 = lab.rss_mib()
    proc = lab.visitor("malformed", args.malformed, args.malformed_rate, args.big, args.bursts)
    assert proc.stdout is not None and proc.stdin is not None
    print(f"malformed: {args.malformed} messages at {args.malformed_rate:g}/s over 15 keys "
          f"({args.big} of 1 MiB), in {args.bursts} bursts; RSS (MiB):")
    print(f"  {'burst':>5}  {'robot':>16}  {'plain zenoh':>16}")
    print(f"  {'start':>5}  {robot0:8.1f}          {plain0:8.1f}")
    rows = []
    for _ in range(args.bursts):
        line = proc.stdout.readline().split()
        time.sleep(SETTLE_S)
        robot, plain = lab.rss_mib()
        rows.append({"sent": int(line[2]), "robot_mib": robot, "plain_mib": plain})
        print(f"  {line[1]:>5}  {robot:8.1f} ({robot - robot0:+6.1f})  "
              f"{plain:8.1f} ({plain - plain0:+6.1f})", flush=True)
        proc.stdin.write("\n")
        proc.stdin.flush()
    proc.wait()
    after_first = [r["robot_mib"] - rows[0]["robot_mib"] for r in rows[1:]]
    return {"start_mib": {"robot": robot0, "plain": plain0}, "bursts": rows,
            "robot_growth_after_first_burst_mib": max(after_first, default=0.0),
            "ticking_after": lab.ticking()}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.visitors", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--only", default="flood,visits,malformed",
                        help="which situations, comma-separated (default: all three)")
    parser.add_argument("--robot", default="mini")
    parser.add_argument("--baseline-s", type=float, default=5.0)
    parser.add_argument("--flood-rate", type=float, default=10_000.0)
    parser.add_argument("--flood-s", type=float, default=10.0)
    parser.add_argument("--visits", type=int, default=4)
    parser.add_argument("--visit-messages", type=int, default=3000)
    parser.add_argument("--visit-bytes", type=int, default=5000)
    parser.add_argument("--visit-rate", type=float, default=1000.0)
    parser.add_argument("--malformed", type=int, default=100_000)
    parser.add_argument("--malformed-rate", type=float, default=1500.0)
    parser.add_argument("--big", type=int, default=60, help="payloads of 1 MiB among them")
    parser.add_argument("--bursts", type=int, default=4)
    parser.add_argument("--json", type=Path, help="also write the figures to this file")
    args = parser.parse_args(argv)
    only = set(args.only.split(","))
    unknown = only - {"flood", "visits", "malformed"}
    if unknown:
        parser.error(f"--only: unknown {', '.join(sorted(unknown))}")
    lab = Lab(args)
    results: dict[str, Any] = {}
    try:
        lab.wait_ticking()
        if "flood" in only:
            results["flood"] = flood(lab, args)
        if "visits" in only:
            results["visits"] = visits(lab, args)
        if "malformed" in only:
            results["malformed"] = malformed(lab, args)
        results["robot_alive"] = lab.robot.poll() is None
        print(f"robot alive at the end: {results['robot_alive']}")
    finally:
        lab.close()
    if args.json:
        args.json.write_text(json.dumps(results, indent=2) + "\n", encoding="utf-8")
    return 0 if results.get("robot_alive") else 1


if __name__ == "__main__":
    sys.exit(main())
