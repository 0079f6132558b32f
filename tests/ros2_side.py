"""The ROS 2 side of tests/test_ros2*.py, in a process of its own: zenoh-ros2-sdk, an
implementation of rmw_zenoh's wire format independent of ubf_async.services.ros2.

It is given the message definitions below (as in the ROS 2 interface packages) and computes
the type hashes itself (``zenoh_ros2_sdk.utils.get_type_hash``), so it needs no network.
Commands are JSON lines on stdin, answers JSON lines on stdout:

* ``{"op": "list"}`` → ``{"op": "list", "topics": [[name, [types]]...], "nodes": [...]}``
* ``{"op": "sub", "topic": T, "type": TYPE}`` → ``{"op": "msg", "topic": T, "msg": {...}}``
  per message
* ``{"op": "pub", "topic": T, "linear": X, "angular": Z, "rate_hz": R, "count": N}`` → Twists,
  then the publisher is closed (its tokens undeclared): ``{"op": "pub_done", ...}``
* ``{"op": "quit"}``
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time
from typing import Any

import numpy as np
from zenoh_ros2_sdk import ROS2Publisher, ROS2Subscriber, discovery
from zenoh_ros2_sdk.session import ZenohSession
from zenoh_ros2_sdk.utils import get_type_hash

TIME = "int32 sec\nuint32 nanosec\n"
HEADER = "builtin_interfaces/Time stamp\nstring frame_id\n"
VECTOR3 = "float64 x\nfloat64 y\nfloat64 z\n"
POINT = "float64 x\nfloat64 y\nfloat64 z\n"
QUATERNION = "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n"
POSE = "Point position\nQuaternion orientation\n"
TWIST = "Vector3  linear\nVector3  angular\n"
RANGE_HUMBLE = ("uint8 ULTRASOUND=0\nuint8 INFRARED=1\nstd_msgs/Header header\n"
                "uint8 radiation_type\nfloat32 field_of_view\nfloat32 min_range\n"
                "float32 max_range\nfloat32 range\n")
DEFINITIONS: dict[str, str] = {
    "builtin_interfaces/msg/Time": TIME,
    "std_msgs/msg/Header": HEADER,
    "std_msgs/msg/String": "string data\n",
    "geometry_msgs/msg/Vector3": VECTOR3,
    "geometry_msgs/msg/Point": POINT,
    "geometry_msgs/msg/Quaternion": QUATERNION,
    "geometry_msgs/msg/Pose": POSE,
    "geometry_msgs/msg/PoseWithCovariance": "Pose pose\nfloat64[36] covariance\n",
    "geometry_msgs/msg/Twist": TWIST,
    "geometry_msgs/msg/TwistWithCovariance": "Twist twist\nfloat64[36] covariance\n",
    "nav_msgs/msg/Odometry": ("std_msgs/Header header\nstring child_frame_id\n"
                              "geometry_msgs/PoseWithCovariance pose\n"
                              "geometry_msgs/TwistWithCovariance twist\n"),
    "sensor_msgs/msg/Range": RANGE_HUMBLE + "float32 variance\n",
    "rosgraph_msgs/msg/Clock": "builtin_interfaces/Time clock\n",
}
DEPENDENCIES: dict[str, list[str]] = {
    "std_msgs/msg/Header": ["builtin_interfaces/msg/Time"],
    "geometry_msgs/msg/Pose": ["geometry_msgs/msg/Point", "geometry_msgs/msg/Quaternion"],
    "geometry_msgs/msg/PoseWithCovariance": ["geometry_msgs/msg/Pose"],
    "geometry_msgs/msg/Twist": ["geometry_msgs/msg/Vector3"],
    "geometry_msgs/msg/TwistWithCovariance": ["geometry_msgs/msg/Twist"],
    "nav_msgs/msg/Odometry": ["std_msgs/msg/Header", "geometry_msgs/msg/PoseWithCovariance",
                              "geometry_msgs/msg/TwistWithCovariance"],
    "sensor_msgs/msg/Range": ["std_msgs/msg/Header"],
    "rosgraph_msgs/msg/Clock": ["builtin_interfaces/msg/Time"],
}


def closure(ros_type: str) -> list[str]:
    """``ros_type``'s dependencies, deepest first."""
    out: list[str] = []
    for dep in DEPENDENCIES.get(ros_type, []):
        for t in (*closure(dep), dep):
            if t not in out:
                out.append(t)
    return out


def type_hash(ros_type: str, distro: str) -> str:
    if distro == "humble":
        return "TypeHashNotSupported"
    deps = {t: DEFINITIONS[t] for t in closure(ros_type)}
    return get_type_hash(ros_type, msg_definition=DEFINITIONS[ros_type], dependencies=deps)


def plain(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if hasattr(value, "__dataclass_fields__"):
        return {k: plain(getattr(value, k)) for k in value.__dataclass_fields__
                if not k.startswith("__")}
    return value


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--port", type=int, required=True)
    parser.add_argument("--distro", default="jazzy")
    parser.add_argument("--domain-id", type=int, default=0)
    args = parser.parse_args()
    if args.distro == "humble":
        DEFINITIONS["sensor_msgs/msg/Range"] = RANGE_HUMBLE
    session = ZenohSession.get_instance("127.0.0.1", args.port)
    for ros_type in DEFINITIONS:  # dependencies first: each registration needs its fields'
        for t in (*closure(ros_type), ros_type):
            session.register_message_type(DEFINITIONS[t], t)
    lock = threading.Lock()

    def say(obj: dict[str, Any]) -> None:
        with lock:
            sys.stdout.write(json.dumps(obj) + "\n")
            sys.stdout.flush()

    say({"op": "ready", "hashes": {t: type_hash(t, args.distro) for t in DEFINITIONS}})
    subscribers = []
    for line in sys.stdin:
        cmd = json.loads(line)
        op = cmd["op"]
        if op == "quit":
            break
        if op == "list":
            topics = discovery.get_topic_names_and_types(
                domain_id=args.domain_id, router_ip="127.0.0.1", router_port=args.port,
                timeout=1.0)
            nodes = sorted({str(r.ok.key_expr) for r in session.liveliness.get(
                f"@ros2_lv/{args.domain_id}/*/*/*/NN/**", timeout=1.0) if r.ok is not None})
            say({"op": "list", "topics": topics, "nodes": nodes})
        elif op == "sub":
            topic = cmd["topic"]
            subscribers.append(ROS2Subscriber(
                topic, cmd["type"], lambda m, topic=topic: say(
                    {"op": "msg", "topic": topic, "msg": plain(m)}),
                msg_definition=DEFINITIONS[cmd["type"]], router_ip="127.0.0.1",
                router_port=args.port, domain_id=args.domain_id,
                type_hash=type_hash(cmd["type"], args.distro)))
            say({"op": "subscribed", "topic": topic})
        elif op == "pub":
            def publish(cmd: dict[str, Any] = cmd) -> None:
                ros_type = "geometry_msgs/msg/Twist"
                pub = ROS2Publisher(cmd["topic"], ros_type, msg_definition=DEFINITIONS[ros_type],
                                    router_ip="127.0.0.1", router_port=args.port,
                                    domain_id=args.domain_id,
                                    type_hash=type_hash(ros_type, args.distro))
                v3 = session.store.types["geometry_msgs/msg/Vector3"]
                for _ in range(cmd["count"]):
                    pub.publish(linear=v3(x=float(cmd["linear"]), y=0.0, z=0.0),
                                angular=v3(x=0.0, y=0.0, z=float(cmd["angular"])))
                    time.sleep(1.0 / cmd["rate_hz"])
                pub.close()
                say({"op": "pub_done", "topic": cmd["topic"], "count": cmd["count"]})
            threading.Thread(target=publish, daemon=True).start()
    for sub in subscribers:
        sub.close()
    session.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())


class RosSide:
    """This file run as a child process (the ROS 2 side), driven from a test."""

    def __init__(self, port: int, *, distro: str = "jazzy", domain_id: int = 0,
                 env: dict[str, str] | None = None) -> None:
        import queue
        import subprocess
        from pathlib import Path

        self._queue: queue.Queue[dict[str, Any] | None] = queue.Queue()
        self.messages: dict[str, list[dict[str, Any]]] = {}
        self.proc = subprocess.Popen(
            [sys.executable, str(Path(__file__).resolve()), "--port", str(port), "--distro",
             distro, "--domain-id", str(domain_id)],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
            cwd=Path(__file__).resolve().parent.parent, env=env)
        self._lock = threading.Lock()
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()
        self.hashes: dict[str, str] = self.wait("ready")["hashes"]

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            answer = json.loads(line)
            if answer["op"] == "msg":
                with self._lock:
                    self.messages.setdefault(answer["topic"], []).append(answer["msg"])
            else:
                self._queue.put(answer)
        self._queue.put(None)

    def send(self, **cmd: Any) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write(json.dumps(cmd) + "\n")
        self.proc.stdin.flush()

    def wait(self, op: str, timeout_s: float = 30.0) -> dict[str, Any]:
        import queue

        deadline = time.monotonic() + timeout_s
        while True:
            try:
                answer = self._queue.get(timeout=max(0.0, deadline - time.monotonic()))
            except queue.Empty:
                raise AssertionError(f"the ROS side said no {op!r} within {timeout_s}s") from None
            if answer is None:
                raise AssertionError(f"the ROS side ended ({self.proc.poll()}) before {op!r}")
            if answer["op"] == op:
                return answer

    def received(self, topic: str) -> list[dict[str, Any]]:
        with self._lock:
            return list(self.messages.get(topic, []))

    def close(self) -> None:
        import contextlib
        import subprocess

        with contextlib.suppress(OSError, ValueError):
            self.send(op="quit")
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        self._reader.join(timeout=10)
        for pipe in (self.proc.stdin, self.proc.stdout):
            if pipe is not None:
                with contextlib.suppress(OSError):
                    pipe.close()
