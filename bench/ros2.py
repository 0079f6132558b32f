"""What the ROS 2 bridge adds to latency, beside the native path in the same run.

    python -m bench.ros2 [--samples 300] [--json FILE]

A robot (``python -m ubf_async.launch``: the simulated motors, in real time, 200 Hz ticks,
the bridge in-process from its robot file's ``ros2:`` section) and, in this process, two
zenoh sessions connected to it: a *sender* and an *observer*. One sample at a time (the next
only once the last has arrived or timed out), all times ``time.monotonic_ns()`` of this host:

* **range**: the sender puts a ``range`` sample on ``sensor/range/front``; the observer
  notes when it gets it natively (msgpack on the robot's key) and when the bridge's
  ``sensor_msgs/msg/Range`` arrives on the ROS key. Extra = bridged − native, per sample.
* **drive**: the sender votes (native: msgpack on ``vote/root/native``, stamped with the
  simulation time it follows) or sends a ``geometry_msgs/msg/Twist`` on ``cmd_vel_in`` (ROS),
  each with a turn value of its own; the time until the motors say they applied it
  (``sensor/motors/main``). Both wait for the next controller tick (5 ms apart): compare the
  two, not either with 0.

Each figure is an observed sample (nearest-rank percentiles, ``bench.latency_stats``).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import zenoh

from bench.latency_stats import fmt_us, header, row, summarize
from bench.processes import terminate
from ubf_async.services.ros2 import keys as rk
from ubf_async.services.ros2 import messages as rm
from ubf_async.wire.protocol import decode, encode

ROBOT = "bench"
LINEAR, ANGULAR = 0.34, 1.62
ROBOT_FILE = f"""
format: 1
name: {ROBOT}
devices:
  - {{kind: motors, name: main, backend: sim}}
controller: {{mode: periodic, rate_hz: 200}}
tree:
  name: root
  arbiter: HighestPriority
  children:
    - behavior: stop
    - remote: teleop
      priority: 10
    - remote: native
      priority: 11
ros2: {{max_linear_m_s: {LINEAR}, max_angular_rad_s: {ANGULAR}, ttl_s: 2.0}}
"""


def session(endpoint: str) -> zenoh.Session:
    conf = zenoh.Config()
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    return zenoh.open(conf)


class Arrivals:
    """When each tagged sample arrived (observer's threads)."""

    def __init__(self) -> None:
        self.at: dict[tuple[str, float], int] = {}
        self.cond = threading.Condition()

    def note(self, path: str, tag: float) -> None:
        now = time.monotonic_ns()
        with self.cond:
            self.at.setdefault((path, tag), now)
            self.cond.notify_all()

    def wait(self, keys: list[tuple[str, float]], timeout_s: float = 1.0) -> bool:
        with self.cond:
            return self.cond.wait_for(lambda: all(k in self.at for k in keys), timeout_s)


def run(samples: int, port: int) -> dict[str, Any]:
    endpoint = f"tcp/127.0.0.1:{port}"
    codec = rm.Codec("jazzy")
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "bench.yaml"
        path.write_text(ROBOT_FILE)
        robot = subprocess.Popen([sys.executable, "-m", "ubf_async.launch", str(path),
                                  "--listen", endpoint, "--quiet"], stdout=subprocess.PIPE,
                                 text=True)
        assert robot.stdout is not None
        for line in robot.stdout:
            if "controller:" in line:
                break
        threading.Thread(target=robot.stdout.read, daemon=True).start()
        sender, observer = session(endpoint), session(endpoint)
        arrivals = Arrivals()
        try:
            range_key = rk.data_key(0, f"/{ROBOT}/range/front", rm.RANGE, codec.hash(rm.RANGE))
            twist_key = rk.data_key(0, f"/{ROBOT}/cmd_vel_in", rm.TWIST, codec.hash(rm.TWIST))

            def on_native_range(sample: zenoh.Sample) -> None:
                arrivals.note("range native", decode(sample.payload.to_bytes()).data.range_mm)

            def on_ros_range(sample: zenoh.Sample) -> None:
                msg: Any = codec.store.deserialize_cdr(sample.payload.to_bytes(), rm.RANGE)
                arrivals.note("range ros", round(msg.range * 1000.0))

            def on_applied(sample: zenoh.Sample) -> None:
                arrivals.note("drive", round(decode(sample.payload.to_bytes()).data.turn, 3))

            sim_ns = [0]

            def on_clock(sample: zenoh.Sample) -> None:
                sim_ns[0] = decode(sample.payload.to_bytes()).stamp_ns

            observer.declare_subscriber(f"ubf/{ROBOT}/sensor/range/front", on_native_range)
            observer.declare_subscriber(range_key, on_ros_range)
            observer.declare_subscriber(f"ubf/{ROBOT}/sensor/motors/main", on_applied)
            sender.declare_subscriber(f"ubf/{ROBOT}/clock", on_clock)
            # The bridge declares the Range publisher at the range finder's first sample.
            range_out = sender.declare_publisher(f"ubf/{ROBOT}/sensor/range/front")
            seq = [0]

            def send_range(mm: int) -> int:
                seq[0] += 1
                payload = encode("range", {"range_mm": mm, "status": "ok", "min_mm": 40,
                                           "max_mm": 2000}, stamp_ns=time.monotonic_ns(),
                                 seq=seq[0], pub=7)
                sent = time.monotonic_ns()
                range_out.put(payload)
                return sent

            send_range(39 + 1)
            time.sleep(1.0)  # the ROS publisher's token and the observer's routes settle
            extra: list[float] = []
            native: list[float] = []
            bridged: list[float] = []
            for i in range(samples):
                mm = 41 + i % 1900
                sent = send_range(mm)
                if arrivals.wait([("range native", mm), ("range ros", mm)]):
                    n = arrivals.at[("range native", mm)] - sent
                    r = arrivals.at[("range ros", mm)] - sent
                    native.append(n)
                    bridged.append(r)
                    extra.append(r - n)
                arrivals.at.clear()
                time.sleep(0.005)
            result: dict[str, Any] = {"range_native": summarize(native),
                                      "range_ros": summarize(bridged),
                                      "range_extra": summarize(extra)}

            # Drive: native votes first (then their token goes), then Twists.
            token = sender.liveliness().declare_token(f"ubf/{ROBOT}/alive/native")
            vote_out = sender.declare_publisher(f"ubf/{ROBOT}/vote/root/native")
            twist_out = sender.declare_publisher(twist_key)
            gid = rk.new_gid()
            time.sleep(0.5)
            for path_name in ("native", "ros"):
                values: list[float] = []
                for i in range(samples):
                    turn = round(-90 + (i % 180) + (0.25 if path_name == "ros" else 0.5), 3)
                    sent = time.monotonic_ns()
                    if path_name == "native":
                        vote_out.put(encode("vote", {"vote": 1.0, "speed": 0.0, "turn": turn,
                                                     "ttl_s": 2.0}, stamp_ns=sim_ns[0],
                                            seq=i + 1, pub=9))
                    else:
                        twist_out.put(codec.twist(0.0, turn / 100 * ANGULAR),
                                      attachment=rk.attachment(i + 1, time.time_ns(), gid))
                    if arrivals.wait([("drive", turn)]):
                        values.append(arrivals.at[("drive", turn)] - sent)
                    arrivals.at.clear()
                    time.sleep(0.005)
                result[f"drive_{path_name}"] = summarize(values)
                if path_name == "native":
                    vote_out.put(encode("vote", {"vote": 0.0}, stamp_ns=sim_ns[0],
                                        seq=samples + 1, pub=9))
                    token.undeclare()
                    time.sleep(0.3)
            return result
        finally:
            sender.close()
            observer.close()
            terminate(robot)


def main() -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.ros2", description=__doc__.split(
        "\n\n")[0])
    parser.add_argument("--samples", type=int, default=300)
    parser.add_argument("--port", type=int, default=17611)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    result = run(args.samples, args.port)
    print(header())
    print(row("range sample → native subscriber (msgpack)", result["range_native"]))
    print(row("range sample → ROS Range (through the bridge)", result["range_ros"]))
    print(row("  extra added by the bridge (per sample)", result["range_extra"]))
    print(row("native vote → motors applied", result["drive_native"]))
    print(row("ROS Twist on cmd_vel_in → motors applied", result["drive_ros"]))
    n, r = result["drive_native"], result["drive_ros"]
    if n.get("n") and r.get("n"):
        print(f"  Twist path minus native: median {fmt_us(r['median_us'] - n['median_us'])}, "
              f"p99 {fmt_us(r['p99_us'] - n['p99_us'])}")
    if args.json is not None:
        args.json.write_text(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
