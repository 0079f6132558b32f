"""The launch status line: fitted to the terminal's width (80 and 200 columns) with the
important fields first, tick rates labelled by what ran them, redrawn in place on a terminal
and one plain line per period otherwise."""

from __future__ import annotations

import fcntl
import io
import json
import os
import pty
import re
import select
import struct
import subprocess
import sys
import termios
import time
from pathlib import Path

import pytest

from tests.cli_inprocess import launch_main
from tests.test_inprocess_units import RANGE_PERIOD_S, Rig, tree
from ubf_async.clocks.clock import SimClock, WallClock
from ubf_async.runtime.aggregator import StateAggregator
from ubf_async.runtime.controller import Controller, TickMode
from ubf_async.services.status import CLOCK_SILENT_S, fit, followed_clock, tick_label
from ubf_async.tools.launch import parse_args, plan_launch, print_plan

ROOT = Path(__file__).resolve().parent.parent
FIELDS = ["[mini] 12.3s", "drive +40/+30 (chase,flee)", "tick 50.0Hz +reflex 24.9Hz",
          "sim 12.3s x1.00", "camera/front 130ms", "encoders/wheels 10ms",
          "leds/panel ●○ 230ms", "motors/main 10ms", "odometry/wheels 10ms",
          "range/front 30ms", "range/left 12ms STALE"]


@pytest.mark.parametrize("width", [80, 200])
def test_fit_keeps_every_line_within_the_width_and_the_important_fields_first(
        width: int) -> None:
    lines = fit(FIELDS, width)
    assert 1 <= len(lines) <= 2
    assert all(len(line) <= width for line in lines)
    assert lines[0].startswith("[mini] 12.3s | drive +40/+30 (chase,flee) | tick 50.0Hz")
    shown = " | ".join(lines)
    assert "sim 12.3s x1.00" in shown  # the real-time factor is never pushed out
    more = re.search(r"\+(\d+) more", shown)
    left = int(more.group(1)) if more else 0
    assert sum(f in shown for f in FIELDS) + left == len(FIELDS)  # every field accounted for
    if width == 200:
        assert left == 0 and len(lines) == 2  # all of it, wrapped to a second line
    else:
        assert left > 0  # what does not fit in two lines is counted, not run off the edge


def test_a_followed_clock_that_fell_silent_is_said_so() -> None:
    """A controller following a replay's clock (launch --no-sim --sim-time): its status line
    shows the followed time, and once the replay has ended — its clock silent — says so,
    instead of going on as if nothing had happened."""
    clock = SimClock(0)
    clock.advance_to(4_000_000_000)
    now = time.monotonic_ns()
    assert followed_clock(clock, wall_now_ns=now) == "sim 4.0s"
    later = now + round((CLOCK_SILENT_S + 1.0) * 1e9)
    assert followed_clock(clock, wall_now_ns=later) == (
        f"sim 4.0s CLOCK SILENT {CLOCK_SILENT_S + 1.0:.0f}s (its replay or simulator ended?)")
    assert followed_clock(WallClock()) == ""


def test_fit_cuts_a_field_longer_than_a_line() -> None:
    lines = fit(["x" * 300, "drive +0/+0 (stop)"], 80)
    assert lines == ["x" * 79 + "…", "drive +0/+0 (stop)"]


@pytest.mark.asyncio
async def test_tick_rates_are_labelled_by_what_ran_them() -> None:
    rig = Rig()
    agg = StateAggregator(bus=rig.robot)
    periodic = Controller(bus=rig.robot, aggregator=agg, root=tree(), rate_hz=10,
                          reflex_sources=("range/",))
    await rig.start(agg, periodic)
    for step in range(30):  # 3 s: ticks at 10 Hz, IR samples at 5 Hz
        if step % 2 == 0:
            await rig.publish_range(400)
        await rig.advance_s(0.1)
    label = tick_label(periodic)
    match = re.fullmatch(r"tick (\S+)Hz \+reflex (\S+)Hz", label)
    assert match, label
    assert float(match.group(1)) == pytest.approx(10, abs=0.5)
    assert float(match.group(2)) == pytest.approx(5, abs=0.5)
    await rig.close()
    rig = Rig()
    agg = StateAggregator(bus=rig.robot)
    sync = Controller(bus=rig.robot, aggregator=agg, root=tree(), mode=TickMode.SYNC,
                      sync_source="range/front")
    await rig.start(agg, sync)
    for _ in range(int(3 / RANGE_PERIOD_S)):
        await rig.publish_range(400)
        await rig.advance_s(RANGE_PERIOD_S)
    label = tick_label(sync)
    assert label.startswith("sync ") and label.endswith("(range/front)"), label
    assert float(label.split()[1].removesuffix("Hz")) == pytest.approx(5, abs=0.5)
    await rig.close()


def visible_lines(raw: str) -> list[str]:
    """What a terminal shows line by line, escape sequences and carriage returns resolved
    to their effect on line length (each \\r starts the line over)."""
    text = re.sub(r"\x1b\[[0-9;]*[A-Za-z]", "\n", raw)
    return [part for line in text.split("\n") for part in line.split("\r")]


def test_on_an_80_column_terminal_no_line_is_longer_than_the_terminal() -> None:
    leader, follower = pty.openpty()
    fcntl.ioctl(follower, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 80, 0, 0))
    proc = subprocess.Popen(
        [sys.executable, "-m", "ubf_async.launch", "--duration", "3", "--speed", "2",
         "--status-period-s", "0.2", "--listen", "tcp/127.0.0.1:0"],
        cwd=ROOT, stdin=follower, stdout=follower, stderr=follower,
        env={**os.environ, "PYTHONUNBUFFERED": "1", "COLUMNS": "80"})
    os.close(follower)
    raw = b""
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        ready, _, _ = select.select([leader], [], [], 1.0)
        if ready:
            try:
                chunk = os.read(leader, 65536)
            except OSError:  # the child closed the terminal
                break
            if not chunk:
                break
            raw += chunk
        elif proc.poll() is not None:
            break
    os.close(leader)
    assert proc.wait(timeout=30) == 0
    text = raw.decode(errors="replace")
    status = [line for line in visible_lines(text) if line.startswith("[mini]")]
    assert len(status) >= 5  # redrawn every 0.2 s
    assert all(len(line) <= 80 for line in status), max(status, key=len)
    assert all("drive " in line and "tick " in line for line in status if "0.0s" not in line)


def test_without_a_terminal_each_period_is_one_plain_line(tmp_path: Path) -> None:
    summary = tmp_path / "summary.json"
    result = subprocess.run(
        [sys.executable, "-m", "ubf_async.launch", "--duration", "2", "--speed", "2",
         "--status-period-s", "0.25", "--listen", "tcp/127.0.0.1:0", "--summary",
         str(summary)], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    status = [line for line in result.stdout.splitlines() if line.startswith("[mini]")]
    # A line every 0.25 s of wall time: ≈ 4 in the 1 s that 2 simulated seconds take at 2×,
    # more on a machine too busy to keep up (the run then takes longer), never one a tick.
    wall_s = json.loads(summary.read_text())["wall_time_s"]
    assert 3 <= len(status) <= wall_s / 0.25 + 2, (len(status), wall_s)
    assert "\r" not in result.stdout and "\x1b" not in result.stdout
    assert all(" | tick 50.0Hz +reflex " in line or "tick --" in line for line in status)


def test_the_plan_and_the_inspector_use_the_status_lines_labels(
        capfd: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    from ubf_async.services.status import planned_ticks
    from ubf_async.tools.inspector.state import format_state

    # launch --check (its main, here): a sync controller does not tick at the clock's rate,
    # nor take reflexes.
    check = launch_main(["--check", "--tick", "sync"], capfd, monkeypatch)
    assert check.returncode == 0, check.stderr
    (line,) = [line for line in check.stdout.splitlines() if "controller:" in line]
    assert line.strip() == ("controller: sync on each camera/front sample (the thesis's loop; "
                            "between ticks the decision is re-sent at 50 Hz)")
    assert "reflex" not in line
    assert planned_ticks(TickMode.PERIODIC, rate_hz=50, reflex=("range/",)) == \
        "periodic tick 50Hz +reflex on each range/ sample"
    assert planned_ticks(TickMode.PERIODIC, rate_hz=20) == "periodic tick 20Hz (no reflex)"
    # Only the reflexes of sources the robot has (issue 35: "+reflex on each range/ sample"
    # on a robot without a range finder).
    assert planned_ticks(TickMode.PERIODIC, rate_hz=50, reflex=("range/", "bump/"),
                         sources=["camera/front", "range/front"]) == \
        "periodic tick 50Hz +reflex on each range/ sample"
    assert planned_ticks(TickMode.PERIODIC, rate_hz=50, reflex=("range/",),
                         sources=["camera/front"]) == "periodic tick 50Hz (no reflex source)"
    without_range = io.StringIO()
    print_plan(plan_launch(parse_args(["--devices", "camera,motors"])), without_range)
    assert "  controller: periodic tick 50Hz (no reflex source)\n" in without_range.getvalue()
    # inspector state: the clock's ticks apart from the reflex ticks, as the status line.
    periodic = format_state({"mode": "periodic", "rate_hz": 75.0, "periodic_rate_hz": 50.0,
                             "rate_hz_target": 50}, robot="r", controller="controller",
                            status_age_s=None).splitlines()[0]
    assert "periodic mode, tick 50.0Hz +reflex 25.0Hz (clock target 50Hz)," in periodic
    assert "75.0" not in periodic  # the reflex ticks are not passed off as the clock's
    sync = format_state({"mode": "sync", "rate_hz": 9.1, "periodic_rate_hz": None,
                         "rate_hz_target": None}, robot="r", controller="controller",
                        status_age_s=None).splitlines()[0]
    assert "sync mode, sync 9.1Hz," in sync and "target" not in sync and "50Hz" not in sync
