"""One robot wired from a checked plan, and its ordered end: what launch runs behind its
command line and what :func:`ubf_async.runs.inprocess.run` runs in-process.

A :class:`RunPlan` is everything checked before anything starts (the robot file resolved, the
devices this process builds, the simulator and its options, the controller's settings). A
:class:`RobotRun` holds what has been opened so far on one bus; :func:`build_robot` builds the
devices, the state aggregator, the controller with the robot's tree, the remote behaviours'
slots and the live-tree service (and opens the simulation when a device needs one);
:func:`add_clock_components` adds what keeps time; :func:`start` starts it all; :func:`end`
saves the results and closes everything, whatever ended the run.

Nothing here opens a session or reads a command line: the caller gives the bus (a zenoh
session for launch, the in-process transport for a library run) and the console (``out``).
"""

from __future__ import annotations

import io
import json
import logging
from collections.abc import Callable, Collection, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, TextIO

from ubf_async.assembly.context import DeviceContext
from ubf_async.assembly.robotfile import ResolvedDevice, Robot
from ubf_async.assembly.simulation import OpenSimulation, SimulationOptions, Simulator
from ubf_async.cli import ending
from ubf_async.clocks.clock import Clock, SimClock
from ubf_async.clocks.simclock import follow_sim_clock
from ubf_async.errors import ConfigurationError, ResultsNotSavedError, ShutdownError
from ubf_async.net.options import ConnectionOptions
from ubf_async.runtime import timekeepers
from ubf_async.runtime.aggregator import StateAggregator
from ubf_async.runtime.bus import Bus
from ubf_async.runtime.component import Component, HealthMonitor
from ubf_async.runtime.controller import Controller, TickMode
from ubf_async.runtime.timekeepers import RobotTimeBeacon
from ubf_async.services.live import TreeService
from ubf_async.services.remote import RemoteBehaviors
from ubf_async.services.status import planned_ticks

__all__ = [
    "CLOSE_BOUND_S",
    "EXIT_DEGRADED",
    "RESULTS_BOUND_S",
    "ControllerSettings",
    "RobotRun",
    "RunPlan",
    "add_clock_components",
    "bodied",
    "build_robot",
    "end",
    "open_simulation",
    "print_unsaved_summary",
    "simulation_plan",
    "simulator_needed",
    "start",
]

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True, kw_only=True)
class ControllerSettings:
    """The robot file's ``controller:``, with whatever overrides it (launch's flags)."""

    mode: TickMode
    rate_hz: float
    reflex: tuple[str, ...]
    sync_source: str
    trigger: str | None
    lane: bool = True
    """Triggered ticks on the reflex lane (the robot file's ``controller: lane``)."""

    @classmethod
    def of(cls, robot: Robot, *, mode: str | None = None, rate_hz: float | None = None,
           trigger: str | None = None, reflex: list[str] | None = None) -> ControllerSettings:
        """The robot file's settings, each overridden where given. Raises
        :class:`ConfigurationError`."""
        spec = robot.spec.controller
        tick_mode = TickMode(mode or spec.mode)
        rate_hz = spec.rate_hz if rate_hz is None else rate_hz
        if not rate_hz > 0:
            raise ConfigurationError(f"--rate-hz must be > 0, got {rate_hz:g}")
        trigger = trigger or spec.trigger
        if tick_mode is TickMode.EVENT and not trigger:
            raise ConfigurationError("--tick event needs --trigger SOURCE (or `trigger:` in "
                                     "the robot file's controller)")
        prefixes = spec.reflex if reflex is None else reflex
        return cls(mode=tick_mode, rate_hz=rate_hz, reflex=tuple(p for p in prefixes if p),
                   sync_source=spec.sync_source, trigger=trigger, lane=spec.lane)

    def planned(self, sources: Collection[str]) -> str:
        """What will tick the controller, in the status line's terms, given the robot's own
        ``sources`` (``kind/name`` of its devices, here or elsewhere)."""
        return planned_ticks(self.mode, rate_hz=self.rate_hz, reflex=self.reflex,
                             sync_source=self.sync_source, trigger=self.trigger,
                             sources=sources)


@dataclass(slots=True, kw_only=True)
class RunPlan:
    """Everything checked before the robot starts."""

    robot: Robot
    devices: list[ResolvedDevice]
    """Devices this process builds."""
    elsewhere: list[ResolvedDevice]
    """Devices of the file left to other processes (``--no-sim`` with simulated backends)."""
    simulator: Simulator | None
    sim_options: SimulationOptions | None
    controller: ControllerSettings
    connection: ConnectionOptions
    """The bus's options (for launch: the flags given over the ``--config`` file over its
    default listen endpoint)."""
    seed_given: bool = False
    """Whether the seed was chosen by the caller (``--seed``): then the robot file was loaded
    with it; otherwise the behaviours draw from the simulated run's seed."""
    remotes: dict[str, tuple[int, float]] = field(default_factory=dict)
    """Places of remote behaviours beyond the robot file's slots (``--remote``)."""
    lockstep: bool = False
    """Take part in the lockstep of a simulator of another process (``--lockstep``)."""
    helper_processes: bool = True
    """Whether devices may start helper processes (:class:`DeviceContext`)."""
    follow_clock: bool = True
    """With a simulated clock and no simulator in the plan: follow the simulation time a
    simulator elsewhere publishes. ``False`` when a simulator of this process drives the clock
    (an in-process fleet's world)."""
    status_on_robot_clock: bool = False
    """The controller's status period is measured in robot time (each status is of a
    simulated instant: what a fleet's world collects), not wall time."""

    def sources(self) -> list[str]:
        """The robot file's sources (``kind/name``) this run has: its devices here and those
        left to other processes."""
        return [f"{d.kind}/{d.name}" for d in (*self.devices, *self.elsewhere)]


def simulator_needed(robot: Robot, devices: Sequence[ResolvedDevice]) -> str | None:
    """The simulator ``devices`` of ``robot`` need (their backends say), if any. Raises
    :class:`ConfigurationError` when they need several: one robot runs in one."""
    simulators = sorted({d.requires_simulator for d in devices if d.requires_simulator})
    if len(simulators) > 1:
        raise ConfigurationError(f"{robot.source}: devices need several simulators "
                                 f"({', '.join(simulators)}); one robot runs in one")
    return simulators[0] if simulators else None


def bodied(options: SimulationOptions, robot: Robot) -> SimulationOptions:
    """``options`` with what the simulator builds of ``robot``: its body, and where its first
    camera sits (scenarios place things "from the camera", the summary measures from it)."""
    return replace(options, body=robot.body, camera_x_m=robot.mount_x_m("camera"))


def simulation_plan(robot: Robot, options: SimulationOptions, *, simulator: Simulator,
                    connection: ConnectionOptions) -> RunPlan:
    """The plan of a simulated run of every device of ``robot`` in this process, with the robot
    file's controller; ``options`` checked by the simulator (raises
    :class:`~ubf_async.errors.UbfError`)."""
    simulator.check(options)
    return RunPlan(robot=robot, devices=list(robot.devices), elsewhere=[], simulator=simulator,
                   sim_options=options, controller=ControllerSettings.of(robot),
                   connection=connection, seed_given=options.seed is not None)


@dataclass(slots=True, kw_only=True)
class RobotRun:
    """What a run has opened so far: whatever ended the run, :func:`end` closes all of it."""

    bus: Bus
    clock: Clock
    health: HealthMonitor
    components: list[Component] = field(default_factory=list)
    """In the order they start; closed in the reverse order."""
    sim_run: OpenSimulation | None = None
    controller: Controller | None = None
    aggregator: StateAggregator | None = None
    remotes: RemoteBehaviors | None = None
    devices: list[Component] = field(default_factory=list)
    seed: int = 0
    """The run's seed: the simulator's, else the robot file's, else 0."""
    robot: Robot | None = None
    """The robot as it runs (reseeded with the run's seed when simulated)."""
    end_notes: list[Callable[[], str]] = field(default_factory=list)
    """Lines the end prints once everything is closed (a recorder's count, say)."""
    summary: dict[str, Any] | None = None
    """The simulated run's summary, once :func:`end` has saved it."""

    @classmethod
    def on(cls, bus: Bus) -> RobotRun:
        return cls(bus=bus, clock=bus.clock, health=HealthMonitor(bus))


def open_simulation(plan: RunPlan, run: RobotRun, out: TextIO) -> int:
    """The planned simulator opened on the bus, or (a simulated clock without one here) the
    simulation time of one elsewhere followed; says which devices come from elsewhere. Returns
    the run's seed: the simulator's, else the robot file's, else 0."""
    seed = plan.robot.spec.seed or 0
    if plan.simulator is not None and plan.sim_options is not None:
        assert isinstance(run.clock, SimClock)
        run.sim_run = plan.simulator.open(bus=run.bus, clock=run.clock,
                                          options=bodied(plan.sim_options, plan.robot))
        seed = run.sim_run.seed
        print(f"  {run.sim_run.describe()}", file=out)
    elif isinstance(run.clock, SimClock) and plan.follow_clock:
        follow_sim_clock(run.bus, run.clock, {})
        print(f"  no simulator here: following the simulation time on {run.bus.keys.clock}",
              file=out)
    if plan.elsewhere:
        print("  not started here (their backends need the simulator; attach them from "
              "other processes): " + ", ".join(f"{d.kind}/{d.name}" for d in plan.elsewhere),
              file=out)
    if not plan.devices and not plan.elsewhere and run.sim_run is None:
        print("  no devices here: waiting for devices to attach over zenoh", file=out)
    return seed


def build_robot(plan: RunPlan, run: RobotRun, out: TextIO) -> None:
    """The simulation (if planned), the devices, and the control: the state aggregator, the
    controller with the robot's tree, the remote behaviours' slots and the live-tree service —
    added to ``run.components`` in the order they start, nothing started yet."""
    seed = run.seed = open_simulation(plan, run, out)
    robot = plan.robot
    if run.clock.is_simulated and not plan.seed_given and seed != robot.spec.seed:
        # The behaviours draw from the run's seed (a controller following a simulator
        # elsewhere: the file's, else 0), so a simulated run is repeatable.
        robot = robot.reseeded(seed)
    run.robot = robot
    run.devices = _build_devices(plan, run, seed)
    _build_control(plan, robot, run, seed)


def _build_devices(plan: RunPlan, run: RobotRun, seed: int) -> list[Component]:
    """This process's devices, built through the plug-in registries (not started yet)."""
    context = DeviceContext(bus=run.bus, clock=run.clock, seed=seed,
                            simulation=run.sim_run.world if run.sim_run is not None else None,
                            helper_processes=plan.helper_processes, body=plan.robot.body)
    devices: list[Component] = []
    try:
        for device in plan.devices:
            devices.append(device.build(context=context))
    except BaseException:  # the ones built hold their pins and buses: closed at the end
        run.components += devices
        raise
    return devices


def _build_control(plan: RunPlan, robot: Robot, run: RobotRun, seed: int) -> None:
    """The state aggregator, the controller with the robot's tree, the remote behaviours'
    slots and the live-tree service, added to the run's components, after them the devices."""
    spec = robot.spec
    settings = plan.controller
    # The robot's own sources are never evicted to make room for unknown ones.
    protected = set(plan.sources())
    protected.update(s for s in (settings.sync_source, settings.trigger) if s)
    aggregator = run.aggregator = StateAggregator(
        bus=run.bus, stale_after_s=spec.controller.stale_after_s,
        default_stale_after_s=spec.controller.default_stale_after_s,
        protected_sources=protected, notify_refusals=True, departures=run.health,
        fused=spec.controller.fusions())
    root = robot.root
    controller = run.controller = Controller(
        bus=run.bus, aggregator=aggregator, root=root, rate_hz=settings.rate_hz,
        mode=settings.mode, sync_source=settings.sync_source, trigger=settings.trigger,
        reflex_sources=settings.reflex, lane=settings.lane,
        # In lockstep each status is of a simulated instant (a fleet's world reads them).
        status_clock=run.clock if plan.status_on_robot_clock else None,
    )
    remotes = run.remotes = RemoteBehaviors(
        bus=run.bus, root=root, config={**robot.remote_config(), **plan.remotes},
        only_configured=spec.remotes.only_declared,
        default_ttl_s=spec.remotes.default_ttl_s, max_ttl_s=spec.remotes.max_ttl_s,
        max_remotes=spec.remotes.max_remotes, notify_refusals=True, lock=controller.lock,
    )
    tree_service = TreeService(bus=run.bus, controller=controller, remotes=remotes, seed=seed,
                               slots=robot.remotes)
    run.components += [aggregator, controller, remotes, tree_service, *run.devices]


def add_clock_components(plan: RunPlan, run: RobotRun) -> None:
    """What keeps time with other processes: the robot's clock for other hosts (wall time),
    the lockstep participant (``--lockstep``), or the simulator's own components."""
    if not run.clock.is_simulated:  # its clock, for processes on other hosts
        run.components.append(RobotTimeBeacon(bus=run.bus))
    if plan.lockstep:  # last started: the simulator waits for it once all else runs
        assert run.controller is not None
        run.components.append(timekeepers.LockstepParticipant(bus=run.bus,
                                                           participant=run.controller.name))
    if run.sim_run is not None:
        run.sim_run.add_devices(run.devices)
        run.components += run.sim_run.components()


async def start(run: RobotRun) -> None:
    """Every component started in order, then the simulation."""
    assert run.remotes is not None and run.controller is not None, "build_robot first"
    # No remote behaviour may vote under the name of one of the robot's own components.
    run.remotes.reserve(c.name for c in run.components)
    run.health.start()
    for component in run.components:
        await component.start()
    if run.sim_run is not None:
        run.sim_run.start(run.controller)


RESULTS_BOUND_S = 30.0
"""Wall time the end gives to writing the run's summary and recording (the summary first):
long enough for a loaded machine's plot and last frame, short of a write stuck for ever. After
a stop signal the whole stop is bounded tighter (:data:`ubf_async.cli.run.STOP_BOUND_S`)."""
CLOSE_BOUND_S = 5.0
"""Wall time the end gives to closing one component (a recorder drains its queue for a
bounded time) or the session."""

EXIT_DEGRADED = 3
"""The run ended and its results were saved, but it was not the robot file's run: a behaviour
was quarantined (it kept failing and stopped voting) or the tree was changed live."""


async def end(run: RobotRun, out: TextIO, *, saving: bool = False) -> int:
    """The end of a run, whatever ended it (:class:`~ubf_async.cli.ending.Ending`): the results
    written, every component closed (last started first: a recorder sees everything), the bus
    closed — each step bounded, each done even if one before failed — and only then the report
    printed. ``saving``: results are written (a summary, a recording), which may take a while,
    so it is said first. Results that could not be written are printed instead
    (:class:`ResultsNotSavedError`); any other failed step ends in :class:`ShutdownError`.
    Otherwise returns 0, or :data:`EXIT_DEGRADED`."""
    done = ending.Ending(log)
    controller, sim_run = run.controller, run.sim_run
    degraded = []
    if controller is not None:
        if quarantined := controller.quarantined():
            degraded.append(f"quarantined: {', '.join(quarantined)}")
        if controller.tree_changes:
            degraded.append(f"the tree was changed live {len(controller.tree_changes)} time(s)")
    report = io.StringIO()  # printed last: a console that went away cannot cost a result
    unsaved = False
    if sim_run is not None and controller is not None:
        if saving:
            print("  saving the run's results ...", file=out)
            out.flush()
        sim = sim_run
        run.summary = await done.step("saving the run's results",
                                      lambda: sim.finish(controller, report),
                                      bound_s=RESULTS_BOUND_S)
        unsaved = run.summary is None
    for component in reversed(run.components):
        await done.step(f"closing {component.name}", component.aclose, bound_s=CLOSE_BOUND_S)
    run.health.close()
    await done.step("closing the session", run.bus.aclose, bound_s=CLOSE_BOUND_S,
                    overrun_is_failure=False)
    out.write(report.getvalue())
    for note in run.end_notes:
        print(note(), file=out)
    if unsaved and sim_run is not None and controller is not None:
        print_unsaved_summary(sim_run, controller, done, out)
    print("ubf_async: stopped" + (f", but not as the robot file describes ({'; '.join(degraded)})"
                                  if degraded else ""), file=out)
    out.flush()
    if unsaved:
        raise ResultsNotSavedError(f"could not save the run's results ({done.failures[0]}); "
                                   f"its summary was printed instead")
    if not done.ok:
        raise ShutdownError(f"the run ended, but {'; '.join(done.failures)}")
    return EXIT_DEGRADED if degraded else 0


def print_unsaved_summary(sim_run: OpenSimulation, controller: Controller,
                          done: ending.Ending, out: TextIO) -> None:
    """The results were not written (a full disk, a folder removed during the run, a write
    stuck past its bound): print the summary as JSON so they are not lost."""
    try:
        summary = sim_run.summary(controller)
    except Exception as exc:
        done.fail("making the run's summary", f"{type(exc).__name__}: {exc}")
        return
    print("ubf_async: the run's summary, not saved:", file=out)
    print(json.dumps(summary, indent=2, default=str), file=out)
