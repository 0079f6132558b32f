"""One simulated run as a library call: :func:`run` (public as :mod:`ubf_async.experiment`).

A simulated run is a pure function of (robot file, scenario, seed): simulated time advances in
lockstep (:mod:`ubf_async.clocks.lockstep`), so the run is the same at any speed, on any
machine, under any load. :func:`run` runs it in the calling process, flat out, exactly as
``python -m ubf_async.launch ROBOT --scenario S --seed N --speed max`` does — the same wiring
(:mod:`ubf_async.runs.wiring`), the same simulator — with three differences that change
nothing of the run:

* the bus is the in-process transport (no zenoh session, no socket);
* nothing is printed, and nothing is written unless ``out_dir`` is given (then
  ``trajectory.csv`` and ``summary.json`` there, as launch's ``--record``/``--summary`` write
  them; ``pictures=True`` adds the plot and the annotated camera frames);
* the devices start no helper process (a simulated camera renders in a thread of this
  process: the same frames).

It starts its own event loop (the lockstep needs one that tells when it is idle) and leaves no
thread or process behind. Each call builds everything afresh — the robot's tree, the world, the
clock — so two calls with the same arguments give the same result, whatever ran before.
"""

from __future__ import annotations

import asyncio
import io
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ubf_async.assembly.registry import SIMULATORS
from ubf_async.assembly.robotfile import Robot, load_robot
from ubf_async.assembly.simulation import SimulationOptions
from ubf_async.clocks.clock import SimClock
from ubf_async.errors import ConfigurationError
from ubf_async.net.inprocess import InProcessTransport
from ubf_async.net.options import ConnectionOptions
from ubf_async.runs import wiring
from ubf_async.runtime import lending
from ubf_async.runtime.bus import Bus

__all__ = ["SUMMARY_FILE", "TRAJECTORY_FILE", "RunResult", "own_loop", "plan_run", "run",
           "run_async", "run_plan"]

SUMMARY_FILE = "summary.json"
TRAJECTORY_FILE = "trajectory.csv"


@dataclass(frozen=True, slots=True)
class RunResult:
    """What one run gives, as data."""

    summary: dict[str, Any]
    """The summary launch writes with ``--summary`` (docs/scenarios.md, Outputs)."""
    trajectory: list[dict[str, Any]]
    """Every trajectory sample (20 a simulated second), one map per ``trajectory.csv`` row:
    ``t_s``, the robot's pose, the ball's position, the drive command and the winners."""

    @property
    def expected(self) -> dict[str, Any] | None:
        """The scenario's expected outcome judged on this run (``None`` when the scenario
        states none): ``outcome``, ``criteria`` (each with its ``pass``), ``pass``."""
        expected: dict[str, Any] | None = self.summary.get("expected")
        return expected

    @property
    def verdicts(self) -> list[dict[str, Any]]:
        """Each criterion of the expected outcome with its value and ``pass``."""
        return list(self.expected["criteria"]) if self.expected else []

    @property
    def passed(self) -> bool | None:
        """Whether every criterion was met; ``None`` when nothing was judged (no criteria,
        or the robot lacks a behaviour the outcome describes)."""
        return self.expected["pass"] if self.expected else None


def run(robot: str | Path | Robot, scenario: str | Path, *, seed: int | None = None,
        duration_s: float | None = None, out_dir: str | Path | None = None,
        pictures: bool = False) -> RunResult:
    """Run ``robot`` through ``scenario`` in this process, flat out, and return the result.

    ``robot``: a robot file's path, a shipped robot's name (``mini-whegs``), or a loaded
    :class:`~ubf_async.assembly.robotfile.Robot` (e.g. from
    :func:`ubf_async.runs.overrides.load_robot_with`; it is not changed: each run builds its
    tree afresh). ``scenario``: a built-in scenario's name or a scenario file. ``seed``: of
    every random source (default: the scenario's). ``duration_s``: simulated seconds (default:
    the scenario's). ``out_dir``: write ``trajectory.csv`` and ``summary.json`` there (and,
    with ``pictures``, ``trajectory.png`` and camera frames).

    Raises :class:`~ubf_async.errors.UbfError` (a bad robot file, scenario or option) before
    anything runs, and :class:`~ubf_async.errors.ShutdownError` if the run could not end
    cleanly. Called from a running event loop, it refuses (``RuntimeError``): use
    :func:`run_async`.
    """
    runner = own_loop("ubf_async.experiment.run()",
                      instead="await ubf_async.experiment.run_async(...)")
    plan = plan_run(robot, scenario, seed=seed, duration_s=duration_s, out_dir=out_dir,
                    pictures=pictures)
    with runner:
        return runner.run(run_plan(plan))


def own_loop(call: str, *, instead: str) -> asyncio.Runner:
    """The event loop a run in this process gets (not yet started): one that tells the
    lockstep when it is idle. Refused (``RuntimeError``, saying to do ``instead``) when called
    from a running event loop — before anything is done: asyncio's own refusal would come
    later, and leak the run's coroutine."""
    try:
        asyncio.get_running_loop()
    except RuntimeError:
        return asyncio.Runner(loop_factory=lending.new_idle_event_loop)
    raise RuntimeError(f"{call} cannot be called from a running event loop (the run needs a "
                       f"loop of its own): {instead} instead")


async def run_async(robot: str | Path | Robot, scenario: str | Path, *, seed: int | None = None,
                    duration_s: float | None = None, out_dir: str | Path | None = None,
                    pictures: bool = False) -> RunResult:
    """:func:`run` from async code: the run gets an event loop of its own in a worker thread
    (the lockstep needs a loop that tells when it is idle, which the caller's may not be)."""
    return await asyncio.to_thread(run, robot, scenario, seed=seed, duration_s=duration_s,
                                   out_dir=out_dir, pictures=pictures)


def plan_run(robot: str | Path | Robot, scenario: str | Path, *, seed: int | None = None,
             duration_s: float | None = None, out_dir: str | Path | None = None,
             pictures: bool = False) -> wiring.RunPlan:
    """Everything :func:`run` checks before it starts: the robot resolved with ``seed``, its
    simulator, the scenario loaded and the options checked. Raises
    :class:`~ubf_async.errors.UbfError`."""
    if duration_s is not None and not (math.isfinite(duration_s) and duration_s > 0):
        raise ConfigurationError(f"duration_s must be > 0 simulated seconds, got {duration_s}")
    resolved = robot.reseeded(seed) if isinstance(robot, Robot) else load_robot(robot, seed=seed)
    needed = wiring.simulator_needed(resolved, resolved.devices)
    if needed is None:
        raise ConfigurationError(f"{resolved.source}: none of its devices is simulated: "
                                 f"there is nothing to run in this process")
    folder = Path(out_dir) if out_dir is not None else None
    if pictures and folder is None:
        raise ConfigurationError("pictures=True draws into out_dir: give one")
    if folder is not None and folder.exists() and not folder.is_dir():
        raise ConfigurationError(f"out_dir {folder}: exists and is not a directory")
    options = SimulationOptions(
        scenario=str(scenario), speed=math.inf, seed=seed, duration_s=duration_s,
        summary_path=folder / SUMMARY_FILE if folder is not None else None,
        trajectory_path=folder / TRAJECTORY_FILE if folder is not None else None,
        record_dir=folder if pictures else None, keep_trajectory=True,
        command_line=("ubf_async.experiment.run", str(robot if not isinstance(robot, Robot)
                                                      else robot.source), str(scenario),
                      *(() if seed is None else (f"seed={seed}",))))
    plan = wiring.simulation_plan(resolved, options, simulator=SIMULATORS.get(needed)(),
                                  connection=ConnectionOptions(robot=resolved.name))
    plan.helper_processes = False
    if folder is not None:  # only once everything else is checked: a refusal leaves nothing
        folder.mkdir(parents=True, exist_ok=True)
    return plan


async def run_plan(plan: wiring.RunPlan) -> RunResult:
    """A planned run (:func:`plan_run`) on the running loop, which must be a
    :class:`~ubf_async.runtime.lending.IdleEventLoop`: the in-process transport, the
    robot's wiring, until the run's duration; then its end, which saves the results."""
    clock = SimClock()
    robot_run = wiring.RobotRun.on(Bus(transport=InProcessTransport(), options=plan.connection,
                                       clock=clock))
    quiet = io.StringIO()  # what launch would print
    try:
        wiring.build_robot(plan, robot_run, quiet)
        wiring.add_clock_components(plan, robot_run)
        await wiring.start(robot_run)
        sim_run = robot_run.sim_run
        assert sim_run is not None and sim_run.duration_s is not None, "a scenario has one"
        await sim_run.until_elapsed(sim_run.duration_s)
    finally:
        await wiring.end(robot_run, quiet)
    assert robot_run.summary is not None, "end() raises when the results were not saved"
    return RunResult(summary=robot_run.summary, trajectory=sim_run.trajectory())
