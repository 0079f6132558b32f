"""MCAP recording of the bus: a scenario run recorded by launch and read back by the mcap
library alone (no ubf_async import: every message checked against the schema stored in the
file), a killed recorder's file recovered by a streaming reader, drops counted when the disk
does not keep up, and files split by size; without a robot, nothing recorded and an error."""

from __future__ import annotations

import asyncio
import base64
import contextlib
import itertools
import json
import os
import re
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import msgpack
import pytest

from tests.conftest import eventually
from ubf_async.cli.args import connection_options
from ubf_async.clocks.clock import SimClock
from ubf_async.errors import NoRobotError
from ubf_async.net.inprocess import InProcessTransport
from ubf_async.net.options import DEFAULT_LISTEN, ConnectionOptions
from ubf_async.runtime.bus import Bus
from ubf_async.tools import liveview
from ubf_async.tools import record as recording
from ubf_async.tools.record import McapRecorder, build_parser, record

ROOT = Path(__file__).resolve().parent.parent
ENV = {**os.environ, "PYTHONUNBUFFERED": "1"}

READ_WITH_MCAP_ALONE = r'''
import collections, json, sys
import jsonschema, msgpack
from google.protobuf import descriptor_pb2, descriptor_pool, json_format, message_factory
from mcap.reader import make_reader
assert not any(m.startswith("ubf_async") for m in sys.modules)
channels = collections.Counter()
stamps = collections.defaultdict(list)
invalid = []
with open(sys.argv[1], "rb") as f:
    reader = make_reader(f)
    summary = reader.get_summary()
    metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
    validators = {}
    live = collections.Counter()
    live_samples = {}
    classes = {}
    for schema, channel, message in reader.iter_messages():
        if channel.message_encoding == "protobuf":  # the live view's Foxglove channels
            assert schema.encoding == "protobuf" and schema.name.startswith("foxglove.")
            if schema.id not in classes:
                files = descriptor_pb2.FileDescriptorSet.FromString(schema.data)
                pool = descriptor_pool.DescriptorPool()
                for file in files.file:
                    pool.Add(file)
                classes[schema.id] = message_factory.GetMessageClass(
                    pool.FindMessageTypeByName(schema.name))
            decoded = classes[schema.id].FromString(message.data)
            live[channel.topic] += 1
            live_samples[channel.topic] = [schema.name, json_format.MessageToDict(decoded)]
            continue
        if channel.message_encoding == "json":
            assert schema.encoding == "jsonschema" and channel.topic.startswith("/ubf/")
            if schema.id not in validators:
                validators[schema.id] = jsonschema.Draft202012Validator(json.loads(schema.data))
            body = json.loads(message.data)
            errors = [e.message for e in validators[schema.id].iter_errors(body)]
            if errors:
                invalid.append((channel.topic, errors[:2]))
            live[channel.topic] += 1
            continue
        assert schema.encoding == "jsonschema" and channel.message_encoding == "msgpack"
        if schema.id not in validators:
            validators[schema.id] = jsonschema.Draft202012Validator(json.loads(schema.data))
        envelope = msgpack.unpackb(message.data)
        errors = [e.message for e in validators[schema.id].iter_errors(envelope)]
        if errors:
            invalid.append((channel.topic, errors[:2]))
        channels[channel.topic] += 1
        stamps[channel.topic].append((message.log_time, message.publish_time,
                                      envelope["stamp_ns"], envelope["seq"]))
print(json.dumps({"channels": channels, "stamps": stamps, "invalid": invalid, "live": live,
                  "live_samples": live_samples,
                  "metadata": metadata, "schemas": len(summary.schemas)}))
'''


def read_alone(path: Path) -> dict:
    result = subprocess.run([sys.executable, "-c", READ_WITH_MCAP_ALONE, str(path)],
                            capture_output=True, text=True, timeout=120, check=True)
    return json.loads(result.stdout)


def recording_md_snippets() -> list[str]:
    """The Python blocks of docs/recording.md (they read ``out/mini.mcap``)."""
    text = (ROOT / "docs" / "recording.md").read_text("utf-8")
    return re.findall(r"^```python\n(.*?)^```$", text, re.S | re.M)


def test_a_scenario_run_recorded_by_launch_reads_back_with_mcap_alone(tmp_path: Path) -> None:
    result = subprocess.run(
        [sys.executable, "-m", "ubf_async.launch", "--scenario", "ball-in-sight", "--speed",
         "5", "--duration", "4", "--quiet", "--listen", "tcp/127.0.0.1:0", "--record",
         str(tmp_path / "out")], cwd=ROOT, env=ENV, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stdout + result.stderr
    path = tmp_path / "out" / "mini.mcap"
    assert f"recording the bus to {path}" in result.stdout
    read = read_alone(path)
    assert read["invalid"] == []  # every message matches the schema stored in the file
    assert read["metadata"]["ubf_async"]["clock"] == "simulated"
    channels = read["channels"]
    for key in ("sensor/camera/front", "sensor/range/front", "sensor/encoders/wheels",
                "sensor/odometry/wheels", "sensor/motors/main", "sensor/leds/panel",
                "cmd/drive", "clock", "trace", "heartbeat/controller", "status/controller"):
        assert f"ubf/mini/{key}" in channels, key
    # 4 simulated seconds: the controller at 50 Hz plus a reflex tick on each IR sample
    # (25 Hz), the camera every 0.11 s, a trace per tick.
    assert 280 <= channels["ubf/mini/cmd/drive"] <= 320
    assert 30 <= channels["ubf/mini/sensor/camera/front"] <= 40
    assert abs(channels["ubf/mini/trace"] - channels["ubf/mini/cmd/drive"]) <= 2
    assert f"recorded {sum(channels.values())} messages" in result.stdout
    # Beside them, the live view's channels, decoded with the protobuf schemas in the file:
    # the recording opens in Foxglove with the live layout.
    live, samples = read["live"], read["live_samples"]
    assert f"and {sum(live.values())} in the live view's Foxglove channels" in result.stdout
    layout = (ROOT / "docs" / "foxglove-layout.json").read_text("utf-8")
    for topic, schema in (("/camera/front/image", "foxglove.CompressedImage"),
                          ("/robot/pose", "foxglove.PoseInFrame"),
                          ("/tf", "foxglove.FrameTransform"),
                          ("/robot/trail", "foxglove.SceneUpdate"),
                          ("/arena", "foxglove.SceneUpdate"),
                          ("/ir/front", "foxglove.SceneUpdate")):
        assert samples[topic][0] == schema, topic
    assert 30 <= live["/camera/front/image"] <= 40  # a view of every frame
    image = samples["/camera/front/image"][1]
    assert image["format"] == "jpeg" and image["frameId"] == "camera_front"
    assert base64.b64decode(image["data"])[:2] == b"\xff\xd8"  # a JPEG
    assert samples["/robot/pose"][1]["frameId"] == "world"
    arena = {e["id"]: e for e in samples["/arena"][1]["entities"]}
    assert len(arena["arena"]["cubes"]) >= 4 and arena["objects"]["spheres"]  # walls, ball
    assert live["/ubf/cmd/drive"] == channels["ubf/mini/cmd/drive"]
    for topic in ("/camera/front/image", "/arena", "/ir/front", "/ubf/cmd/drive", "/ubf/trace"):
        assert f'"{topic}' in layout, topic  # the shipped layout shows them
    for key, rows in read["stamps"].items():
        log_times = [row[0] for row in rows]
        assert log_times == sorted(log_times), key  # received in order, on the robot's clock
        assert all(0 <= t <= 4.2e9 for t in log_times), key  # simulated time of the run
        assert all(row[1] == row[2] for row in rows), key  # publish_time is the stamp
        if key.startswith("ubf/mini/sensor/") or key == "ubf/mini/cmd/drive":
            assert all(row[0] - row[1] <= 0.2e9 for row in rows), key  # arrived on time
            seqs = [row[3] for row in rows]
            assert seqs == sorted(seqs), key

    # docs/recording.md's snippets, as printed there, on this file: the reading one prints
    # every original message (each checked against its schema), the summary one the counts.
    reading, summary = recording_md_snippets()
    # jsonschema.validate() builds a validator per call: ≈ 20x slower over a recording.
    assert "jsonschema.validate(" not in reading
    printed = subprocess.run([sys.executable, "-c", reading], cwd=tmp_path, capture_output=True,
                             text=True, timeout=120, check=True).stdout.splitlines()
    assert len(printed) == sum(channels.values())
    assert {line.split()[0] for line in printed} == set(channels)
    printed = subprocess.run([sys.executable, "-c", summary], cwd=tmp_path, capture_output=True,
                             text=True, timeout=60, check=True).stdout.splitlines()
    total = sum(channels.values()) + sum(live.values())
    assert re.fullmatch(rf"{total} messages over [\d.]+ s on {len(channels) + len(live)} "
                        rf"channels", printed[0]), printed[0]
    assert f"{channels['ubf/mini/cmd/drive']:7}  ubf/mini/cmd/drive" in printed


MARKER_HZ = 100.0
FLUSH_S = 0.3
TRANSIT_S = 0.2
"""Slack for a marker's way to the recorder's file besides the flush period: zenoh's delivery,
the hand-off onto the recorder's loop, the writer's queue and its flush check (every message,
or ``flush_s / 4`` when idle), on a loaded 2-core machine."""


@pytest.mark.asyncio
async def test_a_killed_recorder_leaves_a_file_a_streaming_reader_recovers(
        tmp_path: Path, endpoint: str, robot: str) -> None:
    robot_proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "ubf_async.launch", "--listen", endpoint, "--robot", robot,
        "--quiet", "--duration", "60", cwd=ROOT, env=ENV, stdout=asyncio.subprocess.DEVNULL)
    recorder = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "ubf_async.record", "--connect", endpoint, "--robot", robot,
        "--out", str(tmp_path), "--flush-s", str(FLUSH_S), "--progress", "--name", "rec",
        "--wait-for-robot-s", "60", cwd=ROOT, env=ENV, stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.STDOUT)
    # Markers beside the robot's traffic, numbered and timed here: what the recorder was given
    # before the kill is known exactly, so the loss can be bounded both ways.
    bus = await Bus.open(ConnectionOptions(robot=robot, connect=[endpoint]))
    marker = bus.publisher(f"{bus.keys.prefix}/test/marker", "test.marker")
    sent_at: list[float] = []  # monotonic time marker n + 1 was put

    async def mark() -> None:
        await marker.wait_for_subscribers(timeout_s=60)  # the recorder's subscription
        start = time.monotonic()
        while True:
            marker.publish({"n": len(sent_at) + 1})
            sent_at.append(time.monotonic())
            await asyncio.sleep(max(0.0, start + len(sent_at) / MARKER_HZ - time.monotonic()))

    marking = asyncio.create_task(mark())
    try:
        assert recorder.stdout is not None
        flushed: list[tuple[int, int]] = []  # (written, queued) after each flush
        flush_times: list[float] = []
        while len(flushed) < 6 or len(sent_at) < MARKER_HZ:
            line = (await asyncio.wait_for(recorder.stdout.readline(), 60)).decode()
            assert line, "the recorder ended early"
            progress = re.match(r"recorded (\d+) messages \((\d+) dropped, (\d+) queued\)", line)
            if progress:
                assert progress[2] == "0"  # nothing dropped: the bound below is the whole loss
                flushed.append((int(progress[1]), int(progress[3])))
                flush_times.append(time.monotonic())
        # Killed two thirds into a flush period (not just after a flush, which would lose
        # nothing): the messages since the last flush are in a chunk not yet closed.
        await asyncio.sleep(FLUSH_S * 2 / 3)
        killed_at = time.monotonic()
        recorder.kill()
        sent_before_kill = sum(1 for t in sent_at if t < killed_at)
    finally:
        marking.cancel()
        for proc in (recorder, robot_proc):
            with contextlib.suppress(ProcessLookupError):
                proc.kill()
            await proc.wait()
        await bus.aclose()
    # A flush (chunk closed, file synced) every flush_s: what bounds the loss below.
    gaps = [b - a for a, b in itertools.pairwise(flush_times)]
    assert max(gaps) <= FLUSH_S + TRANSIT_S, gaps
    got = recover(tmp_path / f"{robot}.mcap")
    assert not got.complete  # killed: no footer, no index
    assert got.live > 0  # the live view's channels are in the file, and not counted below
    # Every message the recorder said was written (on the disk) before the kill is there.
    written, queued = flushed[-1]
    assert got.originals >= written > flushed[0][0] > 0
    # The markers: the first n of those sent, each once (no gap, nothing invented) ...
    numbers = [msgpack.unpackb(p)["data"]["n"] for p in got.payloads[marker.key]]
    assert numbers == list(range(1, len(numbers) + 1))
    assert len(numbers) <= sent_before_kill
    # ... and at most the last flush_s of them lost, plus those queued (docs/recording.md).
    lost = sent_before_kill - len(numbers)
    allowed = MARKER_HZ * (FLUSH_S + TRANSIT_S) + queued
    assert lost <= allowed, (lost, allowed, queued)


@dataclass
class Recovered:
    originals: int = 0
    """Messages of the original channels (msgpack: the bus's keys)."""
    live: int = 0
    """Messages of the live view's Foxglove channels."""
    complete: bool = False
    """Whether the file ended properly (its footer)."""
    payloads: dict[str, list[bytes]] = field(default_factory=dict)
    """The original messages' payloads by key, in file order."""


def recover(path: Path) -> Recovered:
    """What a streaming (non-seeking) reader gets from a possibly truncated file."""
    from mcap.exceptions import McapError
    from mcap.records import Channel, Footer, Message
    from mcap.stream_reader import StreamReader

    got, channels = Recovered(), {}
    with path.open("rb") as f:
        try:
            for record in StreamReader(f, emit_chunks=False).records:
                if isinstance(record, Channel):
                    channels[record.id] = record
                elif isinstance(record, Message):
                    channel = channels[record.channel_id]
                    if channel.message_encoding == "msgpack":
                        got.originals += 1
                        got.payloads.setdefault(channel.topic, []).append(record.data)
                    else:
                        got.live += 1
                got.complete = got.complete or isinstance(record, Footer)
        except (McapError, EOFError, ValueError):
            pass  # the torn end: a chunk that was being written
    return got


@pytest.mark.asyncio
async def test_drops_are_counted_when_the_writer_does_not_keep_up(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # The writer thread stalls after its first flush, as it would in a write to a stalled
    # disk: the bounded queue fills, the rest is dropped and counted, the loop goes on.
    stalled, release = threading.Event(), threading.Event()
    flush = recording._File.flush

    def stalling_flush(file: recording._File) -> None:
        flush(file)
        stalled.set()
        release.wait(timeout=30)

    monkeypatch.setattr(recording._File, "flush", stalling_flush)
    net = InProcessTransport()
    robot, device = Bus(transport=net, robot="r1"), Bus(transport=net, robot="r1")
    recorder = McapRecorder(bus=robot, out=tmp_path, max_queue=10, flush_s=0.01)
    await recorder.start()
    sensor = device.publisher(device.keys.sensor("light", "x"), "light")
    sensor.publish({"lux": -1.0})
    await net.settle()
    await asyncio.to_thread(stalled.wait, 30)
    for i in range(50):
        sensor.publish({"lux": float(i)})
        await net.settle()
    stats = recorder.stats  # (it records its own heartbeats too)
    assert stats.dropped >= 40 and stats.received >= 51
    release.set()
    await recorder.aclose()
    await recorder.aclose()  # harmless twice
    read = read_alone(tmp_path / "r1.mcap")
    assert sum(read["channels"].values()) == stats.written == stats.received - stats.dropped
    assert 9 <= read["channels"]["ubf/r1/sensor/light/x"] <= 11  # (≤ 1 taken, 10 queued)
    await robot.aclose()
    await device.aclose()


@pytest.mark.asyncio
async def test_a_file_that_cannot_be_written_stops_the_recording_and_says_why(
        tmp_path: Path) -> None:
    (tmp_path / "taken").write_text("a file where the directory should be")
    net = InProcessTransport()
    robot = Bus(transport=net, robot="r1")
    recorder = McapRecorder(bus=robot, out=tmp_path / "taken" / "r1.mcap")
    with pytest.raises(OSError):
        await recorder.start()  # the directory cannot be made: said at once
    recorder = McapRecorder(bus=robot, out=tmp_path / "r1.mcap")
    (tmp_path / "r1.mcap").mkdir()  # the file itself cannot be opened
    await recorder.start()
    await eventually(lambda: recorder.stats.error is not None, what="the writer's error")
    assert "Is a directory" in (recorder.stats.error or "")
    await recorder.aclose()
    await robot.aclose()


@pytest.mark.asyncio
async def test_files_are_split_by_size_and_each_is_complete(tmp_path: Path) -> None:
    net = InProcessTransport()
    clock = SimClock(10**9)
    robot = Bus(transport=net, robot="r1", clock=clock)
    device = Bus(transport=net, robot="r1", clock=clock)
    recorder = McapRecorder(bus=robot, out=tmp_path, flush_s=0.05, split_bytes=1 << 16)
    await recorder.start()
    await net.settle()
    sensor = device.publisher(device.keys.sensor("blob", "x"), "blob")
    for _batch in range(6):
        for _ in range(20):  # incompressible: 20 × 2 KiB a batch
            sensor.publish({"noise": os.urandom(2048)})
        await net.settle()
        flushes = recorder.stats.flushes
        await eventually(lambda f=flushes: recorder.stats.flushes > f + 1,
                         what="the writer to flush the batch")
    await recorder.aclose()
    files = recorder.stats.files
    assert len(files) >= 2 and files[0] == tmp_path / "r1.mcap"
    assert files[1] == tmp_path / "r1_1.mcap"
    counts = [read_alone(f)["channels"].get("ubf/r1/sensor/blob/x", 0) for f in files]
    assert sum(counts) == 120 and all(counts[:-1])
    for f in files:
        assert recover(f).complete  # each part finished with its footer
    await robot.aclose()
    await device.aclose()


@pytest.mark.asyncio
async def test_without_a_robot_the_recorder_records_nothing_and_says_so(
        tmp_path: Path, endpoint: str) -> None:
    """Issue 35: it listened only, heard its own heartbeats and reported success. Like the
    inspector and replay it now connects where launch listens, and no robot there is an
    error (exit status 2, through run_main) before anything is written."""
    for parser in (build_parser(), liveview.build_parser()):  # both attach through cli.attach
        assert connection_options(parser.parse_args([])).connect == [DEFAULT_LISTEN]
    out = tmp_path / "rec"
    args = build_parser().parse_args(["--connect", endpoint, "--wait-for-robot-s", "0.5",
                                      "--out", str(out)])
    with pytest.raises(NoRobotError, match=f"no robot to connect to: nothing answered at "
                                           f"{endpoint}"):
        await record(args)
    assert not out.exists()
