"""Real-hardware robot files through the real launch path (``--no-sim``) on gpiozero's mock pin
factory and on a test I²C bus at the smbus2 seam; the standalone motor driver and the wiring
check ending on SIGTERM and Ctrl-C with the stop pulse held and the pins released (seen from the
mock pins' state history, which ``tests.pinlog`` writes out of the process); a run that fails
with an exception stopping the wheels the same way."""

from __future__ import annotations

import asyncio
import errno
import io
import os
import signal
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import msgspec
import pytest
import smbus2
from gpiozero import Device
from gpiozero.pins.mock import MockFactory, MockPWMPin

from components import hardware
from components.motors.component import MotorTrim
from components.motors.pwm import (
    DEFAULT_LEFT_CALIBRATION,
    DEFAULT_PWM,
    DEFAULT_RIGHT_CALIBRATION,
    pulse_widths,
)
from tests.conftest import as_dict, eventually, read_until, stop
from tests.i2c_testbus import TestBus, ads1115, gp2y0e
from tests.pinlog import holds, load
from ubf_async.errors import ConfigurationError
from ubf_async.net.options import ConnectionOptions
from ubf_async.runtime.bus import Bus
from ubf_async.tools import launch
from ubf_async.wire.protocol import decode
from ubf_async.wire.topics import ENCODERS, MOTORS, ODOMETRY, RANGE

ROOT = Path(__file__).resolve().parent.parent
PI_WHEGS = ROOT / "examples" / "robots" / "pi-whegs.yaml"
MOCK_GPIO = {**os.environ, "PYTHONUNBUFFERED": "1", "GPIOZERO_PIN_FACTORY": "mock",
             "GPIOZERO_MOCK_PIN_CLASS": "mockpwmpin"}
HOLD_S = 2 * DEFAULT_PWM.period_ms / 1000.0
"""How long the init and stop pulses must stay on the pins: two 20 ms periods."""

# A robot whose motors are calibrated unlike the defaults, driving at a fixed speed and turn:
# the pulses on the pins follow from this calibration, or the test fails.
LEFT = {"zero_ms": 1.52, "dead_zone_ms": [1.46, 1.58], "reverse_ms": 1.1, "forward_ms": 1.9}
RIGHT = {"zero_ms": 1.58, "dead_zone_ms": [1.51, 1.66], "reverse_ms": 1.05, "forward_ms": 1.95}
SPEED, TURN = 40.0, 10.0
CALIBRATED_ROBOT = f"""
format: 1
name: calibrated
devices:
  - kind: motors
    name: main
    backend: gpio
    backend_params: {{left_pin: GPIO12, right_pin: GPIO13}}
    params:
      left: {msgspec.json.encode(LEFT).decode()}
      right: {msgspec.json.encode(RIGHT).decode()}
  - kind: encoders
    name: wheels
    backend: gpio
    backend_params: {{left_a: GPIO5, left_b: GPIO6, right_a: GPIO16, right_b: GPIO26}}
    params: {{direction: phase}}
tree:
  name: root
  arbiter: HighestPriority
  children:
    - {{behavior: drive, name: cruise, params: {{speed: {SPEED}, turn: {TURN}}}}}
"""


def calibrated_pulses() -> tuple[float, float, float, float]:
    """(left, right) while driving, then (left, right) standing: from the robot file's
    calibration, checked to differ from what the default calibration gives."""
    left = msgspec.convert(LEFT, MotorTrim).calibration()
    right = msgspec.convert(RIGHT, MotorTrim).calibration()
    drive = pulse_widths(SPEED, TURN, left=left, right=right)
    default = pulse_widths(SPEED, TURN, left=DEFAULT_LEFT_CALIBRATION,
                           right=DEFAULT_RIGHT_CALIBRATION)
    assert abs(drive.left_ms - default.left_ms) > 0.01
    assert abs(drive.right_ms - default.right_ms) > 0.01
    assert (left.zero_ms, right.zero_ms) != (DEFAULT_LEFT_CALIBRATION.zero_ms,
                                             DEFAULT_RIGHT_CALIBRATION.zero_ms)
    return drive.left_ms, drive.right_ms, left.zero_ms, right.zero_ms


@pytest.fixture
def calibrated_robot(tmp_path: Path) -> Path:
    """:data:`CALIBRATED_ROBOT` as a robot file."""
    robot_file = tmp_path / "calibrated.yaml"
    robot_file.write_text(CALIBRATED_ROBOT)
    return robot_file


async def spawn_logged(pins: Path, module: str, *args: str) -> asyncio.subprocess.Process:
    """``python -m MODULE ARGS`` on the mock pin factory, its pins' history written to
    ``pins`` when it ends (``tests.pinlog``)."""
    return await asyncio.create_subprocess_exec(
        sys.executable, "-m", "tests.pinlog", str(pins), module, *args, cwd=ROOT, env=MOCK_GPIO,
        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.STDOUT)


async def end(proc: asyncio.subprocess.Process, sig: int) -> tuple[int, str]:
    """Send ``sig`` and wait (bounded) for the process to end; its exit status and the rest
    of its output."""
    assert proc.stdout is not None
    proc.send_signal(sig)
    try:
        rest = await asyncio.wait_for(proc.stdout.read(), 30)
        code = await asyncio.wait_for(proc.wait(), 30)
    except TimeoutError:
        await stop(proc)
        raise
    return code, rest.decode()


def assert_stopped_and_released(history: list[list[float]] | list[Any], stop_ms: float) -> None:
    """The pin's last pulse was ``stop_ms``, held two whole periods, then the pin released."""
    *_, (last_duty, held_s) = holds(history)
    assert last_duty == pytest.approx(stop_ms / DEFAULT_PWM.period_ms)
    assert held_s >= HOLD_S
    assert history[-1][1] == 0  # released: no pulses


def assert_init_held(history: list[list[float]] | list[Any]) -> None:
    init = [held_s for duty, held_s in holds(history)
            if duty == pytest.approx(DEFAULT_PWM.init_ms / DEFAULT_PWM.period_ms)]
    assert init and init[0] >= HOLD_S


def test_the_example_robot_file_validates() -> None:
    result = subprocess.run([sys.executable, "-m", "ubf_async.launch", str(PI_WHEGS), "--check"],
                            cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    for line in ("motors/main: backend gpio", "encoders/wheels: backend gpio",
                 "range/front: backend i2c", "range/left: backend ads1115"):
        assert line in result.stdout


@pytest.mark.asyncio
async def test_launch_drives_the_pins_with_the_robot_files_calibration(
        endpoint: str, tmp_path: Path, calibrated_robot: Path) -> None:
    drive_left, drive_right, zero_left, zero_right = calibrated_pulses()
    pins = tmp_path / "pins.json"
    proc = await spawn_logged(pins, "ubf_async.launch", str(calibrated_robot), "--no-sim",
                              "--listen", endpoint, "--quiet")
    bus = await Bus.open(ConnectionOptions(robot="calibrated", connect=[endpoint]))
    applied: list[dict] = []
    counts: list[dict] = []
    poses: list[dict] = []
    try:
        bus.subscribe(MOTORS.key(bus.keys, "main"),
                      lambda k, p, t: applied.append(as_dict(decode(p, topic=MOTORS).data)),
                      latest=False)
        bus.subscribe(ENCODERS.key(bus.keys, "wheels"),
                      lambda k, p, t: counts.append(as_dict(decode(p, topic=ENCODERS).data)))
        bus.subscribe(ODOMETRY.key(bus.keys, "wheels"),
                      lambda k, p, t: poses.append(as_dict(decode(p, topic=ODOMETRY).data)))
        await eventually(lambda: any(a["reason"] == "command" for a in applied) and counts
                         and poses, timeout_s=30, what="the robot's devices on the bus")
        command = next(a for a in applied if a["reason"] == "command")
        assert (command["speed"], command["turn"]) == (SPEED, TURN)
        assert (command["left_ms"], command["right_ms"]) == (pytest.approx(drive_left),
                                                             pytest.approx(drive_right))
        assert counts[-1]["mode"] == "phase" and counts[-1]["left_edges"] == 0
        assert poses[-1]["x_m"] == 0.0
        code, out = await end(proc, signal.SIGTERM)
        assert code == 0, out
        await eventually(lambda: applied[-1]["reason"] == "stopped",
                         what="the stop pulse on SIGTERM")
        assert (applied[-1]["left_ms"], applied[-1]["right_ms"]) == (zero_left, zero_right)
    finally:
        await stop(proc)  # if it did not end
        await bus.aclose()
    # What reached the pins: the calibrated pulses, the init pulse held, the robot file's stop
    # pulses held two periods and the pins released.
    history = load(pins)
    for pin, drive, zero in (("GPIO12", drive_left, zero_left),
                             ("GPIO13", drive_right, zero_right)):
        duties = [duty for duty, _ in holds(history[pin])]
        assert pytest.approx(drive / DEFAULT_PWM.period_ms) in duties
        assert_init_held(history[pin])
        assert_stopped_and_released(history[pin], zero)


@pytest.mark.asyncio
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT], ids=["SIGTERM", "Ctrl-C"])
async def test_standalone_motor_driver_stops_the_wheels_on_a_stop_signal(
        endpoint: str, tmp_path: Path, sig: int) -> None:
    pins = tmp_path / "pins.json"
    proc = await spawn_logged(pins, "components.motors", "--backend", "gpio", "--backend-params",
                              "{left_pin: GPIO12, right_pin: GPIO13}", "--listen", endpoint,
                              "--robot", "hw", "--clock", "wall", "--timeout-s", "30")
    bus = await Bus.open(ConnectionOptions(robot="hw", connect=[endpoint]))
    applied: list[dict] = []
    try:
        await read_until(proc, "attached to robot")
        bus.subscribe(MOTORS.key(bus.keys, "main"),
                      lambda k, p, t: applied.append(as_dict(decode(p, topic=MOTORS).data)),
                      latest=False)
        drive = bus.publisher(bus.keys.cmd("drive"), "drive")

        def drove() -> bool:
            drive.publish({"speed": 50.0, "turn": 0.0})
            return any(a["reason"] == "command" and a["speed"] == 50 for a in applied)

        await eventually(drove, timeout_s=20, what="a command to reach the pins")
        # Driving when the signal comes (the watchdog's 30 s do not stop it before).
        code, out = await end(proc, sig)
        assert code == 0, out
        await eventually(lambda: applied[-1]["reason"] == "stopped", what="the stop pulse")
        assert applied[-1]["speed"] == 0 and applied[-1]["left_dir"] == 0
    finally:
        await stop(proc)  # if it did not end
        await bus.aclose()
    history = load(pins)
    moving, stopped = applied[-2:]
    assert moving["reason"] == "command" and moving["speed"] == 50  # driving until then
    for pin, side in (("GPIO12", "left_ms"), ("GPIO13", "right_ms")):
        duties = [duty for duty, _ in holds(history[pin])]
        assert duties[-2] == pytest.approx(moving[side] / DEFAULT_PWM.period_ms)
        assert_init_held(history[pin])
        assert_stopped_and_released(history[pin], stopped[side])


@pytest.mark.asyncio
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT], ids=["SIGTERM", "Ctrl-C"])
async def test_wiring_check_ends_on_a_stop_signal_with_the_wheels_stopped(
        tmp_path: Path, sig: int) -> None:
    pins = tmp_path / "pins.json"
    proc = await spawn_logged(pins, "components.motors", "--backend", "gpio", "--check",
                              "--robot-file", str(PI_WHEGS), "--spin-s", "60")
    try:
        printed = await read_until(proc, "left forward:")  # said once it spins, for 60 s
        code, out = await end(proc, sig)
    finally:
        await stop(proc)  # if it did not end
    name = signal.Signals(sig).name
    assert code == 128 + sig, printed + out
    assert f"{name}: the wheels were stopped and the pins released" in out
    history = load(pins)
    left_spin = msgspec.convert({"zero_ms": 1.55, "dead_zone_ms": [1.48, 1.62]},
                                MotorTrim).calibration().pulse_ms(30)  # pi-whegs's left motor
    duties = [duty for duty, _ in holds(history["GPIO12"])]
    assert duties[-2] == pytest.approx(left_spin / DEFAULT_PWM.period_ms)  # then the stop
    for pin in ("GPIO12", "GPIO13"):
        assert_init_held(history[pin])
        assert_stopped_and_released(history[pin], 1.55)


def test_wiring_check_command_line_reports_errors_clearly(tmp_path: Path) -> None:
    sim_robot = ROOT / "ubf_async" / "robots" / "mini-whegs.yaml"
    result = subprocess.run(
        [sys.executable, "-m", "components.motors", "--backend", "gpio", "--check",
         "--robot-file", str(sim_robot)], cwd=ROOT, env=MOCK_GPIO, capture_output=True,
        text=True, timeout=60)
    assert result.returncode == 2
    assert "drives real hardware" in result.stderr


def test_the_wiring_check_is_in_the_motor_drivers_help() -> None:
    result = subprocess.run([sys.executable, "-m", "components.motors", "--help"], cwd=ROOT,
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    assert "wiring check" in result.stdout
    assert "--check" in result.stdout.split("wiring check", 1)[1]
    # A device attaches where launch listens unless told otherwise, as the tools do.
    assert "default: tcp/127.0.0.1:7447, where launch listens" in " ".join(result.stdout.split())


def test_an_inconsistent_motor_calibration_is_refused_naming_its_line(tmp_path: Path) -> None:
    text = PI_WHEGS.read_text().replace("left: {zero_ms: 1.55", "left: {zero_ms: 1.70")
    robot_file = tmp_path / "bad.yaml"
    robot_file.write_text(text)
    line = next(i for i, row in enumerate(text.splitlines(), 1) if "zero_ms: 1.70" in row)
    result = subprocess.run([sys.executable, "-m", "ubf_async.launch", str(robot_file),
                             "--check"], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert result.returncode == 2
    assert f"bad.yaml:{line}" in result.stderr
    assert "zero_ms 1.7 lies outside dead_zone_ms" in result.stderr


class PipeThatBreaks(io.StringIO):
    """A stdout whose reader goes away (``| head``) once ``broken()`` holds."""

    def __init__(self, broken: Callable[[], bool]) -> None:
        super().__init__()
        self.broken = broken

    def write(self, text: str) -> int:
        if self.broken():
            raise BrokenPipeError(errno.EPIPE, "Broken pipe")
        return super().write(text)


@pytest.fixture
def mock_pins(monkeypatch: pytest.MonkeyPatch) -> Iterator[MockFactory]:
    """gpiozero's default pin factory in this process: a mock one with PWM pins."""
    factory = MockFactory(pin_class=MockPWMPin)
    monkeypatch.setattr(hardware, "_FACTORIES", {})  # the process's factories, fresh
    monkeypatch.setattr(Device, "pin_factory", factory)
    yield factory
    factory.close()


@pytest.mark.asyncio
async def test_a_run_ended_by_an_exception_stops_the_wheels(
        endpoint: str, calibrated_robot: Path, mock_pins: MockFactory) -> None:
    # The real launch code in this process; its status line's stdout goes away while the
    # robot drives, and the BrokenPipeError ends the run.
    drive_left, drive_right, zero_left, zero_right = calibrated_pulses()
    args = launch.build_parser().parse_args([str(calibrated_robot), "--no-sim", "--listen",
                                             endpoint, "--status-period-s", "0.05"])
    plan = launch.plan_launch(args)
    left_pin = mock_pins.pin("GPIO12")

    def driving() -> bool:
        return left_pin.state == pytest.approx(drive_left / DEFAULT_PWM.period_ms)

    with pytest.raises(BrokenPipeError):
        await asyncio.wait_for(launch.run_robot(plan, args, out=PipeThatBreaks(driving)), 30)
    for pin, drive, zero in (("GPIO12", drive_left, zero_left),
                             ("GPIO13", drive_right, zero_right)):
        history = mock_pins.pin(pin).states
        duties = [duty for duty, _ in holds(history)]
        assert duties[-2] == pytest.approx(drive / DEFAULT_PWM.period_ms)  # driving, then
        assert_stopped_and_released(history, zero)  # the stop pulse, held, and released


@pytest.fixture
def i2c_buses(monkeypatch: pytest.MonkeyPatch) -> list[tuple[int, TestBus]]:
    """``smbus2.SMBus(n)`` opens a test bus serving pi-whegs's two rangers: a GP2Y0E03 at
    0x40 seeing 20 cm and an ADS1115 at 0x48 whose Sharp ranger gives 1.0 V."""
    opened: list[tuple[int, TestBus]] = []

    def open_bus(bus: int) -> TestBus:
        test_bus = TestBus()
        gp2y0e(test_bus, distance_cm=20.0)
        ads1115(test_bus, volts=1.0)
        opened.append((bus, test_bus))
        return test_bus

    monkeypatch.setattr(smbus2, "SMBus", open_bus)
    return opened


@pytest.mark.asyncio
async def test_launch_builds_the_range_backends_on_an_i2c_bus(
        endpoint: str, i2c_buses: list[tuple[int, TestBus]]) -> None:
    # The real launch code in this process (a subprocess could not be handed the test bus):
    # the robot file's range.i2c and range.ads1115 backends open /dev/i2c-1 through smbus2,
    # their devices publish, and each closes the bus it opened when the run ends.
    args = launch.build_parser().parse_args([str(PI_WHEGS), "--no-sim", "--devices", "range",
                                             "--listen", endpoint, "--quiet"])
    plan = launch.plan_launch(args)
    run = asyncio.create_task(launch.run_robot(plan, args, out=io.StringIO()))
    bus = await Bus.open(ConnectionOptions(robot="pi-whegs", connect=[endpoint]))
    readings: dict[str, list[dict]] = {"front": [], "left": []}
    try:
        for name, seen in readings.items():
            bus.subscribe(RANGE.key(bus.keys, name),
                          lambda k, p, t, seen=seen: seen.append(
                              as_dict(decode(p, topic=RANGE).data)), latest=False)
        await eventually(lambda: all(readings.values()), timeout_s=30,
                         what="both rangers' samples")
        assert [number for number, _ in i2c_buses] == [1, 1]  # /dev/i2c-1, one per backend
        front = readings["front"][-1]
        assert (front["range_mm"], front["status"], front["model"]) == (200, "ok", "ir-4-30")
        # GP2Y0A21 at 1.0 V: 29.988 cm by its curve.
        left = readings["left"][-1]
        assert (left["range_mm"], left["status"], left["model"]) == (300, "ok", "ir-10-80")
        # A ranger that stops answering costs samples, not the run.
        front_bus = i2c_buses[0][1]  # built first, as in the file
        assert front_bus.writes == [] and i2c_buses[1][1].writes  # only the ADC is written
        front_bus.fail = 3
        count = len(readings["front"])
        await eventually(lambda: front_bus.fail == 0 and len(readings["front"]) > count + 1,
                         what="readings after the bus errors")
        assert not run.done() and not any(b.closed for _, b in i2c_buses)
    finally:
        run.cancel()  # what SIGTERM does to launch's main task
        # Stopped: launch's end ran, as for any end, and it returns its exit status.
        assert await run == 0
        await bus.aclose()
    assert all(b.closed for _, b in i2c_buses)


@pytest.mark.asyncio
async def test_a_range_device_refuses_another_model_than_its_adc_backend_reads(
        endpoint: str, tmp_path: Path, i2c_buses: list[tuple[int, TestBus]]) -> None:
    text = PI_WHEGS.read_text().replace("{sensor: ir-10-80,", "{sensor: ir-20-150,")
    assert "sensor: ir-20-150" in text
    robot_file = tmp_path / "mismatch.yaml"
    robot_file.write_text(text)
    args = launch.build_parser().parse_args([str(robot_file), "--no-sim", "--devices", "range",
                                             "--listen", endpoint, "--quiet"])
    with pytest.raises(ConfigurationError, match=r"range 'left': its backend reads model "
                                                 r"ir-20-150 but the device's model is ir-10-80"):
        await launch.run_robot(launch.plan_launch(args), args, out=io.StringIO())
    # Both buses opened (the front ranger's, then the ADC's) are closed again.
    assert len(i2c_buses) == 2 and all(b.closed for _, b in i2c_buses)
