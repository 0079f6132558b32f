"""Real-hardware robot files through the real launch path (``--no-sim``) on gpiozero's mock pin
factory, the standalone motor driver on it ending with the stop pulse on SIGTERM, the wiring
check's command line, and the rule that nothing but those backends imports the hardware
libraries."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import as_dict, eventually
from ubf_async.bus import Bus, ConnectionOptions
from ubf_async.protocol import decode
from ubf_async.topics import ENCODERS, MOTORS, ODOMETRY

ROOT = Path(__file__).resolve().parent.parent
PI_WHEGS = ROOT / "examples" / "robots" / "pi-whegs.yaml"
MOCK_GPIO = {**os.environ, "PYTHONUNBUFFERED": "1", "GPIOZERO_PIN_FACTORY": "mock",
             "GPIOZERO_MOCK_PIN_CLASS": "mockpwmpin"}


def start(*args: str) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, *args], cwd=ROOT, env=MOCK_GPIO, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT)


def stop(proc: subprocess.Popen[str]) -> tuple[int, str]:
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
    out, _ = proc.communicate(timeout=30)
    return proc.returncode, out


def test_the_example_robot_file_validates() -> None:
    result = subprocess.run([sys.executable, "-m", "ubf_async.launch", str(PI_WHEGS), "--check"],
                            cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    for line in ("motors/main: backend gpio", "encoders/wheels: backend gpio",
                 "range/front: backend i2c", "range/left: backend ads1115"):
        assert line in result.stdout


@pytest.mark.asyncio
async def test_launch_wires_gpio_devices_from_the_robot_file(endpoint: str) -> None:
    proc = start("-m", "ubf_async.launch", str(PI_WHEGS), "--no-sim", "--devices",
                 "motors,encoders", "--listen", endpoint, "--quiet")
    bus = await Bus.open(ConnectionOptions(robot="pi-whegs", connect=[endpoint]))
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
        # The robot file's calibration: the left motor stands still at 1.55 ms.
        assert command["speed"] == 0 and command["left_ms"] == pytest.approx(1.55)
        assert counts[-1]["mode"] == "phase" and counts[-1]["left_edges"] == 0
        assert poses[-1]["x_m"] == 0.0
        before = len(applied)
        code, out = stop(proc)
        assert code == 0, out
        assert "motors/main (gpio)" in out and "encoders/wheels (gpio)" in out
        await eventually(lambda: any(a["reason"] == "stopped" for a in applied[before:]),
                         what="the stop pulse on SIGTERM")
        assert applied[-1]["left_ms"] == pytest.approx(1.55)
    finally:
        stop(proc)
        await bus.aclose()


@pytest.mark.asyncio
async def test_standalone_motor_driver_stops_the_wheels_on_sigterm(endpoint: str) -> None:
    proc = start("-m", "components.motors", "--backend", "gpio", "--backend-params",
                 "{left_pin: GPIO12, right_pin: GPIO13}", "--listen", endpoint,
                 "--robot", "hw", "--clock", "wall")
    bus = await Bus.open(ConnectionOptions(robot="hw", connect=[endpoint]))
    applied: list[dict] = []
    try:
        bus.subscribe(MOTORS.key(bus.keys, "main"),
                      lambda k, p, t: applied.append(as_dict(decode(p, topic=MOTORS).data)),
                      latest=False)
        drive = bus.publisher(bus.keys.cmd("drive"), "drive")
        def drove() -> bool:
            drive.publish({"speed": 50.0, "turn": 0.0})
            return any(a["reason"] == "command" and a["speed"] == 50 for a in applied)

        await eventually(drove, timeout_s=20, what="a command to reach the pins")
        code, out = stop(proc)
        assert code == 0, out
        await eventually(lambda: applied[-1]["reason"] == "stopped", what="the stop pulse")
        assert applied[-1]["speed"] == 0 and applied[-1]["left_dir"] == 0
    finally:
        stop(proc)
        await bus.aclose()


def test_wiring_check_command_line_reports_errors_clearly(tmp_path: Path) -> None:
    sim_robot = ROOT / "ubf_async" / "robots" / "mini-whegs.yaml"
    result = subprocess.run(
        [sys.executable, "-m", "components.motors", "--backend", "gpio", "--check",
         "--robot-file", str(sim_robot)], cwd=ROOT, env=MOCK_GPIO, capture_output=True,
        text=True, timeout=60)
    assert result.returncode == 2
    assert "drives real hardware" in result.stderr


def test_hardware_libraries_are_imported_only_by_the_backends_that_need_them() -> None:
    # Blocked as if not installed: the framework, the device kinds and the simulated robot
    # still load, and a hardware backend says how to install what it needs.
    code = """
import sys
sys.modules["gpiozero"] = None
sys.modules["smbus2"] = None
import ubf_async.launch, components.motors.component, components.encoders.component
import components.range.component, components.motors.gpio, components.encoders.gpio
import components.range.i2c
from ubf_async.robotfile import load_robot
load_robot("mini-whegs")
from components.range.i2c import i2c_backend
from ubf_async.errors import ConfigurationError
try:
    i2c_backend(context=None)
except ConfigurationError as exc:
    print(exc)
"""
    result = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                            text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    assert 'install the hardware extra: pip install -e ".[hardware]"' in result.stdout


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
