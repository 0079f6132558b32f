"""The I²C range backends (range.i2c, range.ads1115) against a test bus at the smbus2 seam:
register reads of a digital ranger and of an ADS1115, bus errors counted and survived, and the
range component publishing their readings (never on the event loop)."""

from __future__ import annotations

import threading

import pytest

from components.range.backend import MountPose, RangeReadError
from components.range.component import RangeComponent
from components.range.i2c import SHARP_CURVES, Ads1115Ranger, DigitalRanger
from components.range.ir import GP2Y0A21, GP2Y0A41
from tests.conftest import eventually
from tests.i2c_testbus import TestBus, ads1115, gp2y0e
from ubf_async.net.inprocess import InProcessTransport
from ubf_async.runtime.bus import Bus
from ubf_async.wire.protocol import decode
from ubf_async.wire.topics import RANGE

MOUNT = MountPose()


def test_digital_ranger_reads_its_distance_registers() -> None:
    bus = TestBus()
    gp2y0e(bus, distance_cm=23.5)
    ranger = DigitalRanger(bus=bus, address=0x40, layout="gp2y0e")
    assert ranger.distance_m(MOUNT, max_range_m=0.3) == pytest.approx(0.235, abs=1e-3)
    gp2y0e(bus, distance_cm=12.0, shift=1)  # the shift register is read once, at the start
    ranger = DigitalRanger(bus=bus, address=0x40, layout="gp2y0e")
    assert ranger.distance_m(MOUNT, max_range_m=0.3) == pytest.approx(0.12, abs=1e-3)
    gp2y0e(bus, distance_cm=63.0, shift=1)
    assert ranger.distance_m(MOUNT, max_range_m=0.3) is None  # nothing in range
    bus.registers[0x31] = {0x02: [0x01, 0x2C]}  # 300 mm in a 16-bit register
    mm16 = DigitalRanger(bus=bus, address=0x31, layout="mm16", register=0x02)
    assert mm16.distance_m(MOUNT, max_range_m=0.8) == 0.3
    bus.registers[0x31][0x02] = [0xFF, 0xFF]
    assert mm16.distance_m(MOUNT, max_range_m=0.8) is None
    with pytest.raises(ValueError, match="address"):
        DigitalRanger(bus=bus, address=0x80)


def test_ads1115_single_shot_conversion_and_the_sharp_curve() -> None:
    bus = TestBus()
    ads1115(bus, volts=1.0)
    bus.conversion_polls = 3
    ranger = Ads1115Ranger(bus=bus, address=0x48, channel=2, curve=SHARP_CURVES["ir-10-80"])
    assert ranger.volts() == pytest.approx(1.0, abs=2e-4)
    (address, register, data), = bus.writes
    config = (data[0] << 8) | data[1]
    assert (address, register) == (0x48, 0x01)
    assert config >> 15 == 1 and (config >> 12) & 0x7 == 0b110  # start; AIN2 against GND
    assert (config >> 9) & 0x7 == 0b001 and (config >> 8) & 1 == 1  # ±4.096 V, single shot
    # GP2Y0A21 at 1.0 V is ≈30 cm (datasheet); nearer is more volts.
    assert ranger.distance_m(MOUNT, max_range_m=0.8) == pytest.approx(0.29988, abs=1e-3)
    ads1115(bus, volts=2.0)
    assert ranger.distance_m(MOUNT, max_range_m=0.8) == pytest.approx(0.133, abs=2e-3)
    ads1115(bus, volts=0.1)
    assert ranger.distance_m(MOUNT, max_range_m=0.8) is None  # below min_volts: nothing there
    bus.conversion_polls = 10**6
    with pytest.raises(RangeReadError, match="conversion never finished"):
        ranger.volts()
    assert ranger.bus_errors == 1


def test_bus_errors_are_counted_and_raised_as_read_errors() -> None:
    bus = TestBus()
    gp2y0e(bus, distance_cm=20.0)
    ranger = DigitalRanger(bus=bus, address=0x40)
    bus.fail = 2
    for _ in range(2):
        with pytest.raises(RangeReadError, match=r"0x40.*Remote I/O error"):
            ranger.distance_m(MOUNT, max_range_m=0.3)
    assert ranger.bus_errors == 2
    assert ranger.distance_m(MOUNT, max_range_m=0.3) == pytest.approx(0.2, abs=1e-3)
    missing = DigitalRanger(bus=bus, address=0x41)
    with pytest.raises(RangeReadError, match="No such device"):
        missing.distance_m(MOUNT, max_range_m=0.3)
    ranger.close()
    assert not bus.closed  # a bus the backend did not open stays open
    owner = DigitalRanger(bus=bus, address=0x40, owns_bus=True)
    owner.close()
    owner.close()
    assert bus.closed


@pytest.mark.asyncio
async def test_range_component_publishes_measured_readings_off_the_loop() -> None:
    bus = TestBus()
    gp2y0e(bus, distance_cm=20.0)
    net = InProcessTransport()
    robot, tool = Bus(transport=net, robot="r1"), Bus(transport=net, robot="r1")
    ranger = DigitalRanger(bus=bus, address=0x40)
    component = RangeComponent(bus=robot, backend=ranger, name="front", model=GP2Y0A41,
                               period_s=0.01, seed=1)
    readings: list[tuple[int | None, str]] = []

    def on_range(key: str, payload: bytes, received_ns: int) -> None:
        data = decode(payload, topic=RANGE).data
        readings.append((data.range_mm, data.status))

    tool.subscribe(RANGE.key(tool.keys, "front"), on_range, latest=False)
    await component.start()
    await eventually(lambda: len(readings) >= 3, what="readings")
    assert set(readings) == {(200, "ok")}  # the sensor's measurement, no simulated error
    bus.fail = 5  # five failed reads: five samples skipped, counted, the component goes on
    count = len(readings)
    await eventually(lambda: component.read_errors == 5 and len(readings) > count + 2,
                     what="readings after the bus errors")
    assert component.restarts == 0 and ranger.bus_errors == 5
    gp2y0e(bus, distance_cm=3.0)
    await eventually(lambda: readings[-1] == (None, "too_close"), what="too close")
    gp2y0e(bus, distance_cm=63.0)
    await eventually(lambda: readings[-1] == (None, "too_far"), what="nothing in range")
    assert threading.get_ident() not in bus.threads  # every transaction off the event loop
    await component.aclose()
    await robot.aclose()
    await tool.aclose()


def test_limits_of_a_wider_model_apply() -> None:
    from components.range.ir import limit_ir

    assert limit_ir(GP2Y0A21, 0.05).status == "too_close"
    assert limit_ir(GP2Y0A21, 0.81).status == "too_far"
    assert limit_ir(GP2Y0A21, float("nan")).status == "too_far"
    assert limit_ir(GP2Y0A21, 0.4567).range_mm == 457
