"""The simulator records how late each step starts after its due wall time (what every
follower of its clock inherits as tick jitter), and the fleet's world summary reports it."""

from __future__ import annotations

import time

import pytest

from components.sim.runner.run import lateness_summary
from components.sim.runner.stepper import SimulatorComponent
from components.sim.world.config import WorldConfig
from components.sim.world.physics import World
from ubf_async.clocks.clock import SimClock
from ubf_async.net.inprocess import InProcessTransport
from ubf_async.runtime.bus import Bus


def test_the_summary_gives_median_p99_and_worst_in_ms() -> None:
    assert lateness_summary([]) is None
    summary = lateness_summary([i / 1000 for i in range(101)])  # 0 … 100 ms
    assert summary == pytest.approx({"steps": 101, "median_ms": 50.0, "p99_ms": 99.0,
                                     "max_ms": 100.0})


@pytest.mark.asyncio
async def test_a_step_held_up_by_the_loop_is_recorded_as_late() -> None:
    clock = SimClock()
    bus = Bus(transport=InProcessTransport(), robot="late", clock=clock)
    sim = SimulatorComponent(bus=bus, world=World(WorldConfig()), clock=clock, speed=1.0)
    await sim.start()
    try:
        await clock.sleep(0.1)
        time.sleep(0.05)  # noqa: ASYNC251  (the stimulus: something holds the loop 50 ms)
        await clock.sleep(0.1)
    finally:
        await sim.aclose()
    lateness = list(sim.step_lateness_s)
    assert len(lateness) >= 35  # about 40 steps of 5 ms in 0.2 simulated s
    assert all(late >= 0.0 for late in lateness)
    assert max(lateness) >= 0.045  # the held-up step
    # The schedule is absolute: the steps that fell due meanwhile ran back to back, then the
    # simulator was on time again.
    assert sorted(lateness)[len(lateness) // 2] < 0.045
