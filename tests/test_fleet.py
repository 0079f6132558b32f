"""A fleet in one simulated world (issue 16, item 2): robots that see and bump into each
other, fleet files, and four robots whose controllers run in their own processes over a router
— real processes, real zenoh on loopback, the real simulator."""

from __future__ import annotations

import asyncio
import json
import math
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from components.range.backend import MountPose
from components.sim.render.camera import render_camera
from components.sim.world.config import Arena, WorldConfig, WorldPose
from components.sim.world.physics import ROBOT_COLOR, World
from components.sim.world.ranging import beam_distance_m
from tests.conftest import eventually, free_port, read_until, repository_env, spawn, stop
from ubf_async.errors import ConfigurationError
from ubf_async.net.options import ConnectionOptions
from ubf_async.runs.fleet import load_fleet
from ubf_async.runtime.bus import Bus
from ubf_async.wire.protocol import decode
from ubf_async.wire.topics import DRIVE, MOTORS

ROOT = Path(__file__).resolve().parent.parent
ARENA = Arena(x_min_m=-2, x_max_m=2, y_min_m=-2, y_max_m=2)


def two_robots(gap_m: float = 0.5) -> World:
    """Robot 0 at the origin facing +x, robot 1 ``gap_m`` ahead facing it."""
    return World(WorldConfig(arena=ARENA, more_robots=(
        WorldPose(x_m=gap_m, y_m=0.0, heading_rad=math.pi),)))


def test_robots_see_each_other_in_ir_and_camera() -> None:
    world = two_robots(0.5)
    ahead = MountPose(x_m=0.05, y_m=0.0, yaw_rad=0.0)
    # Robot 1's shell is 0.5 m − its half length (5 cm) ahead of the centre; the sensor sits
    # 5 cm forward: 0.40 m to robot 1's face. Robot 1 sees robot 0 the same way.
    assert beam_distance_m(world.snapshot_for(0), ahead, 1.5) == pytest.approx(0.40, abs=1e-3)
    assert beam_distance_m(world.snapshot_for(1), ahead, 1.5) == pytest.approx(0.40, abs=1e-3)
    alone = World(WorldConfig(arena=ARENA))
    assert beam_distance_m(alone.snapshot_for(0), ahead, 1.5) is None  # nothing there alone

    def dark_pixels(snapshot: object) -> int:
        frame = render_camera(snapshot, grid=8)  # type: ignore[arg-type]
        close = np.abs(frame.astype(int) - np.array(ROBOT_COLOR)).max(axis=2) < 40
        return int(close.sum())

    # The other robot is a dark box in the middle of the picture; alone, nothing is.
    assert dark_pixels(world.snapshot_for(0)) > 20 * dark_pixels(alone.snapshot_for(0)) + 20
    assert world.snapshot_for(0).robot.x_m == 0.0 and world.snapshot_for(1).robot.x_m == 0.5


def test_robots_bump_into_each_other_and_each_drives_its_own_wheels() -> None:
    world = two_robots(0.3)
    world.set_motor_pulses(1.943, 2.0, robot=0)  # robot 0 full ahead: speed 100, turn 0
    for _ in range(600):  # 3 s
        world.advance(0.005)
    me, other = world.snapshot_for(0).robot, world.snapshot_for(1).robot
    assert other.x_m > 0.3 + 0.2, "robot 1 was pushed back"
    assert other.x_m - me.x_m >= 0.099, "the shells do not pass through each other"
    assert (other.left_pulse_ms, other.right_pulse_ms) == world.robot(1).motor_pulses
    assert other.left_wheel_speed_rad_s == 0.0 and other.right_wheel_speed_rad_s == 0.0
    with pytest.raises(IndexError):
        world.robot(2)


def write(path: Path, text: str) -> Path:
    path.write_text(text, encoding="utf-8")
    return path


@pytest.mark.parametrize(("text", "message"), [
    ("robots: []", "length >= 1"),
    ("robots: [{name: a, start: {x_m: 0, y_m: 0}}, {name: a, start: {x_m: 1, y_m: 0}}]",
     "unique; twice: a"),
    ("robots: [{name: a, start: {x_m: 0, y_m: 0}, colour: red}]", "unknown field `colour`"),
    ("robots: [{name: 'a/b', start: {x_m: 0, y_m: 0}}]", "robot 'a/b'"),
    ("robots: [{name: a, robot_file: nowhere.yaml, start: {x_m: 0, y_m: 0}}]", "nowhere"),
])
def test_fleet_files_with_mistakes_are_refused_clearly(tmp_path: Path, text: str,
                                                       message: str) -> None:
    with pytest.raises(ConfigurationError, match=message.replace("(", r"\(")):
        load_fleet(write(tmp_path / "fleet.yaml", text))


@pytest.mark.asyncio
async def test_robots_placed_on_each_other_or_outside_the_arena_are_refused(
    tmp_path: Path,
) -> None:
    from components.sim.runner.fleet_world import fleet_world_config
    from components.sim.scenarios.scenario import load_scenario
    from ubf_async.assembly.simulation import FleetMember
    from ubf_async.errors import ScenarioError

    base = load_scenario("ball-in-sight").world

    def member(name: str, x: float, y: float) -> FleetMember:
        return FleetMember(name=name, devices=(), x_m=x, y_m=y)

    with pytest.raises(ScenarioError, match=r"robots a and b start 0\.050 m apart"):
        fleet_world_config(base, [member("a", 0, 0), member("b", 0.05, 0)], seed=None)
    with pytest.raises(ScenarioError, match=r"robot far: .* does not fit inside the arena"):
        fleet_world_config(base, [member("a", 0, 0), member("far", 50, 0)], seed=None)
    config = fleet_world_config(base, [member("a", 0, 0), member("b", -0.4, 0.5)], seed=7)
    assert config.seed == 7 and len(config.more_robots) == 1


FOUR_ROBOTS = """
world: {{scenario: ball-in-sight, speed: 1}}
router: {router}
robots:
  - {{name: {p}1, start: {{x_m: 0.0, y_m: 0.0, heading_deg: 0}}}}
  - {{name: {p}2, start: {{x_m: -0.4, y_m: 0.5, heading_deg: -45}}}}
  - {{name: {p}3, start: {{x_m: -0.4, y_m: -0.5, heading_deg: 45}}}}
  - {{name: {p}4, start: {{x_m: -0.8, y_m: 0.0, heading_deg: 180}}}}
"""


@pytest.mark.asyncio
async def test_four_robots_each_controller_in_its_own_process(tmp_path: Path) -> None:
    """Router, world and four controllers, each its own process: all tick, each robot's
    commands reach only its own motors, and killing one controller stops only its wheels."""
    router = f"tcp/127.0.0.1:{free_port()}"
    prefix = f"q{free_port()}r"
    names = [f"{prefix}{i}" for i in range(1, 5)]
    fleet = write(tmp_path / "fleet.yaml", FOUR_ROBOTS.format(router=router, p=prefix))
    procs: dict[str, asyncio.subprocess.Process] = {}
    tool: Bus | None = None
    try:
        procs["router"] = await spawn("-m", "ubf_async.router", "--listen", router, "--quiet")
        await read_until(procs["router"], "join with")
        for name in names:
            procs[name] = await spawn("-m", "ubf_async.launch", "--no-sim", "--sim-time",
                                      "--robot", name, "--mode", "client", "--connect", router,
                                      "--quiet")
        for name in names:
            await read_until(procs[name], "controller:")
        # Real time: the controllers follow the world without lockstep (one is killed below).
        procs["world"] = await spawn("-m", "ubf_async.fleet", str(fleet), "--world-only",
                                     "--no-lockstep")
        await read_until(procs["world"], "with 4 robots")

        tool = await Bus.open(ConnectionOptions(mode="client", connect=[router]))
        drives: dict[str, list[tuple[float, float]]] = {n: [] for n in names}
        applied: dict[str, list[tuple[float, float, str | None]]] = {n: [] for n in names}

        def on_drive(key: str, payload: bytes, received_ns: int) -> None:
            data = decode(payload, topic=DRIVE).data
            drives[key.split("/")[1]].append((data.speed, data.turn))

        def on_applied(key: str, payload: bytes, received_ns: int) -> None:
            data = decode(payload, topic=MOTORS).data
            applied[key.split("/")[1]].append((data.speed, data.turn, data.reason))

        tool.subscribe("ubf/*/cmd/drive", on_drive, latest=False)
        tool.subscribe("ubf/*/sensor/motors/*", on_applied, latest=False)
        # All tick and drive; the robot facing the ball chases it, the others search.
        await eventually(lambda: all(len(drives[n]) > 50 and len(applied[n]) > 50
                                     for n in names), timeout_s=30,
                         what="every robot's commands and its motors' applied samples")

        def applied_matches_own_commands(name: str) -> bool:
            own = set(drives[name])
            recent = [a for a in applied[name][-20:] if a[2] == "command"]
            return bool(recent) and all((s, t) in own for s, t, _ in recent)

        await eventually(lambda: all(applied_matches_own_commands(n) for n in names),
                         timeout_s=10, what="each robot's motors applying its own commands")
        # No cross-talk: a searching robot's motors never applied the chaser's commands.
        searching = {n for n in names if drives[n][-1][0] == 0.0}
        chasing = set(names) - searching
        assert searching and chasing, drives
        chase_commands = {d for n in chasing for d in drives[n] if d[0] != 0.0}
        for n in searching:
            assert not {(s, t) for s, t, _ in applied[n]} & chase_commands

        # Kill one robot's controller: its wheels stop on their watchdog, the others go on.
        victim, others = names[1], [n for n in names if n != names[1]]
        procs[victim].kill()
        await procs[victim].wait()
        await eventually(lambda: applied[victim][-1][2] == "timeout", timeout_s=5,
                         what="the killed robot's motors to stop on their watchdog")
        assert applied[victim][-1][:2] == (0.0, 0.0)
        counts = {n: len(applied[n]) for n in others}
        await eventually(lambda: all(len(applied[n]) > counts[n] + 20 for n in others),
                         timeout_s=10, what="the other robots' motors to go on")
        for n in others:
            assert all(reason != "timeout" for _, _, reason in applied[n][-20:]), n

        # The router restarts: the world, the controllers and this tool are all back within
        # 2 s of it listening again (every session retries at most 1 s apart).
        await stop(procs["router"])
        await asyncio.sleep(1.0)  # the outage itself, not a wait for anything
        procs["router"] = await spawn("-m", "ubf_async.router", "--listen", router, "--quiet")
        await read_until(procs["router"], "join with")
        up_at = time.monotonic()
        sent = {n: len(drives[n]) for n in others}
        done = {n: len(applied[n]) for n in others}
        await eventually(lambda: all(len(drives[n]) > sent[n] and len(applied[n]) > done[n]
                                     for n in others), timeout_s=10,
                         what="every robot's commands through the restarted router")
        assert time.monotonic() - up_at <= 2.0 + 0.1  # + this check's own polling
    finally:
        if tool is not None:
            await tool.aclose()
        for proc in procs.values():
            await stop(proc)


LAUNCHED = """
world: {{scenario: ball-in-sight, speed: {speed}, duration_s: 4}}
router: {router}
robots:
  - {{name: f1, start: {{x_m: 0.0, y_m: 0.0, heading_deg: 0}}}}
  - {{name: f2, start: {{x_m: -0.4, y_m: 0.5, heading_deg: -45}}}}
  - {{name: f3, start: {{x_m: -0.4, y_m: -0.5, heading_deg: 45}}}}
  - {{name: f4, start: {{x_m: -0.8, y_m: 0.0, heading_deg: 180}}}}
"""


def launch_fleet(folder: Path, *, speed: str, per_process: int) -> tuple[dict[str, Any], str]:
    """``python -m ubf_async.fleet`` on :data:`LAUNCHED` (router, world, the controllers
    ``per_process`` to a process, in lockstep by default): its summary and its output."""
    folder.mkdir()
    fleet = write(folder / "fleet.yaml", LAUNCHED.format(
        speed=speed, router=f"tcp/127.0.0.1:{free_port()}"))
    summary = folder / "summary.json"
    done = subprocess.run(
        [sys.executable, "-m", "ubf_async.fleet", str(fleet), "--summary", str(summary),
         "--log-dir", str(folder / "logs"), "--status-period-s", "0.2",
         "--controllers-per-process", str(per_process)],
        cwd=ROOT, env=repository_env(), capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stdout + done.stderr
    result: dict[str, Any] = json.loads(summary.read_text())
    return result, done.stdout


def test_the_fleet_launcher_runs_a_fleet_and_summarises_it(tmp_path: Path) -> None:
    """Router, world and the four robots' controllers in processes of their own, in lockstep:
    at --speed 2 with a process per controller, and flat out with two controllers to a process
    — each prints the fleet's status lines, the ball found, and a summary per robot (every
    periodic tick 20 ms apart in simulated time: jitter 0), and it is the same run twice (the
    real-time factor aside). (The same fleet's run in one process, twice, idle and beside a
    busy loop on every core: tests/test_lockstep.py; the lockstep across processes beside a
    busy loop: its remote behaviour's test.)"""
    paced, paced_out = launch_fleet(tmp_path / "paced", speed="2", per_process=1)
    flat_out, flat_out_out = launch_fleet(tmp_path / "flat-out", speed="max", per_process=2)
    for result, out, processes in ((paced, paced_out, ["f1", "f2", "f3", "f4"]),
                                   (flat_out, flat_out_out, ["f1+f2", "f3+f4"])):
        assert "fleet t=" in out, out
        assert all(f"| f{i} " in out for i in range(1, 5)), out
        assert "the ball: first found at 0.1 s (simulated)" in out, out  # f1 faces it
        # Where the summary went is said, as launch says it.
        assert out.rstrip().endswith(f"  summary written to {Path(result['fleet']).parent}"
                                     f"/summary.json"), out
        assert result["lockstep"] is True
        assert result["sim_time_s"] == pytest.approx(4.0, abs=0.01)
        assert result["scenario"] == "ball-in-sight"
        assert result.pop("real_time_factor") > 0
        for name, robot in result["robots"].items():
            assert robot["ticks"] > 100, (name, robot)
            assert robot["periodic_rate_hz"] == pytest.approx(50.0), (name, robot)
            assert robot["periodic_jitter_robot_ms_p99"] == 0.0, (name, robot)
            assert robot["overruns"] == 0, (name, robot)
            assert robot["travelled_m"] >= 0.0 and "end" in robot
        assert "chase" in result["robots"]["f1"]["winner_share"]  # f1 faces the ball
        assert "search" in result["robots"]["f2"]["winner_share"]
        folder = Path(result.pop("fleet")).parent
        for log in ("router", "world", *processes):
            assert (folder / "logs" / f"{log}.log").is_file(), log
    assert flat_out == paced


@pytest.mark.parametrize("path", sorted((ROOT / "examples" / "fleets").glob("*.yaml")),
                         ids=lambda p: p.name)
def test_the_shipped_fleet_files_load(path: Path) -> None:
    fleet = load_fleet(path)
    assert fleet.simulator == "mini-whegs" and len(fleet.robots) >= 2
    for robot in fleet.robots.values():
        assert Path(robot.source).is_file() or robot.source == "mini-whegs"


def test_the_launcher_seeds_each_controller_with_the_world_seed(tmp_path: Path) -> None:
    """The behaviours of a launched fleet draw from the fleet file's world seed, as those of
    run_fleet do; without one, from their robot file's seed (launch's default)."""
    from ubf_async.tools.fleet import controller_arguments

    robots = "robots: [{name: r1, start: {x_m: 0.0, y_m: 0.0}}]\n"
    seeded = load_fleet(write(tmp_path / "seeded.yaml", "world: {seed: 42}\n" + robots))
    unseeded = load_fleet(write(tmp_path / "unseeded.yaml", robots))
    words = controller_arguments(seeded, "r1", router="tcp/127.0.0.1:7447", lockstep=True)
    assert words[words.index("--seed") + 1] == "42" and "--lockstep" in words
    assert "--seed" not in controller_arguments(unseeded, "r1", router="tcp/127.0.0.1:7447",
                                                lockstep=False)
