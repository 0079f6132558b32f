"""A simulator in another process, seen through the bus.

:class:`RemoteWorld` offers what the simulator backends (:mod:`components.sim.backends.devices`) use
of a :class:`~components.sim.world.physics.World` — ``snapshot()``, ``set_motor_pulses()``,
``config`` and ``make_rng()`` — from the snapshots the simulator publishes on
``ubf/<robot>/sim/world``, and sends motor pulses back on ``ubf/<robot>/sim/pulses``. So the
very same backends serve a device started with ``python -m components.<device>`` while
``python -m ubf_async.launch`` runs the simulation.
"""

from __future__ import annotations

import asyncio
import logging

import numpy as np

from components.sim.world.air import RadioAir
from components.sim.world.config import RobotConfig, WorldConfig
from components.sim.world.snapshot import WorldSnapshot
from components.sim.world.snapshot_data import snapshot_from_data
from ubf_async.runtime.bus import Bus, Publisher, Subscription
from ubf_async.wire.protocol import Message
from ubf_async.wire.topics import SIM_PULSES, SIM_WORLD, PlainData

__all__ = ["RemoteWorld"]

log = logging.getLogger(__name__)


class RemoteWorld:
    air: RadioAir | None = None
    """No radio air: the robots' ``radio.air`` is the world process's own."""
    index = 0
    """The one robot whose world this process mirrors."""

    def __init__(self, bus: Bus, *, seed: int = 0) -> None:
        self.bus = bus
        self.config = WorldConfig(robot=RobotConfig(), seed=seed)
        self.ready = asyncio.Event()
        """Set once the first world snapshot has arrived."""
        self.malformed: dict[str, int] = {}
        self._snapshot: WorldSnapshot | None = None
        self._sub: Subscription | None = None
        self._pulses: Publisher | None = None

    def start(self) -> None:
        keys = self.bus.keys
        self._sub = self.bus.subscribe_topic(SIM_WORLD.key(keys), SIM_WORLD, self._on_world,
                                             self.malformed)
        self._pulses = self.bus.publisher(SIM_PULSES)

    def close(self) -> None:
        if self._sub is not None:
            self._sub.close()
        if self._pulses is not None:
            self._pulses.close()

    async def wait_ready(self, timeout_s: float) -> None:
        try:
            await asyncio.wait_for(self.ready.wait(), timeout_s)
        except TimeoutError:
            raise ConnectionError(
                f"no simulator is publishing {SIM_WORLD.key(self.bus.keys)} "
                f"(waited {timeout_s:g} s):"
                " start one with python -m ubf_async.launch and pass its endpoint with --connect"
            ) from None

    def _on_world(self, key: str, message: Message[PlainData], received_ns: int) -> None:
        try:
            self._snapshot = snapshot_from_data(message.data)
        except ValueError as exc:
            self.malformed[key] = self.malformed.get(key, 0) + 1
            log.warning("rejected world snapshot on %s: %s", key, exc)
            return
        self.ready.set()

    # -- what the backends use of a World ------------------------------------------------------
    def snapshot(self) -> WorldSnapshot:
        if self._snapshot is None:
            raise RuntimeError("no world snapshot received yet (await wait_ready() first)")
        return self._snapshot

    def set_motor_pulses(self, left_ms: float, right_ms: float) -> None:
        if self._pulses is None:
            raise RuntimeError("RemoteWorld.start() was not called")
        self._pulses.publish({"left_ms": left_ms, "right_ms": right_ms})

    def make_rng(self, stream: int) -> np.random.Generator:
        return np.random.default_rng([self.config.seed, stream])
