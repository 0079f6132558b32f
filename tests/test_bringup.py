"""Issue 50, item 1: bring-up, one device at a time — ``python -m components.bringup`` on fake
backends, parametrised by device: an I²C ranger that answers and one that does not, a bus
that cannot be opened, a camera's frame saved with its pink count, a camera that cannot be
opened, encoders that move under the hand and a wheel that does not, LEDs on GPIO lit one at a
time, and what is not checked here (the motors, which move; simulated backends, LEDs in
memory)."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from gpiozero import Device
from gpiozero.pins.mock import MockFactory, MockPWMPin

from components import bringup, hardware
from components.range import i2c
from tests.i2c_testbus import TestBus
from tests.test_hw_gpio import turn_wheel
from ubf_async.assembly.robotfile import load_robot_text
from ubf_async.errors import ConfigurationError

LEFT, RIGHT = ("GPIO5", "GPIO6"), ("GPIO16", "GPIO26")
PINK_RGB, GREEN_RGB = (200, 60, 110), (40, 120, 40)


@pytest.fixture
def mock_pins(monkeypatch: pytest.MonkeyPatch) -> Iterator[MockFactory]:
    factory = MockFactory(pin_class=MockPWMPin)
    monkeypatch.setattr(hardware, "_FACTORIES", {})
    monkeypatch.setattr(Device, "pin_factory", factory)
    yield factory
    factory.close()


@pytest.fixture
def bus(monkeypatch: pytest.MonkeyPatch) -> TestBus:
    """/dev/i2c-1 as the kernel would serve it: a GP2Y0E ranger at 0x40 reading 23 cm."""
    test_bus = TestBus()
    test_bus.registers[0x40] = {0x35: [0x02], 0x5E: [23 * 16 >> 4 << 2, 0]}
    monkeypatch.setattr(i2c, "_open_bus", lambda number, who: test_bus)
    return test_bus


def video(path: Path, *, pink: bool) -> Path:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (320, 256))
    frame = np.empty((256, 320, 3), np.uint8)
    frame[:] = GREEN_RGB
    if pink:
        frame[96:160, 128:192] = PINK_RGB
    for _ in range(3):
        writer.write(cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
    writer.release()
    return path


def robot(devices: str) -> Any:
    return load_robot_text("format: 1\nname: bench\ndevices:\n" + devices
                           + "tree:\n  name: r\n  arbiter: PriorityMerge\n  children:\n"
                             "    - behavior: search\n", source="bench.yaml")


RANGER = ("  - kind: range\n    name: front\n    backend: i2c\n"
          "    backend_params: {bus: 1, address: ADDRESS, layout: gp2y0e}\n")
CAMERA = ("  - kind: camera\n    name: front\n    backend: video\n"
          "    backend_params: {source: 'SOURCE', width: 320, height: 256, loop: false}\n")
ENCODERS = ("  - kind: encoders\n    name: wheels\n    backend: gpio\n"
            "    backend_params: {left_a: GPIO5, left_b: GPIO6, right_a: GPIO16, "
            "right_b: GPIO26}\n")
MOTORS = ("  - kind: motors\n    name: main\n    backend: gpio\n"
          "    backend_params: {left_pin: GPIO12, right_pin: GPIO13}\n")
SIMULATED = "  - kind: range\n    name: side\n    backend: sim\n"
LEDS = "  - kind: leds\n    name: panel\n    backend: BACKEND\n"
LED_PINS = ("GPIO17", "GPIO27")


def checked(devices: str, tmp_path: Path, *, hand: Callable[[float], None] | None = None
            ) -> bringup.Line:
    said: list[str] = []
    checks: dict[str, bringup.DeviceCheck] = {
        "range": bringup.RangeCheck(), "camera": bringup.CameraCheck(tmp_path / "out"),
        "encoders": bringup.EncodersCheck(2.0, say=said.append, wait=hand or (lambda s: None))}
    (line,) = bringup.bring_up(robot(devices).devices, checks)
    return line


def test_a_ranger_that_answers_is_read(tmp_path: Path, bus: TestBus) -> None:
    line = checked(RANGER.replace("ADDRESS", "0x40"), tmp_path)
    assert (line.status, line.device) == ("ok", "range/front"), line
    assert line.text.startswith("5 reads, ") and " cm" in line.text


def test_a_ranger_that_does_not_answer_says_where_to_look(tmp_path: Path, bus: TestBus) -> None:
    line = checked(RANGER.replace("ADDRESS", "0x41"), tmp_path)
    assert line.status == "FAIL" and "5 of 5 reads failed: I²C device 0x41" in line.text
    assert "i2cdetect" in line.text


def test_a_bus_that_cannot_be_opened_fails_its_device_and_the_rest_go_on(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, mock_pins: MockFactory) -> None:
    def no_bus(number: int, who: str) -> Any:
        raise ConfigurationError(f"{who}: cannot open /dev/i2c-{number}: no such file")

    monkeypatch.setattr(i2c, "_open_bus", no_bus)
    lines = bringup.bring_up(robot(RANGER.replace("ADDRESS", "0x40") + MOTORS).devices,
                             {"range": bringup.RangeCheck()})
    assert [(line.device, line.status) for line in lines] == [
        ("range/front", "FAIL"), ("motors/main", "--")]
    assert "cannot open /dev/i2c-1" in lines[0].text
    assert "python -m components.motors --backend gpio --check" in lines[1].text


@pytest.mark.parametrize("pink", [True, False], ids=["pink in view", "no pink"])
def test_a_cameras_frame_is_saved_with_what_it_counts(tmp_path: Path, pink: bool) -> None:
    source = video(tmp_path / "frames.avi", pink=pink)
    line = checked(CAMERA.replace("SOURCE", str(source)), tmp_path)
    assert line.status == "ok" and line.text.startswith("a 320×256 frame, ")
    picture = tmp_path / "out" / "camera-front.png"
    assert str(picture) in line.text and cv2.imread(str(picture)) is not None
    counted = int(line.text.split(", ")[1].split()[0])
    assert (counted > 20) is pink, line.text  # (a 64-pixel square, one pixel in 8 read)


def test_a_camera_that_cannot_be_opened_fails(tmp_path: Path) -> None:
    line = checked(CAMERA.replace("SOURCE", str(tmp_path / "none.avi")), tmp_path)
    assert line.status == "FAIL" and "camera.video: cannot open video file" in line.text


@pytest.mark.parametrize("turned", [("left", "right"), ("left",)], ids=["both", "left only"])
def test_encoders_count_the_wheels_turned_by_hand(tmp_path: Path, mock_pins: MockFactory,
                                                  turned: tuple[str, ...]) -> None:
    def hand(seconds: float) -> None:  # what a person does while the check listens
        for wheel in turned:
            turn_wheel(mock_pins, LEFT if wheel == "left" else RIGHT, 8)

    line = checked(ENCODERS, tmp_path, hand=hand)
    if len(turned) == 2:
        assert (line.status, line.text) == ("ok", "left 8 edges, right 8 edges")
    else:
        assert line.status == "FAIL"
        assert line.text.startswith("left 8 edges, right 0 edges: no edges from the right "
                                    "wheel — check its A/B lines (right: GPIO16/GPIO26)")


def test_the_leds_light_one_at_a_time_while_you_watch(mock_pins: MockFactory) -> None:
    lit: list[list[str]] = []  # which pins were high each time the check waited

    def watch(seconds: float) -> None:
        lit.append([pin for pin in LED_PINS if mock_pins.pin(pin).state])

    said: list[str] = []
    gpio = (LEDS.replace("BACKEND", "gpio")
            + f"    backend_params: {{pins: [{', '.join(LED_PINS)}]}}\n")
    (line,) = bringup.bring_up(robot(gpio).devices,
                               {"leds": bringup.LedsCheck(say=said.append, wait=watch)})
    assert lit == [["GPIO17"], ["GPIO27"]] * bringup.BLINK_ROUNDS
    assert not any(mock_pins.pin(pin).state for pin in LED_PINS)  # all off after
    assert said == ["leds/panel: watch the LEDs light one at a time, LED 0 (GPIO17) first ..."]
    assert line.status == "ok" and line.text.startswith("2 LEDs lit in turn (GPIO17, GPIO27); ")
    (line,) = bringup.bring_up(robot(LEDS.replace("BACKEND", "sim")).devices,
                               {"leds": bringup.LedsCheck(say=said.append, wait=watch)})
    assert (line.status, line.text) == ("--", "sim backend: LEDs in memory, nothing to light "
                                              "here")


def test_what_is_not_checked_here_says_so(tmp_path: Path, mock_pins: MockFactory) -> None:
    lines = bringup.bring_up(robot(MOTORS + SIMULATED).devices, {})
    assert [line.status for line in lines] == ["--", "--"]
    assert "(simulated): nothing to bring up" in lines[1].text


def test_the_command_prints_a_line_a_device_and_fails_when_one_does(
        tmp_path: Path, bus: TestBus, capsys: pytest.CaptureFixture[str]) -> None:
    robot_file = tmp_path / "bench.yaml"
    robot_file.write_text("format: 1\nname: bench\ndevices:\n"
                          + RANGER.replace("ADDRESS", "0x40")
                          + CAMERA.replace("SOURCE", str(tmp_path / "none.avi"))
                          + "tree:\n  name: r\n  arbiter: PriorityMerge\n  children:\n"
                            "    - behavior: search\n")
    code = bringup.main([str(robot_file), "--out", str(tmp_path / "out")])
    out = capsys.readouterr().out.splitlines()
    assert code == 1
    assert out[0].startswith("ok    range/front: 5 reads") and out[1].startswith(
        "FAIL  camera/front: ")
    assert out[-1] == "1 of 2 devices failed"
