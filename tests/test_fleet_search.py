"""The cooperative search (issue 16, item 4): the fleet behaviours as pure logic, the radio the
robots of one world share, odometry in the world's frame, and a search by two robots of one
world run in this process."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pytest

from components.sim.world.config import Arena, WorldConfig, WorldPose
from components.sim.world.physics import World
from ubf_async.assembly.context import DeviceContext
from ubf_async.assembly.devices import build_device
from ubf_async.assembly.robotfile import load_robot
from ubf_async.behaviors.ball_reports import GoToReport, ReportBall, format_report, parse_report
from ubf_async.core.state import State
from ubf_async.net.inprocess import InProcessTransport
from ubf_async.runs.fleet import run_fleet
from ubf_async.runtime.bus import Bus

ROOT = Path(__file__).resolve().parent.parent
S = 10**9


def seen(bins: list[int], *, x: float = 0.0, y: float = 0.0, heading_deg: float = 0.0,
         now_s: float = 0.0, **more: Any) -> State:
    return State.of(now_ns=round(now_s * S),
                    camera__front={"bins": bins, "total": sum(bins)},
                    odometry__wheels={"x_m": x, "y_m": y,
                                      "heading_rad": math.radians(heading_deg)}, **more)


def test_reports_are_plain_text_and_anything_else_is_ignored() -> None:
    assert format_report(1.234, -2.0) == "ball 1.23 -2.00"
    assert parse_report("ball 1.23 -2.00") == (1.23, -2.0)
    for other in ("hello", "ball 1", "ball x y", "ball nan 1", "ball 1e9 0", "ball 1 2 3"):
        assert parse_report(other) is None, other


def test_report_ball_says_where_the_ball_is_in_the_shared_frame() -> None:
    report = ReportBall(period_s=1.0)
    # 140 px dead ahead: the reference distance, 0.45 m, from (1, 2) heading +x.
    action = report.act(seen([0, 0, 140, 0, 0], x=1.0, y=2.0))
    assert action is not None and action.speed is None and action.turn is None
    assert parse_report(action.message or "") == pytest.approx((1.45, 2.0), abs=0.01)
    assert report.act(seen([0, 0, 140, 0, 0], x=1.0, y=2.0, now_s=0.5)) is None  # rate-limited
    # A quarter of the pixels: twice as far; all in the left bin: 14° to the left; heading 90°.
    action = report.act(seen([35, 0, 0, 0, 0], heading_deg=90.0, now_s=1.0))
    assert action is not None
    x, y = parse_report(action.message or "") or (0.0, 0.0)
    assert (x, y) == pytest.approx((-0.9 * math.sin(math.radians(14)),
                                    0.9 * math.cos(math.radians(14))), abs=0.01)
    assert report.act(seen([0, 0, 2, 0, 0], now_s=5.0)) is None  # too few pixels to trust
    assert report.act(State.of(camera__front={"bins": [0, 0, 140, 0, 0], "total": 140})) is None


def test_go_to_report_heads_for_the_reported_position() -> None:
    go = GoToReport(arrive_m=0.5, remember_s=10.0)
    nothing = [0, 0, 0, 0, 0]
    assert go.act(seen(nothing)) is None  # nothing heard yet
    ahead = go.act(seen(nothing, radio__link={"text": "ball 3.00 0.00"}))
    assert ahead is not None and (ahead.speed, ahead.turn) == (40.0, 0.0)
    # Facing +y with the target along +x: turn right on the spot (the report is remembered).
    right = go.act(seen(nothing, heading_deg=90.0, now_s=1.0))
    assert right is not None and (right.speed, right.turn) == (0.0, -60.0)
    slightly = go.act(seen(nothing, heading_deg=10.0, now_s=1.0))
    assert slightly is not None and slightly.speed == 40.0 and slightly.turn == -20.0
    assert go.act(seen([0, 0, 9, 0, 0], now_s=1.0)) is None  # it sees pink itself
    assert go.act(seen(nothing, x=2.6, now_s=1.0)) is None  # arrived
    assert go.act(seen(nothing, now_s=12.0)) is None  # forgotten after remember_s
    go.reset()
    assert go.target is None


@pytest.mark.asyncio
async def test_the_robots_of_one_world_share_the_air_and_one_frame() -> None:
    """radio.air: what one robot sends, the others receive, not itself; the encoders of a
    fleet's robot start from its pose in the world."""
    world = World(WorldConfig(arena=Arena(x_min_m=-2, x_max_m=2, y_min_m=-2, y_max_m=2),
                              more_robots=(WorldPose(x_m=1.0, y_m=0.5), WorldPose(x_m=-1.0))))
    robot = load_robot(str(ROOT / "examples" / "robots" / "fleet-whegs.yaml"))
    radio = next(d for d in robot.devices if d.kind == "radio")
    encoders = next(d for d in robot.devices if d.kind == "encoders")
    bus = Bus(transport=InProcessTransport(), robot="t")
    radios = [radio.backend_factory(context=DeviceContext(bus=bus, clock=bus.clock,
                                                          simulation=world.robot(i)))
              for i in range(3)]
    radios[1].send("ball 1.00 2.00")
    assert radios[0].receive() == ["ball 1.00 2.00"] == radios[2].receive()
    assert radios[1].receive() == [] and radios[0].receive() == []

    context = DeviceContext(bus=bus, clock=bus.clock, simulation=world.robot(1),
                            extras={"origin_x_m": 1.0, "origin_y_m": 0.5,
                                    "origin_heading_deg": 30.0})
    backend = encoders.backend_factory(context=context, **encoders.backend_params)
    component = build_device(encoders.factory, kind="encoders", name="wheels",
                             backend=backend, params=encoders.params, context=context)
    pose = component.odometry.pose  # type: ignore[attr-defined]
    assert (pose.x_m, pose.y_m, math.degrees(pose.heading_rad)) == pytest.approx((1, 0.5, 30))
    # A robot file that sets the origin keeps it.
    component = build_device(encoders.factory, kind="encoders", name="wheels", backend=backend,
                             params={**encoders.params, "origin_x_m": -3.0}, context=context)
    assert component.odometry.pose.x_m == -3.0  # type: ignore[attr-defined]


def test_a_search_by_two_robots_of_one_world(tmp_path: Path) -> None:
    """Two robots of examples/robots/fleet-whegs.yaml in the fleet-search room, world and
    controllers in this process (ubf_async.runs.fleet, flat out): the one in the middle sees the
    ball and says where; the one in the far corner, which cannot see it from there, heads for
    it and finds it too. (The fleet launcher's processes, its status lines and its line on the
    ball found: tests/test_fleet.py.)"""
    robot_file = ROOT / "examples" / "robots" / "fleet-whegs.yaml"
    fleet = tmp_path / "search.yaml"
    fleet.write_text(
        f"world: {{scenario: fleet-search, speed: 2, duration_s: 60}}\nrobots:\n"
        f"  - {{name: far, robot_file: {robot_file}, start: {{x_m: -2.5, y_m: -2.5, "
        f"heading_deg: 45}}}}\n"
        f"  - {{name: mid, robot_file: {robot_file}, start: {{x_m: 0.0, y_m: 0.0, "
        f"heading_deg: -90}}}}\n")
    result = run_fleet(fleet)
    far, mid = result["robots"]["far"], result["robots"]["mid"]
    assert "report_ball" in mid["controller"]["winner_share"]  # it told the other
    assert far["controller"]["winner_share"].get("go_to_report", 0) > 0.1, far  # which went
    assert mid["found_s"] is not None and far["found_s"] is not None, result
    assert mid["found_s"] < far["found_s"] == result["all_found_s"]
    assert result["first_found_s"] == mid["found_s"]
