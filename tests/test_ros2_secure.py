"""Secure mode and the ROS 2 bridge: the robot file's ``ros2:`` section adds three identities
(``ros2-bridge``, ``ros2-reader``, ``ros2-driver``) and their rules; a ROS 2 node
(zenoh-ros2-sdk, its own process) joins the robot over mutual TLS with the identity's
certificate and credentials — the ``ZENOH_CONFIG_OVERRIDE`` that ``python -m ubf_async.secure
zenoh-override`` prints, as rmw_zenoh reads it — reads with either and drives only as
``ros2-driver``."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.conftest import free_port
from tests.ros2_side import RosSide
from tests.test_ros2 import wait_until
from ubf_async.access.setup import init
from ubf_async.assembly.robotfile import load_robot
from ubf_async.net.secure import override

ROOT = Path(__file__).resolve().parent.parent
ROBOT = "rsec"
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
ros2: {{domain_id: 3}}
"""


def rules_of(acl: dict[str, Any], identity: str) -> dict[str, set[str]]:
    """What ``identity`` may do: message → key expressions (ingress, and egress as
    ``egress:<message>``)."""
    subject = f"user-{identity}"
    ids = {r for p in acl["policies"] if subject in p["subjects"] for r in p["rules"]}
    out: dict[str, set[str]] = {}
    for rule in acl["rules"]:
        if rule["id"] in ids:
            for message in rule["messages"]:
                name = message if rule["flows"] == ["ingress"] else f"egress:{message}"
                out.setdefault(name, set()).update(rule["key_exprs"])
    return out


def test_the_ros2_section_adds_identities_with_only_their_own_rights(tmp_path: Path) -> None:
    path = tmp_path / "robot.yaml"
    path.write_text(ROBOT_FILE)
    setup = init(tmp_path / "secure", robot=load_robot(path))
    assert {"ros2-bridge", "ros2-reader", "ros2-driver"} <= set(setup.identities)
    acl = json.loads((tmp_path / "secure" / "acl.json").read_text())["access_control"]
    ros_keys = {f"3/{ROBOT}/**", "3/clock/**", "@ros2_lv/3/**"}
    reader, driver = rules_of(acl, "ros2-reader"), rules_of(acl, "ros2-driver")
    bridge, inspector = rules_of(acl, "ros2-bridge"), rules_of(acl, "inspector")
    assert "put" not in reader and reader["declare_subscriber"] >= ros_keys
    assert reader["liveliness_token"] == {"@ros2_lv/3/**"}
    assert driver["put"] == {f"3/{ROBOT}/cmd_vel_in/**"}
    assert bridge["put"] == {f"3/{ROBOT}/**", "3/clock/**", f"ubf/{ROBOT}/vote/root/teleop",
                             f"ubf/{ROBOT}/heartbeat/ros2"}
    assert bridge["liveliness_token"] >= {f"ubf/{ROBOT}/alive/teleop", f"ubf/{ROBOT}/alive/ros2"}
    assert ros_keys <= reader["egress:put"]
    assert not ros_keys & inspector.get("egress:put", set())  # ROS keys go to ROS nodes only


@pytest.fixture(scope="module")
def secure_robot(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[int, Path]]:
    folder = tmp_path_factory.mktemp("ros2s")
    path = folder / "robot.yaml"
    path.write_text(ROBOT_FILE)
    init(folder / "secure", robot=load_robot(path))
    port = free_port()
    proc = subprocess.Popen([sys.executable, "-m", "ubf_async.launch", str(path), "--listen",
                             f"tls/127.0.0.1:{port}", "--quiet", "--secure",
                             str(folder / "secure")], cwd=ROOT, stdout=subprocess.PIPE,
                            text=True)
    assert proc.stdout is not None
    for line in proc.stdout:
        if "controller:" in line:
            break
    drain = threading.Thread(target=proc.stdout.read, daemon=True)
    drain.start()
    try:
        yield port, folder / "secure"
    finally:
        proc.terminate()
        proc.wait(timeout=30)
        drain.join(timeout=10)
        proc.stdout.close()


def ros_side(port: int, setup: Path, identity: str) -> RosSide:
    """A ROS 2 node joining as ``identity``, configured as the secure docs say: with the
    override ``python -m ubf_async.secure zenoh-override DIR IDENTITY --connect tls/…``
    prints (:func:`ubf_async.net.secure.override`)."""
    made = override(setup, identity, connect=[f"tls/127.0.0.1:{port}"])
    assert "transport/link/tls/enable_mtls=true" in made and 'mode="client"' in made
    return RosSide(port, domain_id=3, env={**os.environ, "ZENOH_CONFIG_OVERRIDE": made})


TURNING = (0.0, 1.0)


def turning_seen(ros: RosSide, topic: str) -> bool:
    return any((t["linear"]["x"], t["angular"]["z"]) == TURNING for t in ros.received(topic))


@pytest.mark.slow
def test_a_ros2_reader_reads_but_only_a_ros2_driver_drives(
        secure_robot: tuple[int, Path]) -> None:
    port, setup = secure_robot
    cmd_vel = f"/{ROBOT}/cmd_vel"
    reader = ros_side(port, setup, "ros2-reader")
    try:
        reader.send(op="sub", topic=cmd_vel, type="geometry_msgs/msg/Twist")
        reader.wait("subscribed")
        wait_until(lambda: len(reader.received(cmd_vel)) >= 10, timeout_s=20,
                   what="the reader to read cmd_vel")
        reader.send(op="pub", topic=f"/{ROBOT}/cmd_vel_in", linear=TURNING[0],
                    angular=TURNING[1], rate_hz=20, count=30)
        reader.wait("pub_done")
        after = len(reader.received(cmd_vel))
        wait_until(lambda: len(reader.received(cmd_vel)) >= after + 25, timeout_s=20,
                   what="half a second more of cmd_vel")
        assert not turning_seen(reader, cmd_vel), "the reader's Twists must be dropped"
        driver = ros_side(port, setup, "ros2-driver")
        try:
            deadline = time.monotonic() + 20
            while not turning_seen(reader, cmd_vel) and time.monotonic() < deadline:
                driver.send(op="pub", topic=f"/{ROBOT}/cmd_vel_in", linear=TURNING[0],
                            angular=TURNING[1], rate_hz=20, count=20)
                driver.wait("pub_done")
            assert turning_seen(reader, cmd_vel), "the driver's Twists drive the robot"
        finally:
            driver.close()
    finally:
        reader.close()
