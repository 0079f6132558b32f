"""The typed seam between launch and a simulator, and what device backends are given.

A simulator is a plug-in (entry-point group ``ubf_async.simulators``) like any other: launch
never imports one by module name. It provides

* the *world* that simulated device backends read and drive (handed to backend factories as
  :attr:`DeviceContext.simulation`), and
* a :class:`OpenSimulation`: simulated time, the simulator's own components, a status-line
  suffix and, at the end, a summary.

A device's backend that needs a simulator says which (its factory's ``requires_simulator``
attribute, e.g. ``"mini-whegs"``); launch starts that simulator only when some device of the
robot file needs it, so a robot whose devices are real or remote runs without one.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, TextIO, runtime_checkable

# DeviceContext lives in its own low module so devices and robotfile need not import this one
# (which stands above them); re-exported here, where plug-ins have always found it.
from ubf_async.assembly.context import DeviceContext as DeviceContext

if TYPE_CHECKING:
    from ubf_async.assembly.body import BodySpec
    from ubf_async.assembly.robotfile import ResolvedDevice
    from ubf_async.clocks.clock import SimClock
    from ubf_async.runtime.bus import Bus
    from ubf_async.runtime.component import Component
    from ubf_async.runtime.controller import Controller

__all__ = ["CONTROLLER_SUMMARY_FIELDS", "FLAT_OUT", "FleetMember", "OpenSimulation",
           "SimulationOptions", "Simulator", "TurnRig", "describe_speed"]


@dataclass(frozen=True, slots=True, kw_only=True)
class SimulationOptions:
    """What a user asks of a simulated run (launch's ``--scenario``, ``--speed`` …)."""

    scenario: str | None = None
    """A built-in scenario name or a scenario file; ``None``: the simulator's default."""
    speed: float = 1.0
    """Simulated seconds per wall second asked for (> 0); ``math.inf``: flat out."""
    seed: int | None = None
    """Seed of every random source; ``None``: the scenario's."""
    duration_s: float | None = None
    """Simulated seconds to run; ``None``: the scenario's when one was named, else forever."""
    summary_path: Path | None = None
    trajectory_path: Path | None = None
    """Stream every trajectory sample (20 a simulated second) to this CSV as the run goes;
    with ``record_dir`` it is ``record_dir/trajectory.csv``."""
    record_dir: Path | None = None
    record_every_s: float = 2.0
    keep_trajectory: bool = False
    """Keep every trajectory sample in memory, for :meth:`OpenSimulation.trajectory` (a library
    run's result); otherwise only a bounded, decimated history is kept."""
    judge_open_ended: bool = False
    """Judge the scenario's expected outcome at the end of a run with no set length (no
    ``duration_s``, no named scenario), stopped whenever its user stopped it; otherwise it is
    said to be not judged: an outcome describes the end of a whole run."""
    lockstep_participants: int = 0
    """Hold simulated time at its start until this many lockstep participants of other
    processes have joined (:mod:`ubf_async.clocks.lockstep`)."""
    command_line: tuple[str, ...] = ()
    """How the run was started (for its summary)."""
    body: BodySpec | None = None
    """The robot's body (its robot file's ``body``); ``None``: the simulator's own robot."""
    camera_x_m: float | None = None
    """Where the robot's first camera sits ahead of its centre; ``None``: the simulator's
    default (scenarios place objects "from the camera", the summary measures from it)."""


@runtime_checkable
class OpenSimulation(Protocol):
    """One simulated run, as launch drives it. Every method runs on the event loop."""

    @property
    def seed(self) -> int: ...

    @property
    def duration_s(self) -> float | None:
        """Simulated seconds to run, or ``None`` to run until stopped."""
        ...

    @property
    def world(self) -> Any:
        """What simulated backends are given as :attr:`DeviceContext.simulation`."""
        ...

    def describe(self) -> str:
        """One line for launch's banner."""
        ...

    def components(self) -> list[Component]:
        """The simulator's own components (started after the devices)."""
        ...

    def add_devices(self, devices: list[Component]) -> None:
        """The robot's devices, once built (for the summary's counts)."""
        ...

    def status_suffix(self) -> str:
        ...

    def elapsed_s(self) -> float:
        ...

    def start(self, controller: Controller) -> None:
        """Called once every component runs."""
        ...

    async def until_elapsed(self, duration_s: float) -> None:
        ...

    async def finish(self, controller: Controller, out: TextIO) -> dict[str, Any]:
        """Stop, write the summary and recording asked for, return the summary; what it
        reports goes to ``out`` after everything is written."""
        ...

    def summary(self, controller: Controller) -> dict[str, Any]:
        """The run's summary as it stands (what launch prints when :meth:`finish` failed)."""
        ...

    def trajectory(self) -> list[dict[str, Any]]:
        """Every sample of the run's trajectory, one map per ``trajectory.csv`` row (its
        columns, in order); empty unless the options asked to ``keep_trajectory``."""
        ...


@dataclass(frozen=True, slots=True, kw_only=True)
class FleetMember:
    """One robot of a fleet, as the world process hosts it: its name, its devices whose
    backends need the simulator (built on its own bus ``ubf/<name>/…``), and where it
    starts."""

    name: str
    devices: tuple[ResolvedDevice, ...]
    x_m: float
    y_m: float
    heading_deg: float = 0.0


class TurnRig(Protocol):
    """Drives a simulated robot with a fixed drive command and reports what happened
    (``python -m components.encoders.calibrate`` fits the effective track from it)."""

    def drive(self, *, speed: float, turn: float, settle_s: float,
              measure_s: float) -> tuple[float, float, float]:
        """Drive ``speed``/``turn`` (through the motors' pulse calibration, the rig's business)
        for ``settle_s`` (not measured), then ``measure_s`` more; return ``(Δθ_left, Δθ_right,
        true yaw)`` in radians over the measured part."""
        ...


class Simulator(Protocol):
    """A simulator plug-in (what a ``ubf_async.simulators`` entry point names). A plug-in
    deriving from it gets the defaults of its optional members (:meth:`turn_rig`)."""

    name: str

    def check(self, options: SimulationOptions) -> None:
        """Refuse, before anything starts, whatever :meth:`open` would refuse (a bad speed, an
        unknown or invalid scenario …): launch runs it before the bus opens, and
        ``launch --check`` runs exactly it. Raises :class:`~ubf_async.errors.UbfError`."""
        ...

    def open(self, *, bus: Bus, clock: SimClock, options: SimulationOptions) -> OpenSimulation:
        """Build a run (raises :class:`~ubf_async.errors.ConfigurationError` on bad options)."""
        ...

    async def attach(self, *, bus: Bus, seed: int, wait_s: float) -> Any:
        """The world of a simulator running in another process, for a device started on its
        own (``python -m components.<device>``); raises ``ConnectionError`` if none answers
        within ``wait_s``. The caller closes it with its ``close()``."""
        ...

    def scenario_names(self) -> list[str]:
        """Built-in scenarios, for ``--help``."""
        ...

    async def host_fleet(self, *, buses: Sequence[Bus], clock: SimClock,
                         members: Sequence[FleetMember], options: SimulationOptions,
                         out: TextIO) -> dict[str, Any]:
        """Run one world holding every member (``buses[i]`` is member ``i``'s, all on
        ``clock``), their simulated devices and simulated time, until ``options.duration_s``
        (or cancelled); return a summary per robot (``python -m ubf_async.fleet``)."""
        ...

    def turn_rig(self) -> TurnRig:
        """A :class:`TurnRig` on this simulator's robot. By default none: a
        :class:`~ubf_async.errors.ConfigurationError` saying so."""
        from ubf_async.errors import ConfigurationError

        raise ConfigurationError(f"simulator {self.name!r} offers no turn rig")


CONTROLLER_SUMMARY_FIELDS = ("ticks", "periodic_rate_hz", "periodic_jitter_robot_ms_p99",
                             "overruns", "errors", "winner_share")
"""What a fleet's summary keeps of each robot's controller status (all in robot time)."""

FLAT_OUT = "max"
"""How a user asks for a flat-out simulation (``--speed max``)."""


def describe_speed(speed: float) -> str:
    """``5x real time``, or ``flat out`` for ``math.inf``."""
    return "flat out" if speed == math.inf else f"{speed:g}x real time"
