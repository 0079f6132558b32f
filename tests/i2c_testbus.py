"""A test bus at the smbus2 seam: what the I²C range backends read, served as the kernel's i2c-dev
would serve it (register maps per address, bus errors on demand, an ADS1115's conversion)."""

from __future__ import annotations

import errno
import threading

from components.range.i2c import Ads1115Ranger


class TestBus:
    """Serves register reads of the devices on it, as the kernel's i2c-dev would: a register
    map per address, ``fail`` transactions raising EREMOTEIO (a device that does not answer),
    and for an ADS1115 a conversion that finishes ``conversion_polls`` reads after it starts."""

    __test__ = False

    def __init__(self) -> None:
        self.registers: dict[int, dict[int, list[int]]] = {}
        self.fail = 0
        self.conversion_polls = 1
        self.writes: list[tuple[int, int, list[int]]] = []
        self.threads: set[int] = set()
        self._polls = 0
        self.closed = False
        self.ads: set[int] = set()
        """Addresses that answer as an ADS1115 (conversion-ready bit in the config)."""

    def _transaction(self, address: int) -> dict[int, list[int]]:
        self.threads.add(threading.get_ident())
        if self.fail:
            self.fail -= 1
            raise OSError(errno.EREMOTEIO, "Remote I/O error")
        if address not in self.registers:
            raise OSError(errno.ENXIO, "No such device or address")
        return self.registers[address]

    def read_i2c_block_data(self, i2c_addr: int, register: int, length: int) -> list[int]:
        device = self._transaction(i2c_addr)
        if register == Ads1115Ranger.CONFIG and i2c_addr in self.ads:
            self._polls += 1
            ready = self._polls >= self.conversion_polls
            high = device[register][0]
            return [(high | 0x80) if ready else (high & 0x7F), device[register][1]]
        return device[register][:length]

    def write_i2c_block_data(self, i2c_addr: int, register: int, data: list[int]) -> None:
        device = self._transaction(i2c_addr)
        self.writes.append((i2c_addr, register, list(data)))
        device[register] = list(data)
        self._polls = 0

    def read_byte_data(self, i2c_addr: int, register: int) -> int:
        return self._transaction(i2c_addr)[register][0]

    def close(self) -> None:
        self.closed = True


def gp2y0e(bus: TestBus, *, distance_cm: float, shift: int = 2) -> None:
    raw = round(distance_cm * 16 * (1 << shift))
    bus.registers[0x40] = {0x35: [shift], 0x5E: [raw >> 4, raw & 0x0F]}


def ads1115(bus: TestBus, *, volts: float) -> None:
    raw = round(volts / 4.096 * 32768)
    bus.registers[0x48] = {0x00: [(raw >> 8) & 0xFF, raw & 0xFF], 0x01: [0x85, 0x83]}
    bus.ads.add(0x48)
