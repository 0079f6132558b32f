"""Bodies, mounts and lenses as data (issue 49, items 1–3).

* The body a robot file declares is what the simulator, the odometry, the PWM mapping and the
  encoders read; without one, the thesis's Mini-WHEGS, number for number (its runs are pinned
  by tests/test_golden_runs.py).
* Bad bodies and mounts are refused at ``FILE:LINE`` before anything runs.
* Cameras have mounts and lenses; several cameras on one robot render in lockstep, the run
  byte-identical when repeated.
* The shipped Pioneer runs the Mini-WHEGS's behaviour classes, passes its four scaled thesis
  scenarios, and what its file changes is listed in docs/bodies.md.
"""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from components.camera.backend import CameraMount
from components.camera.seekcolor import seekcolor
from components.miniwhegs import MINI_WHEGS, MiniWhegsGeometry
from components.motors.pwm import (
    DEFAULT_LEFT_CALIBRATION,
    DEFAULT_RIGHT_CALIBRATION,
    body_calibrations,
)
from components.sim.backends.devices import SimCameraBackend
from components.sim.world.config import BallConfig, RobotConfig, WorldConfig
from components.sim.world.physics import World
from tests.conftest import REPOSITORY
from tests.shared_runs import DEFAULT_ROBOT
from ubf_async import experiment
from ubf_async.assembly.body import DEFAULT_BODY, BodySpec
from ubf_async.assembly.robotfile import Robot, load_robot, load_robot_text
from ubf_async.core.behavior import Behavior, Composite
from ubf_async.errors import RobotFileError

PIONEER = REPOSITORY / "examples" / "robots" / "pioneer.yaml"
PIONEER_SCENARIOS = REPOSITORY / "examples" / "scenarios" / "pioneer"
BODIES_DOC = REPOSITORY / "docs" / "bodies.md"


# -- one source of truth ----------------------------------------------------------------------

def test_the_default_body_is_the_mini_whegs_number_for_number() -> None:
    assert MiniWhegsGeometry.of(DEFAULT_BODY) == MINI_WHEGS
    assert RobotConfig.from_body(DEFAULT_BODY) == RobotConfig()
    assert body_calibrations(DEFAULT_BODY) == (DEFAULT_LEFT_CALIBRATION,
                                               DEFAULT_RIGHT_CALIBRATION)
    assert load_robot("mini-whegs").body == DEFAULT_BODY  # no `body:`: the thesis's robot


def test_a_declared_body_reaches_the_world_the_odometry_and_the_motors() -> None:
    robot = load_robot(PIONEER)
    config = RobotConfig.from_body(robot.body, camera_x_m=robot.mount_x_m("camera"))
    assert config.geometry.length_m == 0.45 and config.geometry.edges_per_rev == 2000
    assert config.drive == "differential" and config.camera_x_m == 0.20
    # Two wheels share what the caster does not carry (lever rule about the centre).
    contacts = config.wheel_contacts(100.0)
    assert [c[:3] for c in contacts] == [(0.03, 0.165, 0), (0.03, -0.165, 1)]
    assert sum(c[3] for c in contacts) == pytest.approx(100.0 * 0.19 / 0.22)
    assert robot.body.odometry_track_m == 0.33  # null: the physical track
    assert robot.body.top_speed_m_s == pytest.approx(0.70, abs=0.01)
    left, _ = body_calibrations(robot.body)
    assert left != DEFAULT_LEFT_CALIBRATION


def test_a_differential_body_drives_at_its_top_speed_and_turns_without_skidding() -> None:
    body = load_robot(PIONEER).body
    world = World(WorldConfig(robot=RobotConfig.from_body(body)))
    world.set_motor_pulses(2.0, 2.0)  # full forward on both
    for _ in range(300):
        world.advance(0.01)
    speed = math.hypot(world.snapshot().robot.vx_m_s, world.snapshot().robot.vy_m_s)
    assert speed == pytest.approx(7.2 * 0.0975, rel=0.05)  # the slower motor's pace, ±5 %
    assert RobotConfig.from_body(body).yaw_fraction == 1.0


# -- refused at FILE:LINE ---------------------------------------------------------------------

MINI_TEXT = DEFAULT_ROBOT.read_text(encoding="utf-8")


def with_body(body: str) -> str:
    """The shipped Mini-WHEGS file with a ``body:`` section (its lines after line 3)."""
    return MINI_TEXT.replace("\ndevices:\n", f"\n{body}\ndevices:\n", 1)


def line_of(text: str, needle: str, nth: int = 1) -> int:
    lines = [i for i, line in enumerate(text.splitlines(), 1) if needle in line]
    return lines[nth - 1]


BAD: dict[str, tuple[str, str | tuple[str, int], str]] = {
    "a range finder's mount outside the footprint": (
        MINI_TEXT.replace("x_m: 0.05, y_m: 0.0, yaw_deg: 0.0", "x_m: 0.2, y_m: 0.0, yaw_deg: 0.0"),
        "model: ir-10-80", "outside the body's footprint"),
    "a camera's mount outside the footprint": (
        MINI_TEXT.replace("params: {latency_s: 0.11}", "params: {latency_s: 0.11,\n"
                          "             y_m: 0.1}"),
        "y_m: 0.1}", "outside the body's footprint"),
    "a lens of 0°": (
        MINI_TEXT.replace("params: {latency_s: 0.11}", "params: {latency_s: 0.11,\n"
                          "             hfov_deg: 0}"),
        "hfov_deg: 0", "hfov_deg"),
    "a lens of 200°": (
        MINI_TEXT.replace("params: {latency_s: 0.11}", "params: {latency_s: 0.11,\n"
                          "             hfov_deg: 200}"),
        "hfov_deg: 200", "hfov_deg"),
    "two devices with one key": (
        MINI_TEXT.replace("  - kind: radio\n    name: link\n",
                          "  - kind: camera\n    name: front\n    backend: sim\n"
                          "  - kind: radio\n    name: link\n"),
        ("kind: camera", 2), "duplicate device camera/front"),
    "a track wider than the body": (
        with_body("body:\n  width_m: 0.05\n  track_m: 0.06\n"), "track_m: 0.06",
        "wider than the body"),
    "a differential drive without its caster": (
        with_body("body:\n  drive: differential\n"), "drive: differential", "caster_x_m"),
    "a caster on the axle's side": (
        with_body("body:\n  drive: differential\n  axle_x_m: 0.02\n  caster_x_m: 0.04\n"),
        "caster_x_m: 0.04", "tips over"),
    "a dead zone outside the pulses": (
        with_body("body:\n  motors:\n    left: {max_wheel_speed_rad_s: 5, "
                  "dead_zone_ms: [1.6, 1.7]}\n"), "left: {max", "dead zone"),
    "a body of no mass": (with_body("body:\n  mass_kg: 0\n"), "mass_kg: 0", "mass_kg"),
    "an unknown body field": (with_body("body:\n  wheels: 6\n"), "wheels: 6",
                              "`body` takes: length_m"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_a_bad_body_or_mount_is_refused_at_its_line(case: str) -> None:
    text, needle, says = BAD[case]
    where = line_of(text, *needle) if isinstance(needle, tuple) else line_of(text, needle)
    with pytest.raises(RobotFileError) as refused:
        load_robot_text(text, source="bad.yaml")
    assert str(refused.value).startswith(f"bad.yaml:{where}: "), str(refused.value)
    assert says in str(refused.value)


def test_a_mount_on_the_footprints_edge_is_on_the_body() -> None:
    robot = load_robot_text(MINI_TEXT.replace("x_m: 0.05, y_m: 0.0,", "x_m: 0.05, y_m: 0.035,"))
    assert robot.devices  # the Mini-WHEGS's IR sits on its front edge, as the thesis's does


# -- cameras: mounts, lenses, several -----------------------------------------------------------

def pink_total(mount: CameraMount, ball: tuple[float, float]) -> int:
    world = World(WorldConfig(ball=BallConfig(x_m=ball[0], y_m=ball[1])))
    camera = SimCameraBackend(world, grid=8)
    camera.mount(mount)
    return seekcolor(camera.capture()).total


def test_a_camera_renders_from_its_mount_through_its_lens() -> None:
    beside = (0.05, 0.5)  # half a metre to the robot's left
    assert pink_total(CameraMount(), beside) == 0
    assert pink_total(CameraMount(name="left", yaw_deg=90), beside) > 0
    ahead = (0.55, 0.0)
    narrow, wide = pink_total(CameraMount(), ahead), pink_total(CameraMount(hfov_deg=90), ahead)
    assert narrow > 4 * wide > 0  # the same ball, smaller through the wider lens
    small = SimCameraBackend(World(WorldConfig(ball=BallConfig(x_m=0.55, y_m=0.0))))
    small.mount(CameraMount(width_px=640, height_px=480))
    assert small.capture().shape == (480, 640, 3)


TWO_CAMERAS = MINI_TEXT.replace(
    "  - kind: camera\n    name: front\n    backend: sim\n    params: {latency_s: 0.11}",
    "  - kind: camera\n    name: front\n    backend: sim\n    params: {latency_s: 0.11}\n"
    "  - kind: camera\n    name: left\n    backend: sim\n"
    "    params: {latency_s: 0.11, yaw_deg: 30, y_m: 0.02}")


def test_two_cameras_of_one_robot_render_in_lockstep_and_repeat_byte_for_byte(
        tmp_path: Path) -> None:
    robot = load_robot_text(TWO_CAMERAS, source="two-cameras.yaml")
    assert [d.name for d in robot.devices if d.kind == "camera"] == ["front", "left"]
    runs = [experiment.run(robot, "ball-in-sight", duration_s=3.0, out_dir=tmp_path / str(i))
            for i in range(2)]
    one_camera = experiment.run("mini-whegs", "ball-in-sight", duration_s=3.0)
    # Both cameras, each a frame every 0.11 s of simulated time: twice the one camera's.
    assert runs[0].summary["camera_frames"] == 2 * one_camera.summary["camera_frames"] > 0
    first, again = ((tmp_path / str(i) / "trajectory.csv").read_bytes() for i in range(2))
    assert first == again


# -- the Pioneer ------------------------------------------------------------------------------

def leaves(node: Behavior) -> list[Behavior]:
    if isinstance(node, Composite):
        return [leaf for child in node.children for leaf in leaves(child.behavior)]
    return [node]


def shape(robot: Robot) -> list[tuple[str, type]]:
    return [(leaf.name, type(leaf)) for leaf in leaves(robot.root)]


def test_both_shipped_robots_run_the_same_behaviour_classes() -> None:
    mini, pioneer = load_robot("mini-whegs"), load_robot(PIONEER)
    assert shape(mini) == shape(pioneer)
    assert type(mini.root.arbiter) is type(pioneer.root.arbiter)
    assert [(s.name, s.priority) for s in mini.remotes] == \
        [(s.name, s.priority) for s in pioneer.remotes]


def flat(data: Any, prefix: str = "") -> dict[str, Any]:
    """A robot file's data as ``path → value``; a device is keyed ``devices[kind/name]``, and
    one found in one file only is that one path."""
    out: dict[str, Any] = {}
    if isinstance(data, dict):
        for key, value in data.items():
            out.update(flat(value, f"{prefix}.{key}" if prefix else str(key)))
    elif prefix == "devices":
        for device in data:
            out[f"devices[{device['kind']}/{device['name']}]"] = device
    elif isinstance(data, list) and data and all(isinstance(d, dict) for d in data):
        for i, item in enumerate(data):
            out.update(flat(item, f"{prefix}[{i}]"))
    else:
        out[prefix] = data
    return out


def changed_parameters() -> set[str]:
    """What the Pioneer's file changes against the Mini-WHEGS's (not its name and
    description, which say which robot it is)."""
    mini = flat(yaml.safe_load(DEFAULT_ROBOT.read_text(encoding="utf-8")))
    pioneer = flat(yaml.safe_load(PIONEER.read_text(encoding="utf-8")))
    changed = set()
    for path in set(mini) | set(pioneer):
        if path.startswith("devices[") and path in mini and path in pioneer:
            both = (flat(mini[path], path), flat(pioneer[path], path))
            changed |= {p for p in set(both[0]) | set(both[1])
                        if both[0].get(p, ...) != both[1].get(p, ...)}
        elif mini.get(path, ...) != pioneer.get(path, ...):
            changed.add(path)
    return changed - {"name", "description"}


def test_the_docs_list_every_parameter_the_pioneer_changes() -> None:
    text = BODIES_DOC.read_text(encoding="utf-8")
    table = text.split("<!-- changed parameters -->")[1]
    listed = set(re.findall(r"^\| `([^`]+)` \|", table, flags=re.MULTILINE))
    assert listed == changed_parameters()
    behaviour = {p for p in listed if p.startswith("tree.")}
    assert behaviour == {"tree.children[2].params.start_pixels"}  # one number of the tree


@pytest.mark.parametrize("scenario", ["ball-in-sight", "ball-behind", "keep-away", "dance"])
def test_the_pioneer_passes_the_thesis_scenarios_scaled(scenario: str) -> None:
    result = experiment.run(PIONEER, PIONEER_SCENARIOS / f"{scenario}.json")
    assert result.passed, result.verdicts


def test_a_body_is_in_the_schema() -> None:
    body = BodySpec()
    assert body.drive == "skid-steer" and body.edges_per_rev == 4096
    assert np.isclose(body.top_speed_m_s, 17.0 * 0.02)
