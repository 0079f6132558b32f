"""The clock trap (issue 12): samples stamped on another clock are reported, and every shipped
sender stamps on the robot's clock — against ``python -m ubf_async.launch`` with no arguments
(simulated time)."""

from __future__ import annotations

import asyncio
import logging
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.conftest import eventually
from tests.remote_robot import Process
from ubf_async.behaviors.pink_ball import seek_pink_ball
from ubf_async.clocks import clockdomain, follow
from ubf_async.clocks.clock import SimClock
from ubf_async.clocks.clockdomain import ClockDomainWatch, foreign_clock
from ubf_async.core.action import Action
from ubf_async.net.options import ConnectionOptions
from ubf_async.runtime.aggregator import StateAggregator
from ubf_async.runtime.bus import Bus
from ubf_async.runtime.controller import Controller
from ubf_async.runtime.ordering import Refusal
from ubf_async.services.remote import ReceivedVote, RemoteBehaviors
from ubf_async.tools.inspector.state import format_clock_domain
from ubf_async.wire.protocol import Message, decode
from ubf_async.wire.topics import Range

ROOT = Path(__file__).resolve().parent.parent
S = 10**9
WALL_NS = 1_750_000_000 * S  # a CLOCK_REALTIME stamp (June 2025)


# -- the rule ----------------------------------------------------------------------------------

def test_the_rule_tells_foreign_stamps_from_the_robot_clock() -> None:
    def judge(stamp_s: float, now_s: float, *, simulated: bool = True,
              host_s: float = 5000.0) -> str | None:
        return foreign_clock(round(stamp_s * S), now_ns=round(now_s * S), simulated=simulated,
                             host_monotonic_ns=round(host_s * S))

    # The robot's own clock, a little early or late: never foreign.
    assert judge(12.3, 12.0) is None and judge(11.2, 12.0) is None
    assert judge(4.0, 12.0) is None  # 8 s old: an old sample, not another clock
    # Wall-clock time, whatever the robot runs on.
    assert foreign_clock(WALL_NS, now_ns=12 * S, simulated=True, host_monotonic_ns=5000 * S) \
        == "wall clock"
    assert foreign_clock(WALL_NS, now_ns=5000 * S, simulated=False,
                         host_monotonic_ns=5000 * S) == "wall clock"
    # This host's CLOCK_MONOTONIC sent to a simulated-time robot, even when close (3 s ahead).
    assert judge(5000.0, 12.0) == "host monotonic clock"
    assert judge(15.0, 12.0, host_s=15.2) == "host monotonic clock"
    assert judge(15.0, 12.0, simulated=False, host_s=15.2) is None  # that *is* a wall robot's
    # Anything further than 10 s: simulated time sent to a wall-time robot, another host.
    assert judge(3.0, 5000.0, simulated=False) == "another clock"
    assert judge(900.0, 12.0, host_s=50_000.0) == "another clock"


def test_the_watch_counts_per_source_warns_once_and_every_100th(
    caplog: pytest.LogCaptureFixture
) -> None:
    watch = ClockDomainWatch(robot="mini", max_sources=2)
    caplog.set_level(logging.WARNING, logger="ubf_async.clocks.clockdomain")
    assert not watch.check("range/ok", 12 * S + 1000, now_ns=12 * S, simulated=True)
    for _ in range(150):
        assert watch.check("range/wall", WALL_NS, now_ns=12 * S, simulated=True)
    assert watch.check("vote/root/teleop", 2 * S, now_ns=5000 * S, simulated=False)
    assert watch.count("range/wall") == 150 and watch.count("range/ok") == 0
    assert watch.total == 151
    warnings = [r.getMessage() for r in caplog.records]
    assert len(warnings) == 3, warnings  # range/wall: first and 100th; the vote: first
    assert "range/wall" in warnings[0] and "wall clock" in warnings[0]
    assert "refused as from the future" in warnings[0]
    assert "stamp_ns of the newest sample on ubf/mini/clock" in warnings[0]
    assert "100 samples" in warnings[1]
    assert "taken with that age" in warnings[2] and "time.monotonic_ns()" in warnings[2]
    status = watch.status()
    assert [s["source"] for s in status] == ["vote/root/teleop", "range/wall"]
    assert status[1] == {"source": "range/wall", "samples": 150, "clock": "wall clock",
                         "offset_s": pytest.approx((WALL_NS - 12 * S) / S)}
    watch.check("range/third", WALL_NS, now_ns=12 * S, simulated=True)
    assert len(watch.sources) == 2 and watch.count("range/wall") == 0  # bounded
    # A flood of names: one warning per source only for the first few, then a summary.
    caplog.clear()
    for i in range(1000):
        watch.check(f"range/junk{i}", WALL_NS, now_ns=12 * S, simulated=True)
    assert clockdomain.MAX_WARNED_SOURCES - 3 <= len(caplog.records) \
        <= clockdomain.MAX_WARNED_SOURCES + 11


def test_each_clock_reads_right_in_a_sentence(caplog: pytest.LogCaptureFixture) -> None:
    """Issue 28: a warning read "looks like the another clock"."""
    watch = ClockDomainWatch(robot="mini")
    caplog.set_level(logging.WARNING, logger="ubf_async.clocks.clockdomain")
    for _ in range(100):
        watch.check("range/far", 2 * S, now_ns=5000 * S, simulated=False)
    watch.check("range/wall", WALL_NS, now_ns=12 * S, simulated=True)
    first, hundredth, wall = (r.getMessage() for r in caplog.records)
    assert "looks like another clock, not the robot's" in first
    assert "range/far: 100 samples stamped on another clock so far" in hundredth
    assert "looks like the wall clock, not the robot's" in wall
    shown = "\n".join(format_clock_domain(watch.status()))
    assert "like another clock, last" in shown and "like the wall clock, last" in shown
    assert "the another" not in first + hundredth + wall + shown


@pytest.mark.asyncio
async def test_aggregator_and_votes_report_into_the_controllers_status(robot_bus: Bus) -> None:
    clock = SimClock()
    robot_bus.clock = clock
    clock.advance_to(7 * S)
    aggregator = StateAggregator(bus=robot_bus)
    controller = Controller(bus=robot_bus, aggregator=aggregator, root=seek_pink_ball())
    remotes = RemoteBehaviors(bus=robot_bus, root=controller.root)

    def sample(stamp_ns: int, seq: int) -> Message:
        return Message(schema="range", stamp_ns=stamp_ns, seq=seq,
                       data=Range(range_mm=250, status="ok"))

    assert aggregator.ingest("range/sim", sample(7 * S - 2_000_000, 1), 0)
    # A wall-clock stamp: refused as from the future, as before, and now also reported.
    assert not aggregator.ingest("range/wall", sample(WALL_NS, 1), 0)
    assert aggregator.refused[Refusal.FUTURE] == 1
    # This host's CLOCK_MONOTONIC on a vote.
    vote = ReceivedVote(composite="seek_pink_ball", behavior="teleop",
                        action=Action(speed=10.0, vote=1.0),
                        stamp_ns=time.monotonic_ns(), seq=1)
    assert not remotes.accept(vote)
    assert remotes.future  # refused (max_future_s), as before
    status = controller.status()["clock_domain"]
    assert {s["source"]: (s["samples"], s["clock"]) for s in status} == {
        "range/wall": (1, "wall clock"),
        "vote/seek_pink_ball/teleop": (1, "host monotonic clock"),
    }
    assert clockdomain.watch(robot_bus) is aggregator.clock_domain


@pytest.mark.asyncio
async def test_the_warning_names_the_process_that_sent_the_sample(
    robot_bus: Bus, endpoint: str, robot: str, caplog: pytest.LogCaptureFixture
) -> None:
    """Issue 35: the robot said which source stamped on another clock, not which process —
    and another process may publish under a source's name (another robot's device, a second
    copy). The first warning names the process, by the heartbeat announcing the sample's
    publisher: component, pid, host; so does the status."""
    clock = SimClock()
    robot_bus.clock = clock
    clock.advance_to(5 * S)  # simulated time; the radio below stamps this host's monotonic
    aggregator = StateAggregator(bus=robot_bus)
    await aggregator.start()
    radio = subprocess.Popen(
        [sys.executable, "-m", "components.radio", "--connect", endpoint, "--robot", robot,
         "--name", "ext", "--clock", "wall"], cwd=ROOT, text=True, stdin=subprocess.PIPE,
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
        env={**os.environ, "PYTHONUNBUFFERED": "1"})
    try:
        assert radio.stdout is not None and radio.stdin is not None
        attached = await asyncio.to_thread(radio.stdout.readline)
        assert "attached" in attached, attached
        with caplog.at_level(logging.WARNING, logger="ubf_async.clocks.clockdomain"):
            radio.stdin.write("hello robot\n")
            radio.stdin.flush()
            await eventually(lambda: "radio/ext: sample stamped" in caplog.text, timeout_s=15,
                             what="the warning")
        sender = f"radio-ext (pid {radio.pid} on {follow.HOST})"
        warning = next(r.getMessage() for r in caplog.records
                       if r.getMessage().startswith("radio/ext: sample stamped"))
        assert f", sent by {sender}, looks like the host monotonic clock" in warning, warning
        status = aggregator.clock_domain.status()
        assert [(f["source"], f.get("sender")) for f in status] == [("radio/ext", sender)]
        assert "radio/ext  1 samples, like the host monotonic clock, last " in \
            "\n".join(format_clock_domain(status))
        assert format_clock_domain(status)[-1].endswith(f" off, from {sender}")
    finally:
        radio.kill()
        radio.communicate(timeout=10)
        await aggregator.aclose()


def test_a_sample_without_a_publisher_or_unnamed_is_still_reported(
    caplog: pytest.LogCaptureFixture
) -> None:
    """A plain client sends no ``pub``: warned at once, naming no one, as before."""
    watch = ClockDomainWatch(robot="mini")
    caplog.set_level(logging.WARNING, logger="ubf_async.clocks.clockdomain")
    watch.check("range/plain", WALL_NS, now_ns=12 * S, simulated=True, pub=None)
    (warning,) = (r.getMessage() for r in caplog.records)
    assert warning.startswith("range/plain: sample stamped") and "sent by" not in warning


@pytest.mark.asyncio
async def test_a_publisher_no_heartbeat_names_is_reported_after_the_wait(
    robot_bus: Bus, caplog: pytest.LogCaptureFixture
) -> None:
    watch = ClockDomainWatch(robot="mini", senders=clockdomain.SenderNames(robot_bus,
                                                                           wait_s=0.05))
    caplog.set_level(logging.WARNING, logger="ubf_async.clocks.clockdomain")
    watch.check("range/anon", WALL_NS, now_ns=12 * S, simulated=True, pub=1234)
    assert not caplog.records  # waiting for a heartbeat to name it
    await eventually(lambda: bool(caplog.records), what="the warning after the wait")
    (warning,) = (r.getMessage() for r in caplog.records)
    assert "sent by publisher 1234 (which no heartbeat named within 0.05 s" in warning
    assert watch.status()[0].get("sender") is None


# -- the shipped senders against the default robot ---------------------------------------------

WALL_SENDER = """
import json, sys, time, msgpack, zenoh
conf = zenoh.Config()
conf.insert_json5("connect/endpoints", json.dumps([sys.argv[1]]))
conf.insert_json5("scouting/multicast/enabled", "false")
with zenoh.open(conf) as session:
    pub = session.declare_publisher(f"ubf/{sys.argv[2]}/sensor/range/wall")
    seq = 0
    while True:
        seq += 1
        pub.put(msgpack.packb({"schema": "range", "v": 1, "stamp_ns": time.time_ns(),
                               "seq": seq, "period_s": 0.05,
                               "data": {"range_mm": 900, "status": "ok"}}))
        time.sleep(0.05)
"""


@pytest.mark.slow
@pytest.mark.asyncio
async def test_shipped_senders_work_against_the_default_sim_time_robot(
    endpoint: str, robot: str
) -> None:
    """``python -m ubf_async.launch`` with no arguments but where to listen and a unique robot
    name: the simulated Mini-WHEGS on simulated time. The plain-msgpack example sensor, the
    remote behaviour of docs/protocol.md (run as written) and ``python -m components.radio``
    attach; their samples are fresh and their vote drives the robot. A wall-stamped sender
    is reported in the status, by ``inspector state`` and in the robot's log."""
    doc = (ROOT / "docs" / "protocol.md").read_text()
    section = doc[doc.index("## Remote behaviours"):]
    snippet = re.search(r"```python\n(.*?)```", section, re.S).group(1)  # type: ignore[union-attr]
    snippet = snippet.replace("tcp/127.0.0.1:7447", endpoint).replace('"mini"', repr(robot))
    robot_proc = Process("-m", "ubf_async.launch", "--listen", endpoint, "--robot", robot,
                         "--status-period-s", "0.5")
    procs: list[Process] = [robot_proc]
    radio: subprocess.Popen[str] | None = None
    bus = await Bus.open(ConnectionOptions(robot=robot, connect=[endpoint]))
    statuses: list[dict] = []
    drives: list[tuple[float, float, tuple[str, ...]]] = []
    try:
        await asyncio.to_thread(robot_proc.wait_for_line, "controller", timeout_s=40)
        bus.subscribe(bus.keys.status("controller"),
                      lambda k, p, t: statuses.append(decode(p).data))
        bus.subscribe(bus.keys.cmd("drive"), lambda k, p, t: drives.append(
            (decode(p).data.speed, decode(p).data.turn, decode(p).data.winners)))
        sensor = Process(str(ROOT / "examples" / "plain_range_sensor.py"), "--connect",
                         endpoint, "--robot", robot, "--name", "plain", "--range-mm", "700")
        teleop = Process("-c", snippet)
        wall = Process("-c", WALL_SENDER, endpoint, robot)
        procs += [sensor, teleop, wall]
        radio = subprocess.Popen(
            [sys.executable, "-m", "components.radio", "--connect", endpoint, "--robot", robot,
             "--name", "ext"], cwd=ROOT, text=True, stdin=subprocess.PIPE,
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
            env={**os.environ, "PYTHONUNBUFFERED": "1"})
        assert radio.stdout is not None and radio.stdin is not None
        attached = await asyncio.to_thread(radio.stdout.readline)
        assert "attached" in attached and "simulated time" in attached, attached
        assert "simulated time" in sensor.wait_for_line("stamping")
        assert teleop.wait_for_line("time") == "simulated time"
        radio.stdin.write("hello robot\n")
        radio.stdin.flush()

        # The documented remote behaviour's vote takes effect (teleop, priority 10).
        await eventually(lambda: bool(drives) and drives[-1] == (-30.0, 50.0, ("teleop",)),
                         timeout_s=15, what="the documented vote to drive the robot")

        def source(status: dict, name: str) -> dict | None:
            return next((s for s in status["sources"] if s["source"] == name), None)

        def settled() -> bool:
            # ... in a status taken once simulated time runs: while the simulator holds its
            # start (a busy machine renders the camera's first frame slowly) every age is 0.
            # And one in which the plain sensor is fresh: it paces itself with wall-clock
            # sleeps, not in lockstep, so on a busy machine a sample of it comes late now and
            # then, and a status taken just then rightly says it is stale (1.5 periods, 75 ms
            # of robot time, since the last one arrived).
            if not statuses:
                return False
            plain = source(statuses[-1], "range/plain")
            return plain is not None and source(statuses[-1], "radio/ext") is not None \
                and any(f["source"] == "range/wall" for f in statuses[-1]["clock_domain"]) \
                and plain["age_s"] > 0 and not plain["stale"]

        await eventually(settled, timeout_s=15,
                         what="both sources, the plain one fresh, and the wall report")
        status = statuses[-1]
        plain, radio_src = source(status, "range/plain"), source(status, "radio/ext")
        assert plain is not None and radio_src is not None
        # Ages on the robot clock are sane: a few ms, not 0 forever nor minutes.
        assert 0 < plain["age_s"] < 0.5 and not plain["stale"] and plain["refused"] == 0
        assert radio_src["refused"] == 0 and radio_src["age_s"] < 5
        assert source(status, "range/wall") is None  # refused: it never pins a source
        foreign = {f["source"]: f for f in status["clock_domain"]}
        assert set(foreign) == {"range/wall"}, foreign  # the shipped senders are not in it
        assert foreign["range/wall"]["clock"] == "wall clock"
        assert foreign["range/wall"]["samples"] >= 1
        assert status["refused"]["future"] >= 1

        shown = await asyncio.to_thread(
            subprocess.run, [sys.executable, "-m", "ubf_async.inspector", "state",
                             "--connect", endpoint, "--robot", robot],
            cwd=ROOT, capture_output=True, text=True, timeout=30)
        assert shown.returncode == 0, shown.stderr
        assert "stamped on another clock" in shown.stdout
        assert re.search(r"range/wall\s+\d+ samples, like the wall clock", shown.stdout), \
            shown.stdout

        # The conformance check (issue 55, item 3) on the same senders: the page's own remote
        # behaviour and the plain sensor (raw zenoh, hand-built msgpack) pass it; the
        # wall-stamped sender, which declares no token either, fails it on both counts.
        def conform(component: str, key: str) -> subprocess.CompletedProcess[str]:
            return subprocess.run(
                [sys.executable, "-m", "ubf_async.inspector", "conform", component, "--key",
                 key, "--seconds", "2", "--connect", endpoint, "--robot", robot],
                cwd=ROOT, capture_output=True, text=True, timeout=60)

        checked = await asyncio.gather(*(asyncio.to_thread(conform, *args) for args in (
            ("teleop", "vote/seek_pink_ball/teleop"), ("plain", "sensor/range/plain"),
            ("wall", "sensor/range/wall"))))
        for result in checked[:2]:
            assert result.returncode == 0, result.stdout + result.stderr
            assert "conforms: no deviation seen" in result.stdout
        assert checked[2].returncode == 1, checked[2].stdout + checked[2].stderr
        assert f"FAIL  no liveliness token ubf/{robot}/alive/wall" in checked[2].stdout
        assert re.search(r"FAIL  ubf/\S+/sensor/range/wall \(no pub\): \d+ stamped on the "
                         r"wall clock: this robot runs on simulated time", checked[2].stdout), \
            checked[2].stdout
    finally:
        await bus.aclose()
        if radio is not None:
            radio.kill()
            radio.communicate(timeout=10)
        for p in procs[1:]:
            p.kill()
        robot_proc.terminate()
        await asyncio.to_thread(robot_proc.proc.wait, 20)
    log = "\n".join(robot_proc.lines)
    warned = [line for line in robot_proc.lines if "range/wall: sample stamped" in line]
    assert len(warned) == 1, log  # once for the source, with the fix
    assert "ubf/" + robot + "/clock" in warned[0]
    assert " looks like " not in log.replace(warned[0], "")  # nobody else was reported
