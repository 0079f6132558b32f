"""The ROS 2 bridge against an independent implementation of rmw_zenoh (zenoh-ros2-sdk, in a
process of its own: tests/ros2_side.py), on one simulated robot launched for the module with
the bridge in-process (its robot file's ``ros2:`` section)."""

from __future__ import annotations

import itertools
import json
import math
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
import zenoh

from tests.conftest import free_port
from tests.ros2_side import RosSide
from ubf_async.wire.protocol import Message, decode

ROOT = Path(__file__).resolve().parent.parent
ROBOT = "rros"
TTL_S = 0.5
MAX_LINEAR, MAX_ANGULAR = 0.30, 2.0
ROBOT_FILE = f"""
format: 1
name: {ROBOT}
devices:
  - {{kind: motors, name: main, backend: sim, params: {{timeout_s: 0.11}}}}
  - kind: encoders
    name: wheels
    backend: sim
    params: {{period_s: 0.02, direction: commanded, effective_track_m: 0.42}}
  - kind: range
    name: front
    backend: sim
    params: {{model: ir-10-80, x_m: 0.05, y_m: 0.0, yaw_deg: 0.0, period_s: 0.04}}
controller: {{mode: periodic, rate_hz: 50}}
tree:
  name: root
  arbiter: HighestPriority
  children:
    - behavior: stop
      priority: 0
    - remote: teleop
      priority: 10
ros2: {{distro: jazzy, ttl_s: {TTL_S}, max_linear_m_s: {MAX_LINEAR},
        max_angular_rad_s: {MAX_ANGULAR}}}
"""

pytestmark = pytest.mark.slow


def wait_until(predicate: Callable[[], bool], *, timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s}s waiting for {what}")
        time.sleep(0.02)


class Observer:
    """The robot's own samples, decoded, from a plain zenoh session (the ground truth)."""

    def __init__(self, endpoint: str) -> None:
        conf = zenoh.Config()
        conf.insert_json5("mode", '"peer"')
        conf.insert_json5("connect/endpoints", f'["{endpoint}"]')
        conf.insert_json5("scouting/multicast/enabled", "false")
        self.session = zenoh.open(conf)
        self.samples: dict[str, list[Message[Any]]] = {}
        self._lock = threading.Lock()
        self._subs: list[Any] = []

    def watch(self, key: str) -> None:
        def on_sample(sample: zenoh.Sample) -> None:
            message = decode(sample.payload.to_bytes())
            with self._lock:
                self.samples.setdefault(key, []).append(message)
        self._subs.append(self.session.declare_subscriber(f"ubf/{ROBOT}/{key}", on_sample))

    def of(self, key: str) -> list[Message[Any]]:
        with self._lock:
            return list(self.samples.get(key, []))

    def close(self) -> None:
        self.session.close()


@pytest.fixture(scope="module")
def robot(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[str, int]]:
    """The robot, listening on a loopback port, with the bridge in-process."""
    path = tmp_path_factory.mktemp("ros2") / "robot.yaml"
    path.write_text(ROBOT_FILE)
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    proc = subprocess.Popen([sys.executable, "-m", "ubf_async.launch", str(path), "--listen",
                             endpoint, "--quiet"], cwd=ROOT, stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    printed = []
    for line in proc.stdout:
        printed.append(line)
        if "controller:" in line:
            break
    assert any("ROS 2 bridge: /rros/ubf_bridge, domain 0, jazzy" in line for line in printed), \
        printed
    drain = threading.Thread(target=proc.stdout.read, daemon=True)  # keep the pipe drained
    drain.start()
    try:
        yield endpoint, port
    finally:
        proc.terminate()
        proc.wait(timeout=30)
        drain.join(timeout=10)
        proc.stdout.close()


@pytest.fixture(scope="module")
def ros(robot: tuple[str, int]) -> Iterator[RosSide]:
    side = RosSide(robot[1])
    yield side
    side.close()


def test_the_ros_side_lists_the_node_and_its_topics_with_types(ros: RosSide) -> None:
    wanted = {f"/{ROBOT}/cmd_vel": "geometry_msgs/msg/Twist",
              f"/{ROBOT}/cmd_vel_in": "geometry_msgs/msg/Twist",
              f"/{ROBOT}/odom": "nav_msgs/msg/Odometry",
              f"/{ROBOT}/range/front": "sensor_msgs/msg/Range",
              f"/{ROBOT}/ubf/trace": "std_msgs/msg/String",
              "/clock": "rosgraph_msgs/msg/Clock"}
    deadline = time.monotonic() + 20
    while True:
        ros.send(op="list")
        answer = ros.wait("list")
        topics = {name: types for name, types in answer["topics"]}
        if all(topics.get(t) == [ty] for t, ty in wanted.items()) or time.monotonic() > deadline:
            break
    assert {t: topics.get(t) for t in wanted} == {t: [ty] for t, ty in wanted.items()}
    assert any(node.endswith(f"/NN/%/%{ROBOT}/ubf_bridge") for node in answer["nodes"]), \
        answer["nodes"]


def stamp_ns(header: dict[str, Any]) -> int:
    return header["stamp"]["sec"] * 1_000_000_000 + header["stamp"]["nanosec"]


def test_range_front_reaches_ros_with_the_robots_readings(robot: tuple[str, int],
                                                          ros: RosSide) -> None:
    observer = Observer(robot[0])
    try:
        observer.watch("sensor/range/front")
        topic = f"/{ROBOT}/range/front"
        ros.send(op="sub", topic=topic, type="sensor_msgs/msg/Range")
        ros.wait("subscribed")
        wait_until(lambda: len(ros.received(topic)) >= 10, timeout_s=20, what="10 Ranges")
        samples = {m.stamp_ns: m.data for m in observer.of("sensor/range/front")}
        matched = 0
        for msg in ros.received(topic):
            data = samples.get(stamp_ns(msg["header"]))
            if data is None:
                continue
            matched += 1
            expected = (data.range_mm / 1000 if data.status == "ok" else
                        -math.inf if data.status == "too_close" else math.inf)
            assert msg["range"] == pytest.approx(expected, rel=1e-6)
            assert (msg["min_range"], msg["max_range"]) == pytest.approx(
                (data.min_mm / 1000, data.max_mm / 1000), rel=1e-6)
            assert msg["radiation_type"] == 1 and msg["header"]["frame_id"] == "range_front"
            assert msg["variance"] == 0.0  # Jazzy's field: unknown
        assert matched >= 5
    finally:
        observer.close()


def quaternion_yaw(q: dict[str, float]) -> float:
    return math.atan2(2 * (q["w"] * q["z"] + q["x"] * q["y"]),
                      1 - 2 * (q["y"] ** 2 + q["z"] ** 2))


def test_cmd_vel_in_drives_the_robot_and_cmd_vel_and_odom_report_it(
        robot: tuple[str, int], ros: RosSide) -> None:
    observer = Observer(robot[0])
    try:
        for key in ("sensor/motors/main", "sensor/odometry/wheels", "cmd/drive",
                    "vote/root/teleop"):
            observer.watch(key)
        for topic, ros_type in ((f"/{ROBOT}/cmd_vel", "geometry_msgs/msg/Twist"),
                                (f"/{ROBOT}/odom", "nav_msgs/msg/Odometry")):
            ros.send(op="sub", topic=topic, type=ros_type)
            ros.wait("subscribed")
        linear, angular = 0.06, 1.0  # speed 20, turn 50 (left)
        ros.send(op="pub", topic=f"/{ROBOT}/cmd_vel_in", linear=linear, angular=angular,
                 rate_hz=20, count=40)
        ros.wait("pub_done")
        # The vote ends within its TTL of robot time after the last Twist.
        wait_until(lambda: any(not m.data.get("vote") for m in observer.of("vote/root/teleop")),
                   timeout_s=10, what="the bridge giving the slot back")
        votes = [m for m in observer.of("vote/root/teleop") if m.data.get("vote")]
        assert len(votes) >= 20
        assert {(v.data["speed"], v.data["turn"]) for v in votes} == {(20.0, 50.0)}
        last_vote_ns = max(v.stamp_ns for v in votes)
        wait_until(lambda: any(m.stamp_ns > last_vote_ns + 1e9
                               for m in observer.of("sensor/motors/main")),
                   timeout_s=10, what="a second of robot time after the last vote")

        applied = observer.of("sensor/motors/main")
        driven = [m for m in applied if (m.data.speed, m.data.turn) == (20.0, 50.0)]
        assert len(driven) >= 20, "the motors applied the Twist's speed and turn"
        stopped = [m for m in applied if m.stamp_ns > last_vote_ns
                   and (m.data.speed, m.data.turn) == (0.0, 0.0)]
        assert stopped and stopped[0].stamp_ns - last_vote_ns <= TTL_S * 1e9 + 0.05e9
        assert all((m.data.speed, m.data.turn) == (0.0, 0.0) for m in applied
                   if m.stamp_ns > last_vote_ns + TTL_S * 1e9 + 0.05e9)

        # cmd_vel: the drive command in m/s and rad/s, the same as the motors applied.
        twists = ros.received(f"/{ROBOT}/cmd_vel")
        pairs = {(round(t["linear"]["x"] / MAX_LINEAR * 100, 6),
                  round(t["angular"]["z"] / MAX_ANGULAR * 100, 6)) for t in twists}
        applied_pairs = {(m.data.speed, m.data.turn) for m in applied}
        assert (20.0, 50.0) in pairs and (0.0, 0.0) in pairs
        assert pairs <= applied_pairs

        # It turned left, and odom says what the robot's odometry says.
        odometry = {m.stamp_ns: m.data for m in observer.of("sensor/odometry/wheels")}
        headings = [d.heading_rad for d in odometry.values()]
        assert max(headings) - headings[0] > 0.2
        matched = moving = 0
        for msg in ros.received(f"/{ROBOT}/odom"):
            data = odometry.get(stamp_ns(msg["header"]))
            if data is None:
                continue
            matched += 1
            moving += data.heading_rad != 0.0
            pose = msg["pose"]["pose"]
            assert abs(pose["position"]["x"] - data.x_m) < 1e-3
            assert abs(pose["position"]["y"] - data.y_m) < 1e-3
            error = math.remainder(quaternion_yaw(pose["orientation"]) - data.heading_rad,
                                   math.tau)
            assert abs(error) < math.radians(0.1)
            assert (msg["header"]["frame_id"], msg["child_frame_id"]) == ("odom", "base_link")
            assert msg["pose"]["covariance"][14] >= 1e6  # z: not measured
        assert matched >= 20 and moving >= 10
    finally:
        observer.close()


def test_clock_and_the_trace_on_demand(ros: RosSide) -> None:
    trace = f"/{ROBOT}/ubf/trace"
    for topic, ros_type in (("/clock", "rosgraph_msgs/msg/Clock"),
                            (trace, "std_msgs/msg/String")):
        ros.send(op="sub", topic=topic, type=ros_type)
        ros.wait("subscribed")
    wait_until(lambda: len(ros.received("/clock")) >= 10 and len(ros.received(trace)) >= 10,
               timeout_s=20, what="/clock and the trace (asked for by the subscription)")
    clocks = [stamp_ns({"stamp": m["clock"]}) for m in ros.received("/clock")]
    gaps = [b - a for a, b in itertools.pairwise(clocks)]
    assert all(gap >= 10_000_000 for gap in gaps)  # simulated time, at most every 10 ms
    ticks = [json.loads(m["data"]) for m in ros.received(trace)]
    assert all(t["clock"] == "sim" for t in ticks)
    assert [t["tick"] for t in ticks] == sorted(t["tick"] for t in ticks)
    assert {"root", "stop"} <= {n["name"] for n in ticks[-1]["nodes"]}
