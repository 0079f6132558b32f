"""The ``mini-whegs`` simulator plug-in (entry point ``ubf_async.simulators``).

:class:`MiniWhegsSimulator` implements :class:`ubf_async.assembly.simulation.Simulator`:

* :meth:`~MiniWhegsSimulator.open` builds a :class:`~components.sim.runner.run.SimulationRun` —
  the pymunk world of a scenario, the simulator component, simulated time, summary and
  recording — whose ``world`` the ``<kind>.sim`` backends (:mod:`components.sim.backends.devices`)
  are given;
* :meth:`~MiniWhegsSimulator.attach` gives a device started in its own process
  (``python -m components.<device>``) the world of a simulator running elsewhere, seen through
  the bus (:class:`~components.sim.mirror.remote_world.RemoteWorld`);
* :meth:`~MiniWhegsSimulator.host_fleet` runs one world holding a fleet of robots
  (:mod:`components.sim.runner.fleet_world`, for ``python -m ubf_async.fleet``).

Importing this module is cheap: the simulator's modules (pymunk, OpenCV) load on first use.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any, TextIO

from ubf_async.assembly.simulation import FleetMember, SimulationOptions, Simulator, TurnRig
from ubf_async.clocks.clock import SimClock
from ubf_async.runtime.bus import Bus

if TYPE_CHECKING:
    from components.sim.mirror.remote_world import RemoteWorld
    from components.sim.runner.run import SimulationRun

__all__ = ["MiniWhegsSimulator", "SimTurnRig"]


class SimTurnRig(TurnRig):
    """Drives the simulated Mini-WHEGS in an empty world with the pulses the motors' default
    calibration gives a drive command; the true yaw is the body's. Each drive starts afresh
    from rest."""

    def __init__(self, *, step_s: float = 0.005) -> None:
        self.step_s = step_s

    def drive(self, *, speed: float, turn: float, settle_s: float,
              measure_s: float) -> tuple[float, float, float]:
        from components.motors.pwm import pulse_widths
        from components.sim.world.physics import World

        pulses = pulse_widths(speed, turn)
        world = World()
        world.set_motor_pulses(pulses.left_ms, pulses.right_ms)
        for _ in range(round(settle_s / self.step_s)):
            world.advance(self.step_s)
        start = world.snapshot().robot
        for _ in range(round(measure_s / self.step_s)):
            world.advance(self.step_s)
        end = world.snapshot().robot
        return (end.left_wheel_angle_rad - start.left_wheel_angle_rad,
                end.right_wheel_angle_rad - start.right_wheel_angle_rad,
                end.heading_unwrapped_rad - start.heading_unwrapped_rad)


class MiniWhegsSimulator(Simulator):
    """The simulated Mini-WHEGS: a pymunk world, an OpenCV-rendered camera, scenarios."""

    name = "mini-whegs"

    def check(self, options: SimulationOptions) -> None:
        """What :meth:`open` refuses, refused without building anything: the options, and
        the scenario loaded and validated."""
        from components.sim.runner.run import check_options

        check_options(options)

    def open(self, *, bus: Bus, clock: SimClock, options: SimulationOptions) -> SimulationRun:
        """A run of ``options.scenario`` (default ``ball-in-sight``) on ``clock``.

        Raises :class:`~ubf_async.errors.ConfigurationError` for a speed ≤ 0 (or a bad
        duration or recording period) and :class:`~ubf_async.errors.ScenarioError` for an
        unknown or invalid scenario.
        """
        from components.sim.runner.run import SimulationRun

        return SimulationRun(bus=bus, clock=clock, options=options)

    async def attach(self, *, bus: Bus, seed: int, wait_s: float) -> RemoteWorld:
        """The world of the simulator publishing on ``bus``'s robot, started and holding its
        first snapshot. ``seed`` seeds the backends' noise in this process. Raises
        ``ConnectionError`` if no simulator publishes within ``wait_s`` seconds; the caller
        closes the world (``close()``) when done."""
        from components.sim.mirror.remote_world import RemoteWorld

        world = RemoteWorld(bus, seed=seed)
        world.start()
        try:
            await world.wait_ready(wait_s)
        except BaseException:
            world.close()
            raise
        return world

    def turn_rig(self) -> SimTurnRig:
        """A :class:`~ubf_async.assembly.simulation.TurnRig` on an empty simulated world, for
        ``python -m components.encoders.calibrate``."""
        return SimTurnRig()

    async def host_fleet(self, *, buses: Sequence[Bus], clock: SimClock,
                         members: Sequence[FleetMember], options: SimulationOptions,
                         out: TextIO) -> dict[str, Any]:
        """One world holding every robot of a fleet (:mod:`components.sim.runner.fleet_world`)."""
        from components.sim.runner.fleet_world import host_fleet

        return await host_fleet(buses=buses, clock=clock, members=members, options=options,
                                out=out)

    def scenario_names(self) -> list[str]:
        """The built-in scenarios (``components/sim/scenarios/files``)."""
        from components.sim.scenarios.scenario import builtin_names

        return builtin_names()
