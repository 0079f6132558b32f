"""Real IR range finders on I²C (smbus2): digital rangers, and analog Sharp rangers behind an
ADS1115 ADC.

* ``range.i2c`` — the thesis's path: a ranger that reports its distance in registers read over
  I²C (§3.2.5). Two register layouts: ``gp2y0e`` (Sharp GP2Y0E02B/03: distance registers
  0x5E–0x5F in 1/16 cm, scaled by the shift register 0x35; 63 cm or more means nothing in
  range) and ``mm16`` (a 16-bit big-endian register holding millimetres, as the thesis's
  sensor package returned them; 0 or 0xFFFF means nothing in range).
* ``range.ads1115`` — an analog Sharp GP2Y0A ranger (the three thesis models) on one channel
  of an ADS1115: a single-shot conversion (±4.096 V, 860 samples/s, ~1.2 ms), then the
  model's voltage → distance curve ``d_cm = a · V^b`` (fits of Sharp's datasheet curves). A
  voltage at or below ``min_volts`` means nothing in range.

Every read is a bus transaction: these backends are ``blocking`` (the range component reads
them in a worker thread) and ``measured`` (the sensor's own error; the HAL adds none). A bus
error (``OSError`` from the kernel, e.g. EREMOTEIO for a sensor that does not answer) becomes
:class:`~components.range.backend.RangeReadError`, counted in ``bus_errors``: the component
skips that sample and goes on; it never crashes. The bus object is anything with smbus2's
``SMBus`` methods; the default opens ``/dev/i2c-<bus>``.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Annotated, Any, ClassVar, Literal, Protocol

import msgspec

from components import hardware
from components.range.backend import MountPose, RangeBackend, RangeReadError
from ubf_async.assembly.context import DeviceContext
from ubf_async.errors import ConfigurationError

__all__ = ["SHARP_CURVES", "Address", "Ads1115Ranger", "DigitalRanger", "SMBusLike", "SharpCurve",
           "ads1115_backend", "i2c_backend"]


class SMBusLike(Protocol):
    """The part of ``smbus2.SMBus`` these backends use."""

    def read_i2c_block_data(self, i2c_addr: int, register: int, length: int) -> list[int]: ...

    def write_i2c_block_data(self, i2c_addr: int, register: int, data: list[int]) -> None: ...

    def read_byte_data(self, i2c_addr: int, register: int) -> int: ...

    def close(self) -> None: ...


class _I2cDevice(RangeBackend):
    """One device at ``address`` on ``bus``: bus errors counted and raised as
    :class:`RangeReadError`; one transaction at a time."""

    measured: ClassVar[bool] = True
    blocking: ClassVar[bool] = True

    def __init__(self, *, bus: SMBusLike, address: int, owns_bus: bool) -> None:
        if not 0x03 <= address <= 0x77:
            raise ValueError(f"I²C address {address:#x} outside 0x03–0x77")
        self.bus = bus
        self.address = address
        self.bus_errors = 0
        """Transactions that failed (each a skipped sample)."""
        self._owns_bus = owns_bus
        self._lock = threading.Lock()
        self._closed = False

    def _read(self, register: int, length: int) -> list[int]:
        try:
            return self.bus.read_i2c_block_data(self.address, register, length)
        except OSError as exc:
            raise self._error(f"reading register {register:#04x}", exc) from None

    def _write(self, register: int, data: list[int]) -> None:
        try:
            self.bus.write_i2c_block_data(self.address, register, data)
        except OSError as exc:
            raise self._error(f"writing register {register:#04x}", exc) from None

    def _error(self, what: str, exc: OSError) -> RangeReadError:
        self.bus_errors += 1
        return RangeReadError(f"I²C device {self.address:#04x}: {what}: {exc}")

    def close(self) -> None:
        """Close the bus if this backend opened it; calling it again does nothing."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
        if self._owns_bus:
            self.bus.close()


class DigitalRanger(_I2cDevice):
    """A ranger whose distance is read from its registers (``range.i2c``)."""

    GP2Y0E_DISTANCE = 0x5E
    GP2Y0E_SHIFT = 0x35
    GP2Y0E_NOTHING_CM = 63.0

    def __init__(self, *, bus: SMBusLike, address: int,
                 layout: Literal["gp2y0e", "mm16"] = "gp2y0e", register: int = 0x00,
                 owns_bus: bool = False) -> None:
        super().__init__(bus=bus, address=address, owns_bus=owns_bus)
        self.layout = layout
        self.register = register
        self._shift: int | None = None

    def distance_m(self, mount: MountPose, *, max_range_m: float) -> float | None:
        with self._lock:
            if self.layout == "mm16":
                high, low = self._read(self.register, 2)
                raw = (high << 8) | low
                return None if raw in (0, 0xFFFF) else raw / 1000.0
            if self._shift is None:  # read once: the sensor's range setting
                (shift,) = self._read(self.GP2Y0E_SHIFT, 1)
                if shift not in (1, 2):
                    raise self._error(f"shift register reads {shift}, expected 1 or 2",
                                      OSError("unexpected value"))
                self._shift = shift
            high, low = self._read(self.GP2Y0E_DISTANCE, 2)
            distance_cm = ((high << 4) | (low & 0x0F)) / 16.0 / (1 << self._shift)
            return None if distance_cm >= self.GP2Y0E_NOTHING_CM else distance_cm / 100.0


@dataclass(frozen=True, slots=True, kw_only=True)
class SharpCurve:
    """A Sharp analog ranger's output: ``d_cm = a · V^b`` above ``min_volts``."""

    a: float
    b: float
    min_volts: float = 0.25

    def distance_m(self, volts: float) -> float | None:
        if not volts > self.min_volts:
            return None
        return self.a * volts ** self.b / 100.0


SHARP_CURVES: dict[str, SharpCurve] = {
    "ir-4-30": SharpCurve(a=12.08, b=-1.058),    # GP2Y0A41SK0F
    "ir-10-80": SharpCurve(a=29.988, b=-1.173),  # GP2Y0A21YK0F
    "ir-20-150": SharpCurve(a=60.374, b=-1.16),  # GP2Y0A02YK0F
}
"""Voltage → distance of the thesis's three models (fits of Sharp's datasheet curves)."""


class Ads1115Ranger(_I2cDevice):
    """A Sharp analog ranger on one ADS1115 channel (``range.ads1115``)."""

    CONVERSION = 0x00
    CONFIG = 0x01
    FULL_SCALE_V = 4.096
    MAX_POLLS = 20

    def __init__(self, *, bus: SMBusLike, address: int, channel: int, curve: SharpCurve,
                 owns_bus: bool = False, model: str | None = None) -> None:
        super().__init__(bus=bus, address=address, owns_bus=owns_bus)
        if channel not in range(4):
            raise ValueError(f"ADS1115 channel must be 0–3, got {channel}")
        self.channel = channel
        self.curve = curve
        self.model = model
        """The ranger model whose curve this reads (the range device checks that its own
        ``model``, whose limits it applies, is the same)."""
        # Start a single conversion (OS), AINx against GND, ±4.096 V, single-shot, 860 SPS,
        # comparator off.
        self.config = (1 << 15) | ((4 + channel) << 12) | (1 << 9) | (1 << 8) | (7 << 5) | 3

    def volts(self) -> float:
        with self._lock:
            self._write(self.CONFIG, [self.config >> 8, self.config & 0xFF])
            for _ in range(self.MAX_POLLS):  # ~1.2 ms at 860 SPS; each poll is a transaction
                high, _low = self._read(self.CONFIG, 2)
                if high & 0x80:  # OS set again: the conversion finished
                    break
            else:
                raise self._error("conversion never finished", OSError("timeout"))
            high, low = self._read(self.CONVERSION, 2)
        raw = (high << 8) | low
        if raw & 0x8000:
            raw -= 1 << 16
        return raw * self.FULL_SCALE_V / 32768.0

    def distance_m(self, mount: MountPose, *, max_range_m: float) -> float | None:
        return self.curve.distance_m(self.volts())


Address = Annotated[int, msgspec.Meta(ge=0x03, le=0x77)]


def _open_bus(bus: int, *, who: str) -> Any:
    smbus2 = hardware.require("smbus2", who=who)
    try:
        return smbus2.SMBus(bus)
    except OSError as exc:
        raise ConfigurationError(
            f"{who}: cannot open /dev/i2c-{bus}: {exc} (is I²C enabled, and are you in the "
            f"i2c group? docs/hardware.md)") from None


def i2c_backend(
    *,
    context: DeviceContext,
    bus: Annotated[int, msgspec.Meta(ge=0, le=255)] = 1,
    address: Address = 0x40,
    layout: Literal["gp2y0e", "mm16"] = "gp2y0e",
    register: Annotated[int, msgspec.Meta(ge=0, le=255)] = 0x00,
) -> DigitalRanger:
    """``range.i2c``: a digital ranger at ``address`` on ``/dev/i2c-<bus>``; ``layout``
    ``gp2y0e`` (Sharp GP2Y0E02B/03) or ``mm16`` (millimetres in the 16-bit big-endian
    ``register``)."""
    return DigitalRanger(bus=_open_bus(bus, who="range.i2c"), address=address, layout=layout,
                         register=register, owns_bus=True)


def ads1115_backend(
    *,
    context: DeviceContext,
    sensor: Literal["ir-4-30", "ir-10-80", "ir-20-150"],
    channel: Annotated[int, msgspec.Meta(ge=0, le=3)] = 0,
    bus: Annotated[int, msgspec.Meta(ge=0, le=255)] = 1,
    address: Address = 0x48,
) -> Ads1115Ranger:
    """``range.ads1115``: a Sharp analog ranger (``sensor``: the thesis model, whose
    voltage → distance curve it reads; it must be the device's ``model``, whose limits apply —
    the device refuses another) on ``channel`` of an ADS1115 at ``address`` on
    ``/dev/i2c-<bus>``."""
    return Ads1115Ranger(bus=_open_bus(bus, who="range.ads1115"), address=address,
                         channel=channel, curve=SHARP_CURVES[sensor], owns_bus=True,
                         model=sensor)


i2c_backend.requires_simulator = None  # type: ignore[attr-defined]
ads1115_backend.requires_simulator = None  # type: ignore[attr-defined]
