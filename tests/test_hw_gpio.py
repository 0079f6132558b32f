"""The GPIO backends (motors.gpio, encoders.gpio) on gpiozero's own mock pin factory:
pulse widths for speed/turn, the stop on start, on the watchdog and on close, how long the init
and stop pulses are held (from the mock pins' state history), quadrature edges driven on mock
pins decoded in both direction modes, wheel speed from the edges' time stamps, the edge
buffer's overflow, and the wiring check."""

from __future__ import annotations

import asyncio
import io
import math
import signal
import threading
from collections.abc import AsyncIterator, Iterator
from typing import Any

import msgspec
import pytest
import pytest_asyncio
from gpiozero.pins import mock as mock_pins
from gpiozero.pins.mock import MockFactory, MockPWMPin

from components import hardware
from components.encoders.backend import EdgeTiming
from components.encoders.component import EncodersComponent, wheel_speed_rad_s
from components.encoders.gpio import MAX_EDGE_GAP_S, GpioEncoderBackend
from components.motors.check import Interrupted, run_check
from components.motors.component import MotorsComponent, MotorTrim
from components.motors.gpio import GpioMotorBackend, gpio_backend
from components.motors.pwm import DEFAULT_PWM, pulse_widths
from components.quadrature import FORWARD_SEQUENCE, DirectionMode, QuadratureDecoder
from tests.conftest import LoopClock, eventually
from tests.pinlog import holds
from ubf_async.errors import ConfigurationError
from ubf_async.net.inprocess import InProcessTransport
from ubf_async.runtime.bus import Bus
from ubf_async.wire.protocol import decode
from ubf_async.wire.topics import DRIVE, ENCODERS, MOTORS, Encoders

HOLD_S = 2 * DEFAULT_PWM.period_ms / 1000.0
"""Two 20 ms periods: how long the init and stop pulses must stay on the pins."""

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


@pytest_asyncio.fixture
async def buses() -> AsyncIterator[tuple[Bus, Bus]]:
    """The robot's bus and another process's (a teleop, a tool) on one in-process transport."""
    net = InProcessTransport()
    robot, other = Bus(transport=net, robot="r1"), Bus(transport=net, robot="r1")
    yield robot, other
    await robot.aclose()
    await other.aclose()


@pytest_asyncio.fixture
async def loop_buses(monkeypatch: pytest.MonkeyPatch) -> AsyncIterator[tuple[Bus, Bus]]:
    """:func:`buses` on the event loop's clock, for tests on looptime's virtual time: the
    robot clock (the watchdog), the pulses' holds (asyncio sleeps) and the mock pins' stamps
    (gpiozero's ``monotonic``) all read the loop's time, so every duration is exact."""
    loop = asyncio.get_running_loop()
    monkeypatch.setattr(mock_pins, "monotonic", loop.time)
    net, clock = InProcessTransport(), LoopClock()
    robot = Bus(transport=net, robot="r1", clock=clock)
    other = Bus(transport=net, robot="r1", clock=clock)
    yield robot, other
    await robot.aclose()
    await other.aclose()


def motors_on(factory: MockFactory) -> GpioMotorBackend:
    return GpioMotorBackend(left_pin="GPIO12", right_pin="GPIO13", factory=factory)


def motors_component(bus: Bus, backend: GpioMotorBackend, *, timeout_s: float
                     ) -> MotorsComponent:
    """The motors component with the trims above, closing ``backend`` when it closes."""
    motors = MotorsComponent(bus=bus, backend=backend, timeout_s=timeout_s,
                             left=LEFT_TRIM.calibration(), right=RIGHT_TRIM.calibration())
    motors.close_on_exit(backend.aclose)
    return motors


def encoders_on(factory: MockFactory, *, right: tuple[str, str] = RIGHT_PINS,
                **options: Any) -> GpioEncoderBackend:
    return GpioEncoderBackend(factory=factory, left_a=LEFT_PINS[0], left_b=LEFT_PINS[1],
                              right_a=right[0], right_b=right[1], pull="down", **options)


def encoders_component(bus: Bus, backend: GpioEncoderBackend, *,
                       mode: DirectionMode = DirectionMode.PHASE) -> EncodersComponent:
    """The encoders component reading ``backend`` every 20 ms."""
    return EncodersComponent(bus=bus, backend=backend, period_s=0.02, mode=mode,
                             initial_states=backend.current_states())


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
@pytest.mark.looptime
async def test_motors_component_stops_on_start_watchdog_and_close(
        factory: MockFactory, loop_buses: tuple[Bus, Bus]) -> None:
    robot, teleop = loop_buses
    backend = motors_on(factory)
    assert backend.hold_s == pytest.approx(HOLD_S)
    motors = motors_component(robot, backend, timeout_s=0.11)
    applied: list[tuple[int, str]] = []
    teleop.subscribe(MOTORS.key(teleop.keys, name="main"),
                     lambda k, p, t: applied.append((decode(p).stamp_ns, decode(p).data.reason)),
                     latest=False)
    left_pin = factory.pin("GPIO12")
    left_pin.clear_states()
    await motors.start()
    zero = (1.55, 1.56)
    await eventually(lambda: motors.applied is not None, what="the start-up pulses")
    init = DEFAULT_PWM.init_ms / 20.0
    # The init pulse arms the driver for two whole periods, then the stop pulse.
    assert [s for s, _ in holds(left_pin.states)][-2:] == [0.0, pytest.approx(init)]
    assert left_pin.state == pytest.approx(zero[0] / 20.0)
    assert holds(left_pin.states)[-1][1] == pytest.approx(HOLD_S)
    assert backend.last_ms == zero
    drive = teleop.publisher(DRIVE)
    drive.publish({"speed": 40.0, "turn": 0.0})
    expected = pulse_widths(40, 0, left=LEFT_TRIM.calibration(), right=RIGHT_TRIM.calibration())
    await eventually(lambda: backend.last_ms == (expected.left_ms, expected.right_ms),
                     what="the command's pulses")
    assert expected.left_ms > 1.62 and expected.right_ms > 1.66  # out of the dead zones
    # No more commands: the watchdog stops the wheels, 0.11 s after the command.
    await eventually(lambda: backend.last_ms == zero, what="the watchdog stop")
    assert motors.timeouts == 1
    (command_ns, _), (stop_ns, reason) = applied[-2:]
    assert reason == "timeout" and (stop_ns - command_ns) / 1e9 == pytest.approx(0.11, abs=1e-5)
    drive.publish({"speed": -60.0, "turn": 20.0})
    await eventually(lambda: backend.last_ms != zero, what="a second command")
    await motors.aclose()  # closing applies the stop pulse before the pins are released
    history = holds(left_pin.states)
    assert [s for s, _ in history][-1] == pytest.approx(zero[0] / 20.0)
    assert history[-1][1] == pytest.approx(HOLD_S)  # held two whole periods, then released
    assert left_pin.states[-1].state == 0
    assert backend.last_ms == zero


@pytest.mark.asyncio
@pytest.mark.looptime
async def test_pulses_are_held_on_the_loop_without_blocking_it(
        factory: MockFactory, loop_buses: tuple[Bus, Bus]) -> None:
    # The holds are awaited: this test's own coroutine sees the init pulse and the stop pulse
    # on the pins while they are held (a blocking wait would only let it see what came after),
    # and a command that arrives while the stop pulse is held is not applied.
    robot, teleop = loop_buses
    backend = motors_on(factory)
    motors = motors_component(robot, backend, timeout_s=5.0)
    pins = factory.pin("GPIO12"), factory.pin("GPIO13")
    init = DEFAULT_PWM.init_ms
    await motors.start()
    await eventually(lambda: backend.last_ms == (init, init), what="the init pulse")
    assert motors.applied is None  # still holding it
    await eventually(lambda: motors.applied is not None, what="the end of the init hold")
    drive = teleop.publisher(DRIVE)
    drive.publish({"speed": 70.0, "turn": 0.0})
    moving = pulse_widths(70, 0, left=LEFT_TRIM.calibration(), right=RIGHT_TRIM.calibration())
    await eventually(lambda: backend.last_ms == (moving.left_ms, moving.right_ms),
                     what="the command's pulses")
    closing = asyncio.create_task(motors.aclose())
    zero = (1.55, 1.56)
    await eventually(lambda: backend.last_ms == zero, what="the stop pulse")
    assert not closing.done() and pins[0].state == pytest.approx(zero[0] / 20.0)
    drive.publish({"speed": 70.0, "turn": 0.0})  # during the hold: ignored
    await eventually(lambda: motors.ignored == 1, what="the command to arrive")
    assert not closing.done() and backend.last_ms == zero
    await closing
    for pin, stop in zip(pins, zero, strict=True):
        (*_, (held, held_s)) = holds(pin.states)
        assert held == pytest.approx(stop / 20.0) and held_s == pytest.approx(HOLD_S)
        assert pin.state == 0


@pytest.mark.asyncio
@pytest.mark.looptime
async def test_a_second_cancellation_does_not_cut_the_stop_pulse_short(
        factory: MockFactory, loop_buses: tuple[Bus, Bus]) -> None:
    robot, _ = loop_buses
    backend = motors_on(factory)
    motors = MotorsComponent(bus=robot, backend=backend)
    await motors.start()
    await eventually(lambda: motors.applied is not None, what="the start-up pulses")
    backend.apply_pulses(left_ms=1.9, right_ms=1.9)  # as if driving
    run = next(t for t in motors._tasks if t.get_name().endswith(":run"))
    run.cancel()
    await eventually(lambda: backend.last_ms == (1.55, 1.55), what="the stop pulse")
    run.cancel()  # again, while the stop pulse is held
    with pytest.raises(asyncio.CancelledError):
        await run
    backend.close()
    (*_, (stop, held_s)) = holds(factory.pin("GPIO12").states)
    assert stop == pytest.approx(1.55 / 20.0) and held_s == pytest.approx(HOLD_S)
    await motors.aclose()


def test_a_pin_factory_without_pwm_is_named_with_a_hint(monkeypatch: pytest.MonkeyPatch
                                                         ) -> None:
    # gpiozero's PinPWMUnsupported has no message: the error names its type and the fix.
    monkeypatch.setattr(hardware, "_FACTORIES", {})
    monkeypatch.delenv("GPIOZERO_MOCK_PIN_CLASS", raising=False)  # plain MockPin: no PWM
    with pytest.raises(ConfigurationError) as error:
        gpio_backend(context=None, left_pin="GPIO12", right_pin="GPIO13", pin_factory="mock")
    message = str(error.value)
    assert "motors.gpio: cannot set up the pins: PinPWMUnsupported (" in message
    assert "GPIOZERO_MOCK_PIN_CLASS=mockpwmpin" in message
    hardware._FACTORIES["mock"].close()
    # Other errors keep their message, with the type in front.
    assert str(hardware.pins_error("x", ValueError("GPIO99 is not a valid pin"))).startswith(
        "x: cannot set up the pins: ValueError: GPIO99 is not a valid pin (pin names")


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
        factory: MockFactory, buses: tuple[Bus, Bus]) -> None:
    # The pin factory calls back on its own thread: here a thread drives the mock pins while
    # the component reads on the loop.
    robot, tool = buses
    encoders = encoders_component(robot, encoders_on(factory))
    seen: list[tuple[int, int]] = []

    def on_counts(key: str, payload: bytes, received_ns: int) -> None:
        from ubf_async.wire.protocol import decode

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


EDGE_US = 500
"""The wheels' pace in virtual time: one encoder edge per 0.5 ms while the motor turns."""


class PinClock:
    """What gpiozero's mock pins stamp their changes with (the module's ``monotonic``), made
    a clock the test moves: edge times and gaps come out exact, however busy the machine.
    Make it before the first pin, so that every pin is on it."""

    def __init__(self, monkeypatch: pytest.MonkeyPatch) -> None:
        self.now_us = 0  # whole microseconds: durations come out exact
        monkeypatch.setattr(mock_pins, "monotonic", self.time)

    def time(self) -> float:
        return self.now_us / 1e6

    def advance(self, seconds: float) -> None:
        self.now_us += round(seconds * 1e6)


def turn_wheel_timed(factory: MockFactory, pins: tuple[str, str], steps: int, *,
                     state: int = 0, clock: PinClock | None = None
                     ) -> tuple[int, list[float]]:
    """:func:`turn_wheel` one edge at a time (0.5 ms apart on ``clock``, if given), returning
    the state reached and each edge's time stamp as the mock pin factory gave it to the
    backend (the pin's last change)."""
    stamps = []
    for _ in range(abs(steps)):
        if clock is not None:
            clock.advance(EDGE_US / 1e6)
        state = turn_wheel(factory, pins, 1 if steps > 0 else -1, state=state)
        stamps.append(max(factory.pin(p)._last_change for p in pins))
    return state, stamps


def test_edge_timing_from_the_pin_factorys_stamps(factory: MockFactory,
                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    # The edges' own timing on a clock the test moves: a busy machine pausing between two
    # edges (0.1 s is the gap that starts a new movement) cannot change what is measured.
    clock = PinClock(monkeypatch)
    encoders = encoders_on(factory)
    # From standing: the batch is timed from its first edge (39 intervals for 40 edges).
    state, stamps = turn_wheel_timed(factory, LEFT_PINS, 40, clock=clock)
    encoders.read_phases()
    left, right = encoders.edge_timing
    assert left == EdgeTiming(edges=40, span_s=stamps[-1] - stamps[0], intervals=39)
    assert left.span_s == pytest.approx(39 * EDGE_US / 1e6)
    assert right == EdgeTiming(edges=0, span_s=None, intervals=0)
    # Moving on: timed from the newest edge before the batch (every interval counted).
    state, more = turn_wheel_timed(factory, LEFT_PINS, -12, state=state, clock=clock)
    encoders.read_phases()
    assert encoders.edge_timing[0] == EdgeTiming(edges=12, span_s=more[-1] - stamps[-1],
                                                 intervals=12)
    # A period without edges, then one edge: standing still, so its time is not known.
    encoders.read_phases()
    state, one = turn_wheel_timed(factory, LEFT_PINS, 1, state=state, clock=clock)
    encoders.read_phases()
    assert encoders.edge_timing[0] == EdgeTiming(edges=1, span_s=None, intervals=0)
    # An edge long after the one before is a new start too, even between two busy reads:
    # just under the gap, it still counts as moving on; at the gap, it starts anew.
    clock.advance(MAX_EDGE_GAP_S - 2 * EDGE_US / 1e6)
    state, near = turn_wheel_timed(factory, LEFT_PINS, 2, state=state, clock=clock)
    encoders.read_phases()
    assert encoders.edge_timing[0] == EdgeTiming(edges=2, span_s=near[-1] - one[-1],
                                                 intervals=2)
    clock.advance(MAX_EDGE_GAP_S - EDGE_US / 1e6)
    state, late = turn_wheel_timed(factory, LEFT_PINS, 3, state=state, clock=clock)
    encoders.read_phases()
    assert encoders.edge_timing[0] == EdgeTiming(edges=3, span_s=late[-1] - late[0],
                                                 intervals=2)
    encoders.close()


def encoder_samples(tool: Bus) -> list[Encoders]:
    samples: list[Encoders] = []
    tool.subscribe(ENCODERS.key(tool.keys, "wheels"),
                   lambda k, p, t: samples.append(decode(p, topic=ENCODERS).data),
                   latest=False)
    return samples


@pytest.mark.asyncio
async def test_encoders_component_publishes_wheel_speed_from_edge_times(
        factory: MockFactory, buses: tuple[Bus, Bus]) -> None:
    robot, tool = buses
    encoders = encoders_component(robot, encoders_on(factory))
    samples = encoder_samples(tool)
    await encoders.start()
    await eventually(lambda: len(samples) >= 2, what="samples of standing wheels")
    assert samples[-1].left_rad_s == samples[-1].right_rad_s == 0.0
    # Edges driven on the loop, between two reads: one batch per wheel.
    _, left = turn_wheel_timed(factory, LEFT_PINS, 80)
    _, right = turn_wheel_timed(factory, RIGHT_PINS, -20)
    await eventually(lambda: samples[-1].left_edges == 80, what="the batch's sample")
    sample = next(s for s in samples if s.left_edges == 80)
    edge_rad = 2 * math.pi / 4096
    assert sample.left_rad_s == pytest.approx(79 * edge_rad / (left[-1] - left[0]))
    assert sample.right_rad_s == pytest.approx(-19 * edge_rad / (right[-1] - right[0]))
    assert sample.left_rad_s > 0 > sample.right_rad_s
    # The next period has no edges: the wheels turned less than one edge.
    await eventually(lambda: samples[-1] is not sample, what="the next sample")
    assert samples[-1].left_rad_s == 0.0 and samples[-1].dropped == 0
    assert wheel_speed_rad_s(5, EdgeTiming(edges=5, span_s=None, intervals=0)) is None
    await encoders.aclose()


@pytest.mark.asyncio
async def test_encoders_component_on_mock_pins_in_commanded_mode(
        factory: MockFactory, buses: tuple[Bus, Bus]) -> None:
    # The thesis's mode: the sign comes from the motors' command, not from the A/B order.
    robot, tool = buses
    encoders = encoders_component(robot, encoders_on(factory), mode=DirectionMode.COMMANDED)
    samples = encoder_samples(tool)
    await encoders.start()
    await eventually(lambda: bool(samples), what="the first sample")
    assert samples[-1].mode == "commanded"
    tool.publisher(MOTORS, "main").publish({
        "speed": 0.0, "turn": 60.0, "left_ms": 1.3, "right_ms": 1.8, "left_dir": -1,
        "right_dir": 1, "reason": "command"})
    await eventually(lambda: (encoders.left.commanded_direction,
                              encoders.right.commanded_direction) == (-1, 1),
                     what="the commanded directions")
    turn_wheel(factory, LEFT_PINS, 40)  # the A/B order says forward ...
    turn_wheel(factory, RIGHT_PINS, -24)  # ... and backward
    await eventually(lambda: (samples[-1].left_edges, samples[-1].right_edges)
                     == (-40, 24), what="edges with the commanded signs")
    sample = next(s for s in samples if s.left_edges == -40)
    assert sample.left_rad_s is not None and sample.right_rad_s is not None
    assert sample.left_rad_s < 0 < sample.right_rad_s  # the speed has the commanded sign too
    assert samples[-1].errors == 0
    await encoders.aclose()


@pytest.mark.asyncio
async def test_encoders_component_counts_edges_the_buffer_dropped(
        factory: MockFactory, buses: tuple[Bus, Bus]) -> None:
    robot, tool = buses
    backend = encoders_on(factory, max_pending=16)
    encoders = encoders_component(robot, backend)
    samples = encoder_samples(tool)
    await encoders.start()
    await eventually(lambda: bool(samples), what="the first sample")
    turn_wheel(factory, LEFT_PINS, 100)  # between two reads: 84 more than the buffer holds
    await eventually(lambda: samples[-1].dropped > 0, what="the overflow's sample")
    # The first that says so: ``dropped`` is a running total, and on a busy machine the next
    # sample (no new edges: a speed of 0) may be in before this test looks.
    sample = next(s for s in samples if s.dropped > 0)
    # 84 dropped edges are a whole number of cycles: the decoder sees valid steps and counts
    # only the 16 kept, without an error — ``dropped`` is what says the count is short.
    assert (sample.dropped, sample.left_edges, sample.errors) == (84, 16, 0)
    assert sample.left_rad_s is None  # edges missing: no speed from this batch
    assert backend.overflowed == 84
    turn_wheel(factory, LEFT_PINS, 8, state=0)
    await eventually(lambda: samples[-1].left_edges == 24, what="counting on")
    assert samples[-1].dropped == 84
    await encoders.aclose()


class WiredRobot:
    """Mock wiring for the check, in virtual time: the check's ``sleep`` moves a clock that
    also stamps the mock pins' changes, and while a motor's pulse is outside its dead zone,
    that wheel's encoder turns one edge per 0.5 ms of it (the right one's A/B swapped when
    ``swap_right``). No thread and no wall time, so the edges counted are exact however busy
    the machine is (a thread pacing edges in wall time counted too few on a slow one)."""

    def __init__(self, factory: MockFactory, monkeypatch: pytest.MonkeyPatch, *,
                 swap_right: bool = False) -> None:
        self.factory = factory
        self.wheels = {"GPIO12": (LEFT_PINS, LEFT_TRIM),
                       "GPIO13": (RIGHT_PINS[::-1] if swap_right else RIGHT_PINS, RIGHT_TRIM)}
        self.states = dict.fromkeys(self.wheels, 0)
        self.pins = PinClock(monkeypatch)  # the pins' histories on the check's own clock

    def step(self) -> None:
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

    def clock(self) -> float:
        return self.pins.time()

    def sleep(self, seconds: float) -> None:
        end_us = self.pins.now_us + round(seconds * 1e6)
        while self.pins.now_us + EDGE_US <= end_us:
            self.pins.now_us += EDGE_US
            self.step()
        self.pins.now_us = end_us


def test_wiring_check_passes_on_good_wiring(
        factory: MockFactory, monkeypatch: pytest.MonkeyPatch) -> None:
    wired = WiredRobot(factory, monkeypatch)
    motors = motors_on(factory)
    out = io.StringIO()
    steps = run_check(motors=motors, encoders=encoders_on(factory),
                      left=LEFT_TRIM.calibration(), right=RIGHT_TRIM.calibration(),
                      spin_s=0.15, settle_s=0.05, out=out, sleep=wired.sleep,
                      clock=wired.clock)
    assert [(s.wheel, s.direction, s.passed) for s in steps] == [
        ("left", 1, True), ("left", -1, True), ("right", 1, True), ("right", -1, True)]
    spun = round(0.15e6 / EDGE_US)  # every edge of each 0.15 s spin, and only those
    assert steps[0].edges == {"left": spun, "right": 0}
    assert steps[3].edges == {"left": 0, "right": -spun}
    report = out.getvalue()
    assert "FAIL" not in report
    # Counts (four edges each) are what it reports, the edges beside them.
    left = steps[0].edges["left"]
    assert steps[0].counts == {"left": left / 4, "right": 0.0}
    assert f"left {left / 4:+8.2f} counts ({left:+d} edges)" in report
    assert report.startswith("left forward: ")  # said before the wheel spins
    assert backend_pulses(factory) == (1.55, 1.56)  # stopped at the end
    # The init pulse armed the drivers for two whole periods before the first stop pulse,
    # and the last stop pulse is held as long before the pins may be released.
    first = holds(factory.pin("GPIO12").states)
    init = next(i for i, (duty, _) in enumerate(first)
                if duty == pytest.approx(DEFAULT_PWM.init_ms / 20.0))
    assert first[init][1] == pytest.approx(HOLD_S)
    assert first[init + 1][0] == pytest.approx(1.55 / 20.0)
    assert wired.pins.now_us == round((2 * HOLD_S + 0.05 + 4 * (0.15 + 0.05)) * 1e6)


def backend_pulses(factory: MockFactory) -> tuple[float, float]:
    return pulse_ms(factory, "GPIO12"), pulse_ms(factory, "GPIO13")


def test_wiring_check_names_a_swapped_encoder(factory: MockFactory,
                                             monkeypatch: pytest.MonkeyPatch) -> None:
    out = io.StringIO()
    wired = WiredRobot(factory, monkeypatch, swap_right=True)
    steps = run_check(motors=motors_on(factory), encoders=encoders_on(factory),
                      left=LEFT_TRIM.calibration(), right=RIGHT_TRIM.calibration(),
                      spin_s=0.15, settle_s=0.05, out=out, sleep=wired.sleep,
                      clock=wired.clock)
    assert [s.passed for s in steps] == [True, True, False, False]
    assert "swap right_a and right_b" in steps[2].advice
    assert "FAIL: the right wheel counted backwards" in out.getvalue()


def test_wiring_check_interrupted_holds_the_stop_pulse(factory: MockFactory,
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    # SIGTERM or Ctrl-C arrives as Interrupted wherever the check is (here: while the left
    # wheel spins); the stop pulse is applied and held two periods before it is raised.
    wired = WiredRobot(factory, monkeypatch)
    motors = motors_on(factory)
    sleeps: list[float] = []

    def sleep(seconds: float) -> None:
        sleeps.append(seconds)
        if len(sleeps) == 3:  # init hold, settle, then the first spin
            raise Interrupted(signal.SIGTERM)
        wired.sleep(seconds)

    with pytest.raises(Interrupted):
        run_check(motors=motors, encoders=encoders_on(factory), left=LEFT_TRIM.calibration(),
                  right=RIGHT_TRIM.calibration(), spin_s=10.0, settle_s=0.05, out=io.StringIO(),
                  sleep=sleep, clock=wired.clock)
    assert sleeps[:3] == [HOLD_S, 0.05, 10.0]
    motors.close()
    history = holds(factory.pin("GPIO12").states)
    spin = LEFT_TRIM.calibration().pulse_ms(30)
    assert [duty for duty, _ in history][-2:] == [pytest.approx(spin / 20.0),
                                                   pytest.approx(1.55 / 20.0)]
    assert history[-1][1] == pytest.approx(HOLD_S)  # the stop pulse, held, then released
    assert factory.pin("GPIO12").state == 0
