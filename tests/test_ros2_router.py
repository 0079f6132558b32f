"""The ROS 2 bridge in rmw_zenoh's own layout: a zenoh router, the robot and the bridge
(``python -m ubf_async.ros2``, its own process) its clients, the ROS 2 side (zenoh-ros2-sdk,
tests/ros2_side.py) a peer of the router; and Humble's keys (``TypeHashNotSupported``)."""

from __future__ import annotations

import re
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.conftest import free_port
from tests.ros2_side import RosSide
from tests.test_ros2 import MAX_ANGULAR, MAX_LINEAR, wait_until

ROOT = Path(__file__).resolve().parent.parent
ROBOT = "rrouted"
ROBOT_FILE = f"""
format: 1
name: {ROBOT}
devices:
  - {{kind: motors, name: main, backend: sim, params: {{timeout_s: 0.11}}}}
  - {{kind: encoders, name: wheels, backend: sim, params: {{period_s: 0.02}}}}
controller: {{mode: periodic, rate_hz: 50}}
tree:
  name: root
  arbiter: HighestPriority
  children:
    - behavior: stop
    - remote: teleop
      priority: 10
"""

pytestmark = pytest.mark.slow


class Child:
    """A child process whose output is kept (and drained, so it never blocks)."""

    def __init__(self, *argv: str, ready: str) -> None:
        self.proc = subprocess.Popen([sys.executable, *argv], cwd=ROOT, stdout=subprocess.PIPE,
                                     stderr=subprocess.STDOUT, text=True)
        self.lines: list[str] = []
        self._ready = threading.Event()
        self._reader = threading.Thread(target=self._read, args=(ready,), daemon=True)
        self._reader.start()
        if not self._ready.wait(30):
            self.close()
            raise AssertionError(f"{argv[:2]} never said {ready!r}:\n" + "".join(self.lines))

    def _read(self, ready: str) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.append(line)
            if ready in line:
                self._ready.set()
        self._ready.set()

    def close(self) -> None:
        self.proc.terminate()
        try:
            self.proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        self._reader.join(timeout=10)
        assert self.proc.stdout is not None
        self.proc.stdout.close()


@pytest.fixture(scope="module")
def routed(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[int, Child]]:
    """Router, robot (client) and bridge (client, Humble); yields the router's port and the
    bridge's process."""
    path = tmp_path_factory.mktemp("ros2r") / "robot.yaml"
    path.write_text(ROBOT_FILE)
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    children = [Child("-m", "ubf_async.router", "--listen", endpoint, "--quiet",
                      ready="join with")]
    try:
        children.append(Child("-m", "ubf_async.launch", str(path), "--mode", "client",
                              "--connect", endpoint, "--quiet", ready="controller:"))
        children.append(Child(
            "-m", "ubf_async.ros2", "--mode", "client", "--connect", endpoint, "--robot", ROBOT,
            "--distro", "humble", "--max-linear-m-s", str(MAX_LINEAR), "--max-angular-rad-s",
            str(MAX_ANGULAR), "--composite", "root", "--status-period-s", "0.2",
            ready="ROS 2 bridge of robot"))
        yield port, children[-1]
    finally:
        for child in reversed(children):
            child.close()


def test_twist_both_ways_through_a_router_on_humble(routed: tuple[int, Child]) -> None:
    port, bridge = routed
    ros = RosSide(port, distro="humble")
    try:
        assert ros.hashes["geometry_msgs/msg/Twist"] == "TypeHashNotSupported"
        cmd_vel = f"/{ROBOT}/cmd_vel"
        ros.send(op="sub", topic=cmd_vel, type="geometry_msgs/msg/Twist")
        ros.wait("subscribed")
        wait_until(lambda: len(ros.received(cmd_vel)) >= 5, timeout_s=20,
                   what="the robot's drive command on cmd_vel (Humble keys, via the router)")
        assert {(t["linear"]["x"], t["angular"]["z"]) for t in ros.received(cmd_vel)} == {
            (0.0, 0.0)}
        deadline = time.monotonic() + 20
        turning = (0.03, -1.0)  # speed 10, turn -50 (right)
        while True:  # liveliness reaches the bridge through the router: publish until heard
            ros.send(op="pub", topic=f"/{ROBOT}/cmd_vel_in", linear=turning[0],
                     angular=turning[1], rate_hz=20, count=20)
            ros.wait("pub_done")
            seen = {(round(t["linear"]["x"], 9), round(t["angular"]["z"], 9))
                    for t in ros.received(cmd_vel)}
            if turning in seen or time.monotonic() > deadline:
                break
        assert turning in seen, seen
        # The bridge's status line counts what it took in (and refused nothing).
        wait_until(lambda: any(re.search(r"cmd_vel_in: [1-9]\d* taken, refused: none", line)
                               for line in bridge.lines), timeout_s=5,
                   what="the bridge's status line counting the Twists")
    finally:
        ros.close()
