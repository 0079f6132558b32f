"""The LED ``gpio`` backend (issue 50, item 3) on gpiozero's mock pins, built from a robot file
as launch builds it: a ``cmd/leds`` command lights the right pins (either polarity), the LEDs
are off on start and their pins released when the device closes; pins the file gets wrong are
refused — at the file's line when the value is malformed, in one line naming the pin when
gpiozero or the backend refuses it."""

from __future__ import annotations

import pytest
from gpiozero.pins.mock import MockFactory

from components.leds.gpio import GpioLedBackend
from tests.conftest import eventually
from tests.test_bringup import mock_pins  # noqa: F401  (a fixture)
from ubf_async.assembly.context import DeviceContext
from ubf_async.assembly.robotfile import load_robot_text
from ubf_async.errors import ConfigurationError, RobotFileError
from ubf_async.net.inprocess import InProcessTransport
from ubf_async.runtime.bus import Bus
from ubf_async.wire.protocol import decode
from ubf_async.wire.topics import LED_STATE, LEDS

PINS = ("GPIO17", "GPIO27", "GPIO22")


def robot_text(backend_params: str, params: str = "{}") -> str:
    return ("format: 1\nname: bench\ndevices:\n"
            "  - kind: leds\n    name: panel\n    backend: gpio\n"
            f"    backend_params: {backend_params}\n"
            f"    params: {params}\n"
            "tree:\n  name: r\n  arbiter: PriorityMerge\n  children:\n"
            "    - behavior: search\n")


def levels(factory: MockFactory) -> list[bool]:
    """Each of :data:`PINS`'s level: True while the pin is high."""
    return [bool(factory.pin(pin).state) for pin in PINS]


@pytest.mark.asyncio
@pytest.mark.parametrize("active_high", [True, False], ids=["active high", "active low"])
async def test_an_led_command_lights_the_right_pins(mock_pins: MockFactory,  # noqa: F811
                                                    active_high: bool) -> None:
    robot = load_robot_text(robot_text(f"{{pins: [{', '.join(PINS)}], active_high: "
                                       f"{str(active_high).lower()}}}"), source="bench.yaml")
    net = InProcessTransport()
    bus, tool = Bus(transport=net, robot="r1"), Bus(transport=net, robot="r1")
    leds = robot.devices[0].build(context=DeviceContext(bus=bus, clock=bus.clock))
    lit = [level is active_high for level in levels(mock_pins)]  # what each LED shows
    assert lit == [False] * 3  # off from the start
    reported: list[int] = []
    tool.subscribe(LED_STATE.key(tool.keys, "panel"),
                   lambda k, p, t: reported.append(decode(p).data.mask))
    await leds.start()
    try:
        await eventually(lambda: reported, what="the LEDs' first state (it listens)")
        command = tool.publisher(LEDS)
        command.publish({"mask": 0b101})
        await eventually(lambda: [lvl is active_high for lvl in levels(mock_pins)]
                         == [True, False, True], what="LEDs 0 and 2 lit")
        command.publish({"mask": 0b010})
        await eventually(lambda: [lvl is active_high for lvl in levels(mock_pins)]
                         == [False, True, False], what="LED 1 lit alone")
        command.publish({"mask": 0})
        await eventually(lambda: [lvl is active_high for lvl in levels(mock_pins)]
                         == [False] * 3, what="all off")
    finally:
        await leds.aclose()
        await bus.aclose()
        await tool.aclose()
    assert all(mock_pins.pin(pin).function == "input" for pin in PINS)  # released


@pytest.mark.asyncio
async def test_the_device_counts_its_pins(mock_pins: MockFactory) -> None:  # noqa: F811
    robot = load_robot_text(robot_text("{pins: [GPIO17, GPIO27, GPIO22]}"), source="bench.yaml")
    device = robot.devices[0]
    backend = device.backend_factory(context=None, **device.backend_params)
    assert (backend.count, backend.physical) == (3, True)
    backend.close()
    wrong = load_robot_text(robot_text("{pins: [GPIO17, GPIO27]}", "{count: 3}"),
                            source="bench.yaml").devices[0]
    net = InProcessTransport()
    bus = Bus(transport=net, robot="r1")
    with pytest.raises(ConfigurationError, match=r"leds 'panel': its backend drives 2 LEDs "
                                                 r"\(its pins\) but the device's count is 3"):
        wrong.build(context=DeviceContext(bus=bus, clock=bus.clock))
    await bus.aclose()
    assert mock_pins.pin("GPIO17").function == "input"  # the refused backend let go


@pytest.mark.parametrize(("pins", "said"), [
    ("[GPIO17, '']", "bench.yaml:7: backend leds.gpio: Expected `str` of length >= 1 (at "
                     "devices[0].backend_params.pins[1])"),
    ("[]", "bench.yaml:7: backend leds.gpio: Expected `array` of length >= 1 (at "
           "devices[0].backend_params.pins)"),
    ("[1, 2, 3, 4, 5, 6, 7, 8, 9]", "bench.yaml:7: backend leds.gpio: Expected `array` of "
                                    "length <= 8"),
], ids=["empty name", "no pins", "nine pins"])
def test_malformed_pins_are_refused_at_the_files_line(pins: str, said: str) -> None:
    with pytest.raises(RobotFileError) as refused:
        load_robot_text(robot_text(f"{{pins: {pins}}}"), source="bench.yaml")
    assert str(refused.value).startswith(said), refused.value


@pytest.mark.parametrize(("pins", "said"), [
    ("[GPIO17, GPIO99]", "leds.gpio: cannot set up the pins: PinInvalidPin: GPIO99 is not a "
                         "valid pin name (pin names as gpiozero knows them, e.g. GPIO12; are "
                         "you in the gpio group? docs/hardware.md)"),
    ("[GPIO17, GPIO27, GPIO17]", "leds.gpio: cannot set up the pins: ValueError: pin "
                                 "'GPIO17' is given for LEDs 0 and 2 (pin names"),
], ids=["no such pin", "a pin twice"])
def test_a_bad_pin_is_refused_in_one_line(mock_pins: MockFactory,  # noqa: F811
                                          pins: str, said: str) -> None:
    device = load_robot_text(robot_text(f"{{pins: {pins}}}"), source="bench.yaml").devices[0]
    with pytest.raises(ConfigurationError) as refused:
        device.backend_factory(context=None, **device.backend_params)
    message = str(refused.value)
    assert message.startswith(said) and "\n" not in message, message
    assert mock_pins.pin("GPIO17").function == "input"  # the pins had before are released


def test_closing_twice_and_setting_after_close_do_nothing(mock_pins: MockFactory  # noqa: F811
                                                          ) -> None:
    backend = GpioLedBackend(pins=PINS[:2], factory=mock_pins)
    backend.set_leds(0b11)
    assert levels(mock_pins)[:2] == [True, True]
    backend.close()
    backend.close()
    backend.set_leds(0b11)
    assert levels(mock_pins)[:2] == [False, False]
