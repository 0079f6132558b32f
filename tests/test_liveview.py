"""The live view: a Foxglove WebSocket client (tests/foxglove_client.py, written from the
protocol, decoding with the schemas the server advertises) connects to ``launch --foxglove``
and to the standalone bridge, subscribes to the camera, pose and scene channels and decodes
what arrives; the converters on their own (a faulty one cut off, the others go on); the
shipped layout is the one the code builds."""

from __future__ import annotations

import asyncio
import base64
import json
import logging
import math
import os
import re
import signal
import socket
import struct
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

import cv2
import jsonschema
import numpy as np
import pytest

from tests.conftest import eventually, free_port
from tests.foxglove_client import FoxgloveClient
from ubf_async.runtime.bus import Bus
from ubf_async.services.liveview import (
    CLIENT_GONE,
    TRAIL_REFRESH_S,
    TRAIL_STEP_M,
    FoxgloveServer,
    LiveMessage,
    LiveView,
    RangeConverter,
    TruthConverter,
    layout_json,
)
from ubf_async.wire.protocol import Message
from ubf_async.wire.topics import Drive, Range, SimTruth, TruthRobot

ROOT = Path(__file__).resolve().parent.parent
ENV = {**os.environ, "PYTHONUNBUFFERED": "1"}
LAYOUT = ROOT / "docs" / "foxglove-layout.json"
SEEN = {"/camera/front/image", "/robot/pose", "/tf", "/robot/trail", "/arena", "/ir/front",
        "/ubf/cmd/drive", "/ubf/trace"}


def read_line_with(stream: IO[str], text: str) -> str:
    for line in stream:
        if text in line:
            return line
    raise AssertionError(f"the process ended before printing {text!r}")


def url_in(line: str) -> str:
    return next(word for word in line.split() if word.startswith("ws://"))


@pytest.fixture
def running(endpoint: str, robot: str) -> Iterator[Any]:
    """Start processes; each is stopped with SIGINT at the end and must exit cleanly."""
    procs: list[subprocess.Popen[str]] = []

    def start(*args: str) -> subprocess.Popen[str]:
        proc = subprocess.Popen([sys.executable, "-m", *args], cwd=ROOT, env=ENV, text=True,
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
        procs.append(proc)
        return proc

    yield start
    for proc in reversed(procs):
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=30)
        assert proc.returncode == 0, out


def advertised_layout_topics() -> set[str]:
    """Every topic the shipped layout shows."""
    found: set[str] = set()

    def walk(node: Any) -> None:
        if isinstance(node, dict):
            for key, value in node.items():
                if key == "topics" and isinstance(value, dict):
                    found.update(value)
                elif key in ("imageTopic", "topicPath", "value") and isinstance(value, str):
                    found.add(value.split(".", 1)[0])
                walk(value)
        elif isinstance(node, list):
            for item in node:
                walk(item)

    walk(json.loads(LAYOUT.read_text("utf-8")))
    return found


def check_live(url: str) -> None:
    with FoxgloveClient(url) as client:
        client.wait_for_topics(SEEN | advertised_layout_topics())
        client.subscribe(SEEN)
        # The trail is sent as it grows, and every TRAIL_REFRESH_S when the robot stands still
        # (it may have settled before the ball by now).
        got = client.collect(SEEN, per_topic=3, timeout_s=30, at_least={"/robot/trail": 1})
    # The camera's view: the 160×128 pixels seekcolor reads, four times larger, with the
    # bins' boundaries drawn in green.
    image_msg = got["/camera/front/image"][-1].decoded
    assert image_msg.format == "jpeg" and image_msg.frame_id == "camera_front"
    image = cv2.imdecode(np.frombuffer(image_msg.data, np.uint8), cv2.IMREAD_COLOR)
    assert image.shape == (512, 640, 3)
    for x in (128, 256, 384, 512):  # bin edges at 32, 64, 96, 128 of 160 columns, ×4
        b, g, r = (int(v) for v in image[250, x])
        assert g > 150 and r < 100 and b < 100, (x, (b, g, r))
    # The pixels seekcolor counted carry a cyan dot (the ball is in sight in this scenario).
    images = [cv2.imdecode(np.frombuffer(m.decoded.data, np.uint8), cv2.IMREAD_COLOR)
              for m in got["/camera/front/image"]]
    assert any(((i[..., 0] > 190) & (i[..., 1] > 190) & (i[..., 2] < 140)).sum() > 10
               for i in images)
    pose = got["/robot/pose"][-1].decoded
    assert pose.frame_id == "world"
    assert abs(pose.pose.position.x) < 1.5 and abs(pose.pose.position.y) < 1.5
    q = pose.pose.orientation
    assert math.isclose(q.z ** 2 + q.w ** 2, 1.0, rel_tol=1e-6)
    tf = got["/tf"][-1].decoded
    assert (tf.parent_frame_id, tf.child_frame_id) == ("world", "base_link")
    arena = {e.id: e for e in got["/arena"][-1].decoded.entities}
    assert len(arena["arena"].cubes) == 4  # the four walls of ball-in-sight's arena
    assert len(arena["objects"].spheres) == 1  # the ball
    assert arena["robot"].cubes[0].size.x == pytest.approx(0.10)
    ir = got["/ir/front"][-1].decoded.entities[0]
    assert ir.frame_id == "base_link" and len(ir.lines[0].points) == 2
    drive = got["/ubf/cmd/drive"][-1].decoded
    assert set(drive) == {"stamp_ns", "seq", "data"}
    assert -100 <= drive["data"]["speed"] <= 100 and drive["data"]["winners"]
    nodes = got["/ubf/trace"][-1].decoded["data"]["nodes"]
    assert nodes[0]["name"] == "seek_pink_ball" and nodes[0]["depth"] == 0
    for topic, messages in got.items():
        times = [m.log_time_ns for m in messages]
        assert times == sorted(times), topic  # the robot's clock: simulated time of the run
        assert all(0 < t < 120e9 for t in times), topic


def test_launch_serves_the_robot_live_to_a_foxglove_client(running: Any, endpoint: str,
                                                           robot: str) -> None:
    port = free_port()
    proc = running("ubf_async.launch", "--listen", endpoint, "--robot", robot, "--quiet",
                   "--speed", "2", "--foxglove", str(port))
    assert proc.stdout is not None
    line = read_line_with(proc.stdout, "live in Foxglove on")
    assert url_in(line) == f"ws://127.0.0.1:{port}"
    check_live(url_in(line))


def test_the_standalone_bridge_serves_a_running_robot(running: Any, endpoint: str,
                                                      robot: str) -> None:
    robot_proc = running("ubf_async.launch", "--listen", endpoint, "--robot", robot, "--quiet")
    assert robot_proc.stdout is not None
    read_line_with(robot_proc.stdout, "attach with")
    # Nobody connects to this one: it says so at the end, rather than "N messages served".
    idle = subprocess.run(
        [sys.executable, "-m", "ubf_async.liveview", "--connect", endpoint, "--robot", robot,
         "--port", str(free_port()), "--name", "foxglove-idle", "--duration", "1"],
        cwd=ROOT, env=ENV, capture_output=True, text=True, timeout=60)
    assert idle.returncode == 0, idle.stdout + idle.stderr
    ending = idle.stdout.splitlines()[-1]
    assert re.fullmatch(r"python -m ubf_async\.liveview: no Foxglove client subscribed: "
                        r"[1-9]\d* messages converted, none sent", ending), ending
    bridge = running("ubf_async.liveview", "--connect", endpoint, "--robot", robot, "--port",
                     str(free_port()))
    assert bridge.stdout is not None
    check_live(url_in(read_line_with(bridge.stdout, "live on")))
    bridge.send_signal(signal.SIGINT)
    out, _ = bridge.communicate(timeout=30)
    assert bridge.returncode == 0, out
    served = re.search(r"liveview: (\d+) of (\d+) messages converted went to 1 Foxglove "
                       r"client\(s\)", out)
    assert served, out
    sent, converted = int(served[1]), int(served[2])
    assert 0 < sent < converted  # what the client subscribed to, not every channel


def test_foxglove_without_a_port_leaves_the_robot_file_alone() -> None:
    from ubf_async.tools.launch import parse_args

    pi = "examples/robots/pi-whegs.yaml"
    for argv, port, robot_file in (
            (["--foxglove", pi], 8765, pi),
            ([pi, "--foxglove"], 8765, pi),
            (["--foxglove", "0", pi], 0, pi),
            (["--foxglove", "9000"], 9000, "mini-whegs"),
            (["--foxglove", "--quiet", pi], 8765, pi)):
        args = parse_args(argv)
        assert (args.foxglove, str(args.robot_file)) == (port, robot_file), argv
    # As a user runs it: the robot file is loaded, not read as a port.
    check = subprocess.run([sys.executable, "-m", "ubf_async.launch", "--foxglove", pi,
                            "--check"], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert check.returncode == 0, check.stderr
    assert check.stdout.startswith(f"{pi}: robot 'pi-whegs' — OK")


def test_a_port_in_use_is_a_clear_error(endpoint: str, robot: str) -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        proc = subprocess.run(
            [sys.executable, "-m", "ubf_async.launch", "--listen", endpoint, "--robot", robot,
             "--quiet", "--duration", "1", "--foxglove", str(port)],
            cwd=ROOT, env=ENV, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert f"Foxglove server on 127.0.0.1:{port}" in proc.stderr
    assert "Address already in use" in proc.stderr
    assert "Traceback" not in proc.stderr


# -- the converters on their own -------------------------------------------------------------

def message(schema: str, data: Any, stamp_ns: int = 1_000_000_000) -> Message[Any]:
    return Message(schema=schema, stamp_ns=stamp_ns, seq=1, data=data)


def truth(x_m: float, stamp_ns: int) -> Message[Any]:
    return message("sim.truth", SimTruth(time_s=stamp_ns / 1e9, robot=TruthRobot(
        x_m=x_m, y_m=0.0, heading_rad=0.5)), stamp_ns)


def test_the_trail_grows_only_as_the_robot_moves() -> None:
    converter = TruthConverter()
    topics = []
    for i, x in enumerate([0.0, 0.002, 0.004, 0.011, 0.012, 0.03]):
        topics.append([m.topic for m in converter.convert("sim/truth", truth(x, i), i)])
    assert [("/robot/trail" in t) for t in topics] == [True, False, False, True, False, True]
    assert all({"/robot/pose", "/tf"} <= set(t) for t in topics)
    assert len(converter.trail) == 3 and TRAIL_STEP_M == 0.01


def test_a_robot_standing_still_has_its_trail_sent_again_for_late_viewers() -> None:
    converter = TruthConverter()
    step_ns = 50_000_000  # the simulator's truth at 20 Hz
    sent_at = [i * step_ns for i in range(100)  # 5 s standing at the same spot
               if any(m.topic == "/robot/trail"
                      for m in converter.convert("sim/truth", truth(0.5, i * step_ns), i))]
    refresh_ns = int(TRAIL_REFRESH_S * 1e9)
    assert sent_at == list(range(0, 100 * step_ns, refresh_ns))
    assert len(converter.trail) == 1  # sent again, not grown


def test_an_ir_reading_out_of_range_is_drawn_grey_to_the_maximum() -> None:
    from foxglove.messages import SceneUpdate  # noqa: F401  (the SDK decodes nothing: proto)

    converter = RangeConverter(mount_x_m=0.05)
    ok = list(converter.convert("sensor/range/front", message("range", Range(
        range_mm=200, status="ok", min_mm=40, max_mm=300)), 5))
    far = list(converter.convert("sensor/range/front", message("range", Range(
        range_mm=None, status="too_far", min_mm=40, max_mm=300)), 6))
    assert [m.topic for m in ok + far] == ["/ir/front", "/ir/front"]
    assert ok[0].data != far[0].data and b"200 mm" in ok[0].data and b"too far" in far[0].data


class Faulty:
    schemas = frozenset({"drive"})

    def __init__(self) -> None:
        self.calls = 0

    def convert(self, source: str, message: Message[Any],
                log_time_ns: int) -> list[LiveMessage]:
        self.calls += 1
        raise RuntimeError("broken converter")


def test_a_faulty_converter_is_cut_off_and_the_others_go_on(
        caplog: pytest.LogCaptureFixture) -> None:
    faulty = Faulty()
    view = LiveView(robot_prefix="ubf/r", converters=[faulty])
    drive = message("drive", Drive(speed=10.0, turn=-5.0, winners=("chase",)))
    for _ in range(3):
        out = view.convert("ubf/r/cmd/drive", drive, 7)
        assert [m.topic for m in out] == ["/ubf/cmd/drive"]  # the JSON channel goes on
    assert faulty.calls == 1 and "Faulty" in view.failed
    assert "broken converter" in caplog.text
    (live,) = out
    schema = json.loads(live.schema.data)
    jsonschema.Draft202012Validator(schema).validate(json.loads(live.data))
    assert json.loads(live.data)["data"]["winners"] == ["chase"]
    assert view.convert("ubf/other/cmd/drive", drive, 7) == []  # another robot's key


def test_the_shipped_layout_is_the_one_the_code_builds() -> None:
    assert LAYOUT.read_text("utf-8") == layout_json(), (
        "regenerate it: python -m ubf_async.liveview --layout docs/foxglove-layout.json")
    assert {"/camera/front/image", "/arena", "/ubf/cmd/drive", "/ubf/trace"} <= \
        advertised_layout_topics()


@pytest.mark.asyncio
async def test_a_viewer_gone_without_a_goodbye_is_news_not_an_error(
        robot_bus: Bus, caplog: pytest.LogCaptureFixture) -> None:
    """A browser tab closed: its connection reset without the WebSocket's closing handshake.
    foxglove-sdk logs that as an ERROR; the live view says it at INFO."""
    server = FoxgloveServer(bus=robot_bus, port=0, host="127.0.0.1")
    await server.start()
    try:
        with caplog.at_level(logging.INFO, logger="foxglove"):
            assert server.port is not None
            tab = socket.create_connection(("127.0.0.1", server.port))
            key = base64.b64encode(os.urandom(16)).decode()
            tab.sendall(f"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nUpgrade: websocket\r\n"
                        f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\n"
                        f"Sec-WebSocket-Version: 13\r\n"
                        f"Sec-WebSocket-Protocol: foxglove.sdk.v1\r\n\r\n".encode())
            assert (await asyncio.to_thread(tab.recv, 4096)).startswith(b"HTTP/1.1 101")
            tab.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
            tab.close()  # a reset, no closing handshake

            def gone() -> list[logging.LogRecord]:
                return [r for r in caplog.records
                        if any(words in r.getMessage() for words in CLIENT_GONE)]

            await eventually(lambda: bool(gone()), timeout_s=30, what="the reset logged")
            # (Said once or more: what it was receiving, sending, or its server's greeting,
            # when the reset came.)
            assert {r.levelname for r in gone()} == {"INFO"}
            assert not [r for r in caplog.records if r.levelno >= logging.WARNING]
    finally:
        await server.aclose()

