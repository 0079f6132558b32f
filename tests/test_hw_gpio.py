"""The GPIO backends (motors.gpio, encoders.gpio) on gpiozero's own mock pin factory:
pulse widths for speed/turn, the stop on start, on the watchdog and on close, quadrature edges
driven on mock pins decoded in both direction modes, and the wiring check."""

from __future__ import annotations

import asyncio
import io
import threading
from collections.abc import Iterator

import msgspec
import pytest
from gpiozero.pins.mock import MockFactory, MockPWMPin

from components.encoders.component import EncodersComponent
from components.encoders.gpio import GpioEncoderBackend
from components.encoders.quadrature import FORWARD_SEQUENCE, DirectionMode, QuadratureDecoder
from components.motors.check import run_check
from components.motors.component import MotorsComponent, MotorTrim
from components.motors.gpio import GpioMotorBackend
from components.motors.pwm import DEFAULT_PWM, pulse_widths
from tests.conftest import eventually
from ubf_async.bus import Bus
from ubf_async.topics import DRIVE, ENCODERS
from ubf_async.transport import InProcessTransport

LEFT_TRIM = MotorTrim(zero_ms=1.55, dead_zone_ms=(1.48, 1.62))
RIGHT_TRIM = MotorTrim(zero_ms=1.56, dead_zone_ms=(1.46, 1.66), reverse_ms=1.05,
                       forward_ms=1.95)
LEFT_PINS = ("GPIO5", "GPIO6")
RIGHT_PINS = ("GPIO16", "GPIO26")


@pytest.fixture
def factory() -> Iterator[MockFactory]:
    factory = MockFactory(pin_class=MockPWMPin)
    yield factory
    factory.close()


def motors_on(factory: MockFactory) -> GpioMotorBackend:
    return GpioMotorBackend(left_pin="GPIO12", right_pin="GPIO13", factory=factory)


def encoders_on(factory: MockFactory, *, right: tuple[str, str] = RIGHT_PINS
                ) -> GpioEncoderBackend:
    return GpioEncoderBackend(factory=factory, left_a=LEFT_PINS[0], left_b=LEFT_PINS[1],
                              right_a=right[0], right_b=right[1], pull="down")


def pulse_ms(factory: MockFactory, pin: str) -> float:
    """The high time a mock PWM pin carries, from its duty cycle and frequency."""
    mock = factory.pin(pin)
    return float(mock.state) * 1000.0 / mock.frequency


def turn_wheel(factory: MockFactory, pins: tuple[str, str], steps: int, *, state: int = 0
               ) -> int:
    """Drive a wheel's A/B mock pins ``steps`` Gray-code steps (negative: backwards) from
    ``state``; return the state reached."""
    a, b = (factory.pin(p) for p in pins)
    index = FORWARD_SEQUENCE.index(state)
    for _ in range(abs(steps)):
        index = (index + (1 if steps > 0 else -1)) % 4
        new = FORWARD_SEQUENCE[index]
        for pin, bit in ((a, 2), (b, 1)):
            if bool(new & bit) != bool(pin.state):
                pin.drive_high() if new & bit else pin.drive_low()
    return FORWARD_SEQUENCE[index]


def test_pulses_have_the_width_the_hal_computes_for_speed_and_turn(
        factory: MockFactory) -> None:
    motors = motors_on(factory)
    for pin in ("GPIO12", "GPIO13"):
        assert factory.pin(pin).frequency == pytest.approx(50.0)  # the thesis's 20 ms period
    left, right = LEFT_TRIM.calibration(), RIGHT_TRIM.calibration()
    for speed, turn in ((0, 0), (40, 0), (-40, 0), (10, 80), (100, -100), (-25, 30)):
        command = pulse_widths(speed, turn, left=left, right=right)
        motors.apply_pulses(left_ms=command.left_ms, right_ms=command.right_ms)
        assert pulse_ms(factory, "GPIO12") == pytest.approx(command.left_ms, abs=1e-9)
        assert pulse_ms(factory, "GPIO13") == pytest.approx(command.right_ms, abs=1e-9)
    assert pulse_widths(0, 0, left=left, right=right).right_ms == 1.56  # the right motor's zero
    motors.apply_pulses(left_ms=2.7, right_ms=float("nan"))  # never past full forward/reverse
    assert (pulse_ms(factory, "GPIO12"), pulse_ms(factory, "GPIO13")) == (2.0, 1.0)
    assert motors.clipped == 2
    motors.close()
    motors.close()  # harmless twice
    assert factory.pin("GPIO12").state == 0  # released: no pulses
    motors.apply_pulses(left_ms=1.8, right_ms=1.8)  # after close: nothing reaches the pins
    assert factory.pin("GPIO12").state == 0


def test_motor_trim_from_a_robot_file_is_checked() -> None:
    with pytest.raises(msgspec.ValidationError, match="outside dead_zone_ms"):
        msgspec.convert({"zero_ms": 1.7, "dead_zone_ms": [1.48, 1.62]}, MotorTrim)
    with pytest.raises(msgspec.ValidationError, match="must not decrease"):
        msgspec.convert({"zero_ms": 1.55, "dead_zone_ms": [1.48, 1.62], "reverse_ms": 1.9},
                        MotorTrim)
    with pytest.raises(msgspec.ValidationError):
        msgspec.convert({"zero_ms": 1.55, "dead_zone_ms": [1.48, 3.0]}, MotorTrim)


@pytest.mark.asyncio
async def test_motors_component_stops_on_start_watchdog_and_close(factory: MockFactory) -> None:
    net = InProcessTransport()
    robot, teleop = Bus(transport=net, robot="r1"), Bus(transport=net, robot="r1")
    backend = motors_on(factory)
    motors = MotorsComponent(bus=robot, backend=backend, timeout_s=0.11,
                             left=LEFT_TRIM.calibration(), right=RIGHT_TRIM.calibration())
    motors.close_on_exit(backend.close)
    left_pin = factory.pin("GPIO12")
    left_pin.clear_states()
    await motors.start()
    zero = (1.55, 1.56)
    await eventually(lambda: motors.applied is not None, what="the start-up pulses")
    duties = [s.state for s in left_pin.states]
    assert DEFAULT_PWM.init_ms / 20.0 in duties  # the init pulse arms the driver, then stop
    assert backend.last_ms == zero
    drive = teleop.publisher(DRIVE)
    drive.publish({"speed": 40.0, "turn": 0.0})
    expected = pulse_widths(40, 0, left=LEFT_TRIM.calibration(), right=RIGHT_TRIM.calibration())
    await eventually(lambda: backend.last_ms == (expected.left_ms, expected.right_ms),
                     what="the command's pulses")
    assert expected.left_ms > 1.62 and expected.right_ms > 1.66  # out of the dead zones
    # No more commands: the watchdog stops the wheels.
    await eventually(lambda: backend.last_ms == zero, timeout_s=2.0, what="the watchdog stop")
    assert motors.timeouts == 1
    drive.publish({"speed": -60.0, "turn": 20.0})
    await eventually(lambda: backend.last_ms != zero, what="a second command")
    await motors.aclose()  # closing applies the stop pulse before the pins are released
    duties = [s.state for s in left_pin.states]
    assert duties[-2:] == [pytest.approx(zero[0] / 20.0), 0]
    assert backend.last_ms == zero
    await robot.aclose()
    await teleop.aclose()


def test_quadrature_edges_on_mock_pins_decode_in_both_modes(factory: MockFactory) -> None:
    encoders = encoders_on(factory)
    assert encoders.current_states() == (0, 0)
    phase = QuadratureDecoder(mode=DirectionMode.PHASE, initial_state=0)
    commanded = QuadratureDecoder(mode=DirectionMode.COMMANDED, initial_state=0)
    state = turn_wheel(factory, LEFT_PINS, 4 * 25)  # 25 counts forward
    left, right = encoders.read_phases()
    assert (phase.feed(left), right.size) == (100, 0)
    commanded.set_commanded_direction(1)
    assert commanded.feed(left) == 100
    state = turn_wheel(factory, LEFT_PINS, -4 * 10 - 2, state=state)  # backwards
    left, _ = encoders.read_phases()
    assert phase.feed(left) == -42
    commanded.set_commanded_direction(-1)
    assert commanded.feed(left) == -42
    assert phase.errors == commanded.errors == 0
    # Edges on the right encoder stay on the right; an empty read is "no edges".
    assert encoders.last_edge_ticks[1] is None
    turn_wheel(factory, RIGHT_PINS, 7)
    left, right = encoders.read_phases()
    assert left.size == 0 and right.size == 7
    # Each edge keeps the pin factory's time stamp (the kernel's, on lgpio).
    assert encoders.last_edge_ticks[1] == max(factory.pin(p)._last_change for p in RIGHT_PINS)
    assert encoders.read_phases()[1].size == 0
    encoders.close()
    encoders.close()


@pytest.mark.asyncio
async def test_encoders_component_counts_edges_driven_from_another_thread(
        factory: MockFactory) -> None:
    # The pin factory calls back on its own thread: here a thread drives the mock pins while
    # the component reads on the loop.
    net = InProcessTransport()
    robot, tool = Bus(transport=net, robot="r1"), Bus(transport=net, robot="r1")
    backend = encoders_on(factory)
    encoders = EncodersComponent(bus=robot, backend=backend, period_s=0.02,
                                 mode=DirectionMode.PHASE, initial_states=backend.current_states())
    seen: list[tuple[int, int]] = []

    def on_counts(key: str, payload: bytes, received_ns: int) -> None:
        from ubf_async.protocol import decode

        data = decode(payload, topic=ENCODERS).data
        seen.append((data.left_edges, data.right_edges))

    tool.subscribe(ENCODERS.key(tool.keys, "wheels"), on_counts)
    await encoders.start()
    driver = threading.Thread(target=lambda: (turn_wheel(factory, LEFT_PINS, 400),
                                              turn_wheel(factory, RIGHT_PINS, -240)))
    driver.start()
    await asyncio.to_thread(driver.join)
    await eventually(lambda: bool(seen) and seen[-1] == (400, -240),
                     what="the component to publish every edge")
    await encoders.aclose()
    await robot.aclose()
    await tool.aclose()


class WiredRobot:
    """Mock wiring for the check: while a motor's pulse is outside its dead zone, a thread
    turns that wheel's encoder (the right one's A/B swapped when ``swap_right``)."""

    def __init__(self, factory: MockFactory, *, swap_right: bool = False) -> None:
        self.factory = factory
        self.wheels = {"GPIO12": (LEFT_PINS, LEFT_TRIM),
                       "GPIO13": (RIGHT_PINS[::-1] if swap_right else RIGHT_PINS, RIGHT_TRIM)}
        self.states = dict.fromkeys(self.wheels, 0)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run)

    def _run(self) -> None:
        while not self._stop.wait(0.0005):  # the wheel's pace: one edge per 0.5 ms
            for motor, (pins, trim) in self.wheels.items():
                mock = self.factory.pin(motor)
                if not mock.state:
                    continue
                pulse = float(mock.state) * 20.0
                lo, hi = trim.dead_zone_ms
                step = 1 if pulse > hi else -1 if pulse < lo else 0
                if step:
                    self.states[motor] = turn_wheel(self.factory, pins, step,
                                                    state=self.states[motor])

    def __enter__(self) -> WiredRobot:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()


def test_wiring_check_passes_on_good_wiring(
        factory: MockFactory) -> None:
    motors = motors_on(factory)
    out = io.StringIO()
    with WiredRobot(factory):
        steps = run_check(motors=motors, encoders=encoders_on(factory),
                          left=LEFT_TRIM.calibration(), right=RIGHT_TRIM.calibration(),
                          spin_s=0.15, settle_s=0.05, out=out)
    assert [(s.wheel, s.direction, s.passed) for s in steps] == [
        ("left", 1, True), ("left", -1, True), ("right", 1, True), ("right", -1, True)]
    assert steps[0].edges["left"] > 40 and steps[0].edges["right"] == 0
    assert steps[3].edges["right"] < -40
    assert "FAIL" not in out.getvalue()
    assert backend_pulses(factory) == (1.55, 1.56)  # stopped at the end


def backend_pulses(factory: MockFactory) -> tuple[float, float]:
    return pulse_ms(factory, "GPIO12"), pulse_ms(factory, "GPIO13")


def test_wiring_check_names_a_swapped_encoder(factory: MockFactory) -> None:
    out = io.StringIO()
    with WiredRobot(factory, swap_right=True):
        steps = run_check(motors=motors_on(factory), encoders=encoders_on(factory),
                          left=LEFT_TRIM.calibration(), right=RIGHT_TRIM.calibration(),
                          spin_s=0.15, settle_s=0.05, out=out)
    assert [s.passed for s in steps] == [True, True, False, False]
    assert "swap right_a and right_b" in steps[2].advice
    assert "FAIL: the right wheel counted backwards" in out.getvalue()
