"""The inspector's ROS-2-style verbs against a running robot in another process: hz (per
kind of tick for drive commands), bw, info, pub (checked before it sends), echo on a key
nobody publishes, state/tree --watch, and connection flags before or after the subcommand."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import io
import re
import signal
import subprocess
import sys
import time
from collections.abc import AsyncIterator, Iterator
from pathlib import Path

import pytest

from tests.conftest import eventually, free_port
from tests.remote_robot import Process
from ubf_async.net.options import ConnectionOptions
from ubf_async.runtime.bus import Bus
from ubf_async.tools.inspector.parser import build_parser
from ubf_async.tools.inspector.program import run
from ubf_async.wire.protocol import decode
from ubf_async.wire.topics import HEARTBEAT, LEDS, RANGE

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def robot_endpoint() -> Iterator[str]:
    """One simulated robot for the module (seeking the ball, 50 Hz + IR reflex ticks)."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    proc = subprocess.Popen([sys.executable, "-m", "ubf_async.launch", "--listen", endpoint,
                             "--robot", "insp", "--quiet"], cwd=ROOT,
                            stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    for line in proc.stdout:
        if "controller:" in line:
            break
    try:
        yield endpoint
    finally:
        proc.terminate()
        proc.communicate(timeout=30)


def inspect(endpoint: str, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "ubf_async.inspector", "--connect", endpoint,
                           "--robot", "insp", *args], cwd=ROOT, capture_output=True,
                          text=True, timeout=60)


def test_connection_flags_go_before_or_after_the_subcommand() -> None:
    parser = build_parser()
    for argv in (["--connect", "tcp/h:1", "--robot", "r2", "components"],
                 ["components", "--connect", "tcp/h:1", "--robot", "r2"],
                 ["--robot", "r2", "tree", "show", "--connect", "tcp/h:1"],
                 ["tree", "--connect", "tcp/h:1", "--robot", "r2", "show"],
                 ["tree", "--connect", "tcp/h:1", "set-child", "root", "chase", "--priority",
                  "3", "--robot", "r2"]):
        args = parser.parse_args(argv)
        assert (args.connect, args.robot) == (["tcp/h:1"], "r2"), argv
    defaults = parser.parse_args(["state"])
    assert defaults.robot == "mini" and defaults.mode == "client" and defaults.timeout == 5.0
    after = parser.parse_args(["--timeout", "9", "state", "--robot", "r3"])
    assert (after.timeout, after.robot) == (9.0, "r3")  # neither side undoes the other


def test_every_command_takes_the_connection_flags_before_or_after_it() -> None:
    parser = build_parser()
    positionals = {"echo": ["k"], "hz": ["k"], "bw": ["k"], "info": ["k"], "pub": ["k", "{}"]}
    for command in ("components", "keys", "echo", "state", "robots", "hz", "bw", "info", "pub",
                    "tree"):
        words = ([command, "show"] if command == "tree"
                 else [command, *positionals.get(command, [])])
        flags = ["--connect", "tcp/h:1", "--robot", "r2", "--timeout", "3"]
        for argv in (flags + words, words + flags, words[:1] + flags + words[1:]):
            args = parser.parse_args(argv)
            assert (args.connect, args.robot, args.timeout) == (["tcp/h:1"], "r2", 3.0), argv


def test_tree_takes_the_connection_flags_between_tree_and_its_verb(
        robot_endpoint: str) -> None:
    result = subprocess.run([sys.executable, "-m", "ubf_async.inspector", "tree", "--connect",
                             robot_endpoint, "--robot", "insp", "show"], cwd=ROOT,
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    assert "robot 'insp': tree version" in result.stdout and "seek_pink_ball" in result.stdout


@pytest.mark.asyncio
async def test_tree_without_a_verb_shows_the_tree(robot_endpoint: str) -> None:
    out = io.StringIO()
    args = build_parser().parse_args(["tree", "--connect", robot_endpoint, "--robot", "insp"])
    assert await run(args, out) == 0
    assert "robot 'insp': tree version" in out.getvalue()
    assert "seek_pink_ball <PriorityMerge>" in out.getvalue()


MIXED_TICKS_START = ("# every tick sends a drive command: the clock's periodic ticks and "
                     "those a sample runs at once")
HZ_MESSAGES = 150
"""Drive commands the ``hz`` report is read at: two seconds of the robot's ticks (75 Hz)."""


def hz_report(endpoint: str, messages: int) -> tuple[list[str], list[str]]:
    """Run ``inspector hz cmd/drive`` over the whole run (a window longer than it: every
    figure is over the same span of messages) until a report counts ``messages`` drive
    commands — the robot ticking and the inspector hearing it, however long either takes to
    start on a busy machine; a report every wall second says nothing about how many came.
    Returns every line printed until then, and that report (the total and each kind)."""
    proc = subprocess.Popen([sys.executable, "-m", "ubf_async.inspector", "--connect", endpoint,
                             "--robot", "insp", "hz", "cmd/drive", "--window", "1000000",
                             "--seconds", "60"], cwd=ROOT, stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    lines: list[str] = []
    try:
        for line in proc.stdout:
            lines.append(line.rstrip("\n"))
            if not line.startswith("ubf/insp/cmd/drive: average rate "):
                continue
            if int(line.rsplit("window ", 1)[1]) + 1 < messages:
                continue
            report = [lines[-1]]
            for kind in proc.stdout:  # the same report's lines per kind of tick
                lines.append(kind.rstrip("\n"))
                if not kind.startswith("  ticked by "):
                    break
                report.append(lines[-1])
            return lines, report
        raise AssertionError(f"hz ended ({proc.wait()}) before {messages} drive commands:\n"
                             + "\n".join(lines))
    finally:
        proc.terminate()
        proc.communicate(timeout=30)


def test_hz_measures_the_drive_command_rate_and_each_kind_of_tick(robot_endpoint: str) -> None:
    lines, report = hz_report(robot_endpoint, HZ_MESSAGES)
    # The mix is explained once, before the first report that counts more than one kind of
    # tick (before the robot's first commands reach it, hz says it has none yet); then each
    # report gives the total and each kind.
    explained = [i for i, line in enumerate(lines) if line.startswith(MIXED_TICKS_START)]
    reports = [i for i, line in enumerate(lines) if line.startswith("ubf/insp/cmd/drive: ")]
    mixed = [i for i in reports if lines[i + 1:i + 3] and all(
        line.startswith("  ticked by ") for line in lines[i + 1:i + 3])]
    assert len(explained) == 1 and explained[0] < mixed[0], "\n".join(lines)
    assert all(line.startswith("# no messages on ubf/insp/cmd/drive yet")
               for line in lines[:min(explained[0], reports[0])]), "\n".join(lines)
    assert len(report) == 3, "\n".join(lines)
    assert report[1].startswith("  ticked by clock: average rate ")
    assert report[2].startswith("  ticked by reflex (range/front): average rate ")
    (total, n), (clock, n_clock), (reflex, n_reflex) = (
        (float(rate), int(window)) for rate, window in
        re.findall(r"average rate ([\d.]+) Hz .* window (\d+)", "\n".join(report)))
    # Each drive command is of one kind of tick: the kinds' counts add up to the total's.
    assert (n_clock + 1) + (n_reflex + 1) == n + 1, report
    # 50 Hz periodic ticks plus a reflex tick on each IR sample (25 Hz): two clock ticks per
    # reflex tick in simulated time, in lockstep however busy the machine — so in the counts
    # and, every figure being over the same span of messages, in the rates (which are in wall
    # time: a busy machine slows the simulation, and all of them with it).
    assert 1.5 <= clock / reflex <= 2.7, "\n".join(report)
    assert abs(clock + reflex - total) <= 0.15 * total, "\n".join(report)


def test_echo_on_a_key_nobody_publishes_says_so_and_keeps_waiting(
        robot_endpoint: str) -> None:
    echo = Process("-m", "ubf_async.inspector", "--connect", robot_endpoint, "--robot", "insp",
                   "echo", "sensor/range/frnt", "--count", "1", "--wait", "0")
    try:
        # Nothing comes: after a short wait it says so (on stderr) and names what is close.
        said = echo.wait_for_line("# nothing publishes", timeout_s=60)
        assert said.startswith("# nothing publishes ubf/insp/sensor/range/frnt yet: none of the "
                               ), said
        assert "announced keys like it: sensor/range/front" in said, said
        assert said.endswith("still waiting (Ctrl-C stops) (`inspector keys` lists what is "
                             "published)"), said
        # And it is still waiting: a message published now is echoed, and echo is done.
        sent = inspect(robot_endpoint, "pub", "sensor/range/frnt",
                       "{range_mm: 77, status: ok}")
        assert sent.returncode == 0, sent.stderr
        echo.wait_for_line("ubf/insp/sensor/range/frnt range #", timeout_s=60)
        assert echo.proc.wait(timeout=60) == 0, echo.output()
    finally:
        echo.kill()
    # A key a component announces but has not published on yet is named with its publisher.
    # It judges only once every live component's heartbeat has come, however late that is.
    quiet = Process("-m", "ubf_async.inspector", "--connect", robot_endpoint, "--robot", "insp",
                    "echo", "cmd/radio")
    try:
        said = quiet.wait_for_line("# nothing", timeout_s=60)
        assert said.startswith("# nothing on ubf/insp/cmd/radio yet, though controller "
                               "announces publishing it"), said
    finally:
        quiet.kill()


def test_echo_of_a_publisher_that_left_gives_up_after_its_wait(robot_endpoint: str) -> None:
    # A second range finder attached from its own process, echoed while it runs...
    left = Process("-m", "components.range", "--connect", robot_endpoint, "--robot", "insp",
                   "--name", "left", "--yaw-deg", "45")
    try:
        heard = inspect(robot_endpoint, "echo", "sensor/range/left", "--count", "1")
        assert heard.returncode == 0, heard.stderr
        assert heard.stdout.splitlines()[-1].startswith("ubf/insp/sensor/range/left range #")
    finally:
        assert left.terminate() == 0, left.output()
    # ... and once it has gone, an echo asking for 3 samples says so and gives up by itself
    # (30 s by default; --wait here), exit status 1, instead of waiting for ever.
    started = time.monotonic()
    gone = inspect(robot_endpoint, "echo", "sensor/range/left", "--count", "3", "--wait", "3")
    assert gone.returncode == 1, (gone.stdout, gone.stderr)
    assert time.monotonic() - started >= 3.0
    assert gone.stderr.splitlines()[-1] == (
        "# nothing came on ubf/insp/sensor/range/left in 3 s: giving up (--wait S waits "
        "longer, --wait 0 for ever)"), gone.stderr
    assert gone.stdout == "# echo ubf/insp/sensor/range/left\n"
    assert "--wait S" in inspect(robot_endpoint, "echo", "--help").stdout
    refused = inspect(robot_endpoint, "echo", "sensor/range/left", "--wait", "-1")
    assert refused.returncode == 2 and refused.stderr == (
        "python -m ubf_async.inspector: error: --wait must be ≥ 0 (0 waits for ever)\n")


def test_bw_is_consistent_with_message_sizes(robot_endpoint: str) -> None:
    result = inspect(robot_endpoint, "bw", "sensor/camera/front", "--count", "2")
    assert result.returncode == 0, result.stderr
    last = result.stdout.strip().splitlines()[-1]
    match = re.search(r": (\d+) B/s  mean (\d+) B min (\d+) B max (\d+) B", last)
    assert match, last
    rate, mean, low, high = map(int, match.groups())
    assert low <= mean <= high
    assert 0.5 * mean / 0.11 <= rate <= 1.5 * mean / 0.11  # a frame every 0.11 s


def test_info_names_the_schema_fields_and_what_was_heard(robot_endpoint: str) -> None:
    result = inspect(robot_endpoint, "info", "cmd/drive")
    assert result.returncode == 0, result.stderr
    out = result.stdout
    assert "schema: drive" in out and "speed: number −100…100 (required)" in out
    heard = re.search(r"heard on ubf/insp/cmd/drive: (\d+) messages .* from 1 publisher", out)
    assert heard and int(heard.group(1)) > 20, out
    # The robot's components announce what they publish in their heartbeats.
    line = next(line for line in out.splitlines() if line.startswith("publishers"))
    assert re.match(r"publishers \(live components announcing it\): controller \(", line), line


@pytest.mark.asyncio
async def test_info_names_the_live_components_that_announce_the_key(
        robot_endpoint: str) -> None:
    # Another process with two components on the robot: one announces its range finder in its
    # heartbeat, one left (its token gone) still announcing it; a third publisher on the key
    # announces nothing.
    # The inspector connects to this process too: peers that meet only through the robot find
    # each other by gossip, which on a busy machine can take longer than the inspector listens.
    here = f"tcp/127.0.0.1:{free_port()}"
    bus = await Bus.open(ConnectionOptions(robot="insp", connect=[robot_endpoint],
                                           listen=[here]))
    key = bus.keys.sensor("range", "side")
    side = bus.publisher(RANGE, "side", period_s=0.05)
    stray = bus.publisher(RANGE, "side", period_s=0.05)
    beats = {name: bus.publisher(HEARTBEAT, name, period_s=0.2) for name in ("side", "gone")}
    token = bus.declare_token(bus.keys.alive("side"))

    async def run() -> None:
        while True:
            for publisher in (side, stray):
                publisher.publish({"range_mm": 300, "status": "ok"})
            for name, beat in beats.items():
                beat.publish({"component": name, "publishes": [{"key": key, "pub": side.pub}]})
            await asyncio.sleep(0.05)

    running = asyncio.create_task(run())
    try:
        await eventually(lambda: bus.reached_peers(), what="the robot")
        result = await asyncio.to_thread(inspect, robot_endpoint, "info", "sensor/range/side",
                                         "--seconds", "1.5", "--connect", here)
    finally:
        running.cancel()
        token.undeclare()
        await bus.aclose()
    assert result.returncode == 0, result.stderr
    out = result.stdout
    line = next(line for line in out.splitlines() if line.startswith("publishers"))
    # Only the live one ("gone" has no liveliness token); the robot's own components that
    # publish nothing on the key are not named.
    assert re.fullmatch(r"publishers \(live components announcing it\): side "
                        r"\(insp/sensor/range/side\); (\d+) of the (\d+) live components "
                        r"announce no publisher .*", line), line
    heard = next(line for line in out.splitlines() if line.startswith("heard on"))
    assert heard.startswith("heard on ubf/insp/sensor/range/side: ")
    assert "from 2 publisher(s): " in heard
    assert f"side (pub {side.pub})" in heard
    assert f"pub {stray.pub}, announced by no live component" in heard
    assert "gone" not in out


@contextlib.asynccontextmanager
async def leds_heard(endpoint: str) -> AsyncIterator[list[int]]:
    """The masks of the LED commands heard on the robot, from a bus that has reached it."""
    bus = await Bus.open(ConnectionOptions(robot="insp", connect=[endpoint]))
    masks: list[int] = []
    try:
        bus.subscribe(LEDS.key(bus.keys), lambda k, p, t: masks.append(decode(p).data.mask),
                      latest=False)
        await eventually(lambda: bus.reached_peers(), what="the robot")
        yield masks
    finally:
        await bus.aclose()


@pytest.mark.asyncio
async def test_pub_refuses_what_the_robot_would_and_sends_what_it_takes(
        robot_endpoint: str) -> None:
    async with leds_heard(robot_endpoint) as masks:
        refused = await asyncio.to_thread(inspect, robot_endpoint, "pub", "cmd/drive",
                                          "{speed: 500, turn: 0}")
        assert refused.returncode == 2
        assert "refused, nothing sent" in refused.stderr and "data.speed" in refused.stderr
        assert "100" in refused.stderr  # the limit is named
        bad = await asyncio.to_thread(inspect, robot_endpoint, "pub", "cmd/leds", "{mask: 300}")
        assert bad.returncode == 2 and "data.mask" in bad.stderr
        unknown = await asyncio.to_thread(inspect, robot_endpoint, "pub", "cmd/leds",
                                          "{mask: 1, colour: red}")
        assert unknown.returncode == 2 and "colour" in unknown.stderr
        before = list(masks)
        sent = await asyncio.to_thread(inspect, robot_endpoint, "pub", "cmd/leds",
                                       '{"mask": 2}', "--count", "3", "--rate", "20")
        assert sent.returncode == 0, sent.stderr
        assert "sent 3 leds message(s) on ubf/insp/cmd/leds" in sent.stdout
        await eventually(lambda: masks.count(2) >= 3, what="the published commands")
        assert 300 not in masks and not [m for m in before if m == 2]


@pytest.mark.asyncio
async def test_pub_with_a_rate_publishes_until_stopped(robot_endpoint: str) -> None:
    async with leds_heard(robot_endpoint) as masks:
        pub = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "ubf_async.inspector", "--connect", robot_endpoint,
            "--robot", "insp", "pub", "cmd/leds", "{mask: 5}", "--rate", "20", cwd=ROOT,
            stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE)
        # No --count: it goes on (far past one message) until it is stopped.
        await eventually(lambda: masks.count(5) >= 10, timeout_s=30,
                         what="ten messages of one pub --rate")
        assert pub.returncode is None
        pub.send_signal(signal.SIGINT)  # Ctrl-C: the normal end of pub --rate
        out, err = await asyncio.wait_for(pub.communicate(), 30)
        assert pub.returncode == 0, err.decode()
        sent = re.fullmatch(r"sent (\d+) leds message\(s\) on ubf/insp/cmd/leds \(stopped\)\n",
                            out.decode())
        assert sent and int(sent.group(1)) >= 10, out.decode()
        await eventually(lambda: masks.count(5) == int(sent.group(1)),
                         what="every message it says it sent")


def test_pub_help_offers_no_key_expression() -> None:
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    text = sub.choices["pub"].format_help()
    assert "sensor/**" not in text and "not a key expression" in text
    assert "until Ctrl-C" in text and "ros2 topic pub -r" in text
    refused = subprocess.run([sys.executable, "-m", "ubf_async.inspector", "pub", "cmd/leds",
                              "{mask: 1}", "--count", "0", "--connect", "tcp/127.0.0.1:1",
                              "--timeout", "0.5"], cwd=ROOT, capture_output=True, text=True,
                             timeout=60)
    assert refused.returncode == 2


def test_state_and_tree_watch_refresh(robot_endpoint: str) -> None:
    state = inspect(robot_endpoint, "state", "--watch", "--count", "2", "--interval", "0.3")
    assert state.returncode == 0, state.stderr
    blocks = state.stdout.split("\n# ")
    assert len(blocks) == 2 and state.stdout.startswith("# ")
    assert all("drive: speed" in block and "last tick" in block for block in blocks)
    assert "\x1b" not in state.stdout  # not a terminal: plain blocks, no screen control
    tree = inspect(robot_endpoint, "tree", "show", "--watch", "--count", "2",
                   "--interval", "0.2")
    assert tree.returncode == 0, tree.stderr
    assert tree.stdout.count("tree version") == 2 and "seek_pink_ball" in tree.stdout
