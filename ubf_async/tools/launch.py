"""``python -m ubf_async.launch [ROBOT_FILE]`` — run a robot; the one composition root.

Launch reads a robot file (:mod:`ubf_async.assembly.robotfile`; without one, the shipped
``mini-whegs`` file: the simulated Mini-WHEGS seeking the pink ball), opens the zenoh session
(listening on a loopback endpoint by default, printed at start so other processes can attach
with ``--connect``) and runs the robot as :mod:`ubf_async.runs.wiring` wires it — the devices
built through the plug-in registries, a simulator only if some device's backend needs one,
the state aggregator, the UBF controller with the file's behaviour tree, the remote-behaviour
slots and the live-tree service — with what a console run adds: a recording, the Foxglove
view, the ROS 2 bridge, a one-line live status until Ctrl-C, SIGTERM or ``--duration``
elapses; then it shuts everything down cleanly. The same wiring runs a simulated run as a
library call (:mod:`ubf_async.experiment`), so the two are the same run.

Everything a user can get wrong (the robot file, a scenario, options, the ``--config`` file,
the folders ``--summary``/``--record`` write into) is checked before the robot starts; a port
already in use is one line too. Errors become exit status 2 in :func:`main` (through
:func:`ubf_async.cli.run.run_main`) and nowhere else. A ``--config`` file is overridden only by
the flags actually given: the default listen endpoint applies only when neither ``--listen``
nor the file sets one; for ``…:0`` the port really listened on is printed.

The end of a run never loses its results: if the summary or recording cannot be written, the
summary is printed instead and the exit status is 2. A second Ctrl-C or SIGTERM exits at once
(status 130), whatever the shutdown is stuck on.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import math
import os
import re
import sys
import tempfile
import time
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import TextIO

from ubf_async import __version__, extras
from ubf_async.assembly.registry import SIMULATORS
from ubf_async.assembly.robotfile import (
    DEFAULT_ROBOT_FILE,
    ResolvedDevice,
    Robot,
    builtin_robot_files,
    load_robot,
)
from ubf_async.assembly.simulation import FLAT_OUT, OpenSimulation, SimulationOptions, Simulator
from ubf_async.cli.args import HelpFormatter, add_connection_arguments, connection_options
from ubf_async.cli.run import check_lockstep_loop, run_main
from ubf_async.clocks.clock import Clock, SimClock, WallClock
from ubf_async.errors import ConfigurationError, UbfError
from ubf_async.net.options import DEFAULT_LISTEN, DEFAULT_ROBOT, ConnectionOptions
from ubf_async.net.secure import ROBOT
from ubf_async.net.transport import ZenohTransport
from ubf_async.runs import wiring
from ubf_async.runtime.aggregator import StateAggregator
from ubf_async.runtime.bus import Bus
from ubf_async.runtime.component import HealthMonitor
from ubf_async.runtime.controller import Controller, TickMode
from ubf_async.runtime.gcfreeze import freeze_startup_objects
from ubf_async.services import status
from ubf_async.services.liveview import DEFAULT_PORT as DEFAULT_FOXGLOVE_PORT
from ubf_async.services.liveview import FoxgloveServer
from ubf_async.services.monitor import DEFAULT_PORT as DEFAULT_MONITOR_PORT
from ubf_async.services.monitor import MonitorServer
from ubf_async.services.remote import remote_spec
from ubf_async.services.setupwatch import SetupWatch
from ubf_async.services.status import StatusWriter, status_fields
from ubf_async.tools.liveview import add_host_argument
from ubf_async.tools.monitor import add_host_argument as add_monitor_host_argument
from ubf_async.tools.record import McapRecorder, require_recording

__all__ = ["PROG", "add_controller_arguments", "add_device_arguments", "add_live_view_arguments",
           "add_robot_file_arguments", "add_run_arguments", "add_simulation_arguments",
           "build_parser", "check_outputs", "main", "optional_port_only_if_numeric", "parse_args",
           "plan_launch", "print_plan", "print_tree", "run_robot", "selected_devices",
           "speed_argument"]

log = logging.getLogger("ubf_async.tools.launch")

PROG = "python -m ubf_async.launch"


def speed_argument(text: str) -> float:
    """``--speed``'s value: a factor > 0, or ``max`` (flat out: ``math.inf``)."""
    if text.strip().lower() == FLAT_OUT:
        return math.inf
    try:
        speed = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected a number > 0 or {FLAT_OUT!r}, got {text!r}") from None
    if not (math.isfinite(speed) and speed > 0):
        raise argparse.ArgumentTypeError(
            f"expected a number > 0 or {FLAT_OUT!r}, got {text!r}")
    return speed


def build_parser() -> argparse.ArgumentParser:
    """Launch's command line: the robot file, the connection flags, then an argument group per
    topic (the controller, where the devices come from, a simulated run, the live view, the
    run itself)."""
    parser = argparse.ArgumentParser(
        prog=PROG,
        description=(
            "Run a UBF robot described by a robot file (docs/robot-file.md): zenoh session, "
            "its devices, state aggregator, controller with its behaviour tree, and a live "
            "status line. Without ROBOT_FILE: the simulated Mini-WHEGS seeking the pink ball "
            f"(the shipped '{DEFAULT_ROBOT_FILE}' file). Other processes attach over zenoh "
            "with --connect <the endpoint printed at start> and the same --robot."
        ),
        epilog=("Environment: UBF_RENDER_PROCESS=0: simulated cameras render in a thread of "
                "this process instead of a render process (docs/fleet.md); UBF_LOOP: see "
                "\"event loop\" above."),
        formatter_class=HelpFormatter,
    )
    add_robot_file_arguments(parser)
    add_connection_arguments(parser, default_listen=[DEFAULT_LISTEN],
                             default_identity="robot")  # secure mode: see ubf_async.tools.secure
    parser.set_defaults(robot=None)  # the robot file names the robot unless --robot is given
    add_controller_arguments(parser)
    add_device_arguments(parser)
    add_simulation_arguments(parser)
    add_live_view_arguments(parser)
    add_run_arguments(parser)
    return parser


def add_robot_file_arguments(parser: argparse.ArgumentParser) -> None:
    """ROBOT_FILE, and ``--check``: check it and what would run, and exit."""
    parser.add_argument(
        "robot_file", nargs="?", default=DEFAULT_ROBOT_FILE, metavar="ROBOT_FILE",
        help=f"a robot file (.yaml) or a shipped one ({', '.join(builtin_robot_files())}); "
             f"default: {DEFAULT_ROBOT_FILE}")
    parser.add_argument("--check", action="store_true",
                        help="load and check the robot file (every name and parameter), print "
                             "what would run, and exit without starting anything")


def add_controller_arguments(parser: argparse.ArgumentParser) -> None:
    """How the controller ticks, and where remote behaviours vote: the robot file's
    ``controller:`` overridden."""
    ctl = parser.add_argument_group("controller (override the robot file's `controller:`)")
    ctl.add_argument("--rate-hz", type=float, default=None,
                     help="tick rate in periodic mode (robot file default: 50)")
    ctl.add_argument("--tick", dest="tick_mode", choices=[m.value for m in TickMode],
                     default=None,
                     help="periodic: own clock; sync: wait for each sample of the sync source "
                          "(the camera: the thesis's loop); event: tick on each sample of "
                          "--trigger (robot file default: periodic)")
    ctl.add_argument("--trigger", default=None, metavar="SOURCE",
                     help="source that triggers ticks in --tick event, e.g. range/front")
    ctl.add_argument("--reflex", action="append", default=None, metavar="PREFIX",
                     help="in periodic mode, also tick at once on each sample of sources "
                          "starting with PREFIX (repeatable; robot file default: range/ — the "
                          "IR finders; --reflex '' for none)")
    ctl.add_argument("--remote", type=remote_spec, action="append", default=[],
                     metavar="[COMPOSITE/]NAME=PRIORITY[:WEIGHT]",
                     help="place remote behaviour NAME (docs/protocol.md, 'Remote behaviours') "
                          "at PRIORITY[:WEIGHT] in its composite, as a `remote:` slot of the "
                          "tree does (repeatable); other remote behaviours get what they ask "
                          "for unless the robot file says `remotes: {only_declared: true}`")


def add_device_arguments(parser: argparse.ArgumentParser) -> None:
    """Where the devices come from: a simulator here, another process, or the
    hardware."""
    world = parser.add_argument_group("where the devices come from")
    world.add_argument("--no-sim", action="store_true",
                       help="no simulator: devices whose backend needs one are not started "
                            "here; they attach over zenoh from other processes")
    world.add_argument("--sim-time", action="store_true",
                       help="with --no-sim: follow the simulation time published on "
                            "ubf/<robot>/clock by a simulator in another process")
    world.add_argument("--lockstep", action="store_true",
                       help="with --sim-time: take part in the simulator's lockstep, so it "
                            "does not pass a simulated instant before this controller has "
                            "handled it (docs/protocol.md, Lockstep): a repeatable run")
    world.add_argument("--devices", default=None, metavar="KIND[/NAME],...",
                       help="start only these devices of the robot file (e.g. motors,camera); "
                            "others can attach later")


def add_simulation_arguments(parser: argparse.ArgumentParser) -> None:
    """A simulated run: its scenario, speed, seed, and what it writes at its end."""
    sim = parser.add_argument_group("simulated run (when a device's backend is simulated)")
    sim.add_argument("--scenario", default=None, metavar="NAME|PATH",
                     help="world and scripted ball: a built-in scenario or a scenario .json file "
                          "(docs/scenarios.md); default: ball-in-sight, run until stopped")
    sim.add_argument("--speed", type=speed_argument, default=1.0, metavar="K|max",
                     help="run the simulation K times faster than real time, or 'max': flat "
                          "out, as fast as the machine allows (every component, camera latency "
                          "included, follows the simulated clock, which advances in lockstep: "
                          "the same run at any speed)")
    sim.add_argument("--lockstep-participants", type=int, default=0, metavar="N",
                     help="hold simulated time at its start until N processes started with "
                          "--lockstep (remote behaviours, devices) have joined its lockstep, "
                          "so a run with them is repeatable from its first instant")
    sim.add_argument("--seed", type=int, default=None,
                     help="seed for every random source (default: the scenario's)")
    sim.add_argument("--summary", type=Path, default=None, metavar="FILE.json",
                     help="write a JSON summary of the run when it ends")
    sim.add_argument("--judge", action="store_true",
                     help="judge the scenario's expected outcome even at the end of a run with "
                          "no set length (no --scenario, no --duration) stopped by Ctrl-C: "
                          "without it, such a run's outcome is said to be not judged")
    sim.add_argument("--record", type=Path, default=None, metavar="DIR",
                     help="record every message on the robot's keys to DIR/<robot>.mcap "
                          "(docs/recording.md; simulated or not) and, for a simulated run, "
                          "write trajectory.csv, trajectory.png and annotated camera frames")
    sim.add_argument("--trajectory", type=Path, default=None, metavar="FILE.csv",
                     help="write the trajectory (20 samples a simulated second: pose, ball, "
                          "drive command, winners) to FILE.csv, without recording the bus "
                          "(--record writes it too, as DIR/trajectory.csv)")
    sim.add_argument("--record-every-s", type=float, default=2.0, metavar="S",
                     help="simulated seconds between recorded camera frames")


def add_live_view_arguments(parser: argparse.ArgumentParser) -> None:
    """``--foxglove``: the robot served live to Foxglove."""
    view = parser.add_argument_group("live view")
    view.add_argument("--foxglove", type=int, nargs="?", const=DEFAULT_FOXGLOVE_PORT,
                      default=None, metavar="PORT",
                      help="serve the robot live to Foxglove on ws://HOST:PORT (PORT default "
                           f"{DEFAULT_FOXGLOVE_PORT}, 0: any free port; docs/liveview.md); a "
                           "word after it that is not a number is not its PORT (--foxglove "
                           "ROBOT_FILE runs ROBOT_FILE)")
    add_host_argument(view)
    view.add_argument("--monitor", type=int, nargs="?", const=DEFAULT_MONITOR_PORT,
                      default=None, metavar="PORT",
                      help="serve the behaviour tree live to a browser on http://HOST:PORT/ "
                           f"(PORT default {DEFAULT_MONITOR_PORT}, 0: any free port; "
                           "docs/monitor.md): each node's vote, the winners, the sources' ages, "
                           "and changes to the tree from the page (read-only in secure mode); "
                           "a word after it that is not a number is not its PORT")
    add_monitor_host_argument(view)


def add_run_arguments(parser: argparse.ArgumentParser) -> None:
    """How long the run lasts, and what it says on the console meanwhile."""
    run = parser.add_argument_group("run")
    run.add_argument("--duration", type=float, default=None, metavar="S",
                     help="stop after S seconds (simulated seconds when simulating; default: "
                          "the scenario's duration if --scenario is given, else until Ctrl-C)")
    run.add_argument("--status-period-s", type=float, default=0.5,
                     help="how often (wall seconds) the status line refreshes")
    run.add_argument("--quiet", action="store_true", help="no status line")
    run.add_argument("--log-level", default="WARNING",
                     choices=["DEBUG", "INFO", "WARNING", "ERROR"],
                     help="what is logged on the console (WARNING: warnings, and the live "
                          "tree changes applied)")


def selected_devices(robot: Robot, wanted: str | None) -> list[ResolvedDevice]:
    """The robot file's devices, narrowed by ``--devices KIND[/NAME],...``."""
    if wanted is None:
        return list(robot.devices)
    names = [w.strip() for w in wanted.split(",") if w.strip()]
    known = {d.kind for d in robot.devices} | {f"{d.kind}/{d.name}" for d in robot.devices}
    unknown = [n for n in names if n not in known]
    if unknown:
        raise ConfigurationError(f"--devices: {', '.join(unknown)} not in {robot.source}; its "
                                 f"devices: {', '.join(sorted(known))}")
    return [d for d in robot.devices if d.kind in names or f"{d.kind}/{d.name}" in names]


def plan_launch(args: argparse.Namespace) -> wiring.RunPlan:
    """Load and check the robot file and options; nothing starts. Raises :class:`UbfError`."""
    robot = load_robot(args.robot_file, seed=args.seed)
    devices = selected_devices(robot, args.devices)
    needed = wiring.simulator_needed(robot, devices)
    elsewhere: list[ResolvedDevice] = []
    simulator: Simulator | None = None
    options: SimulationOptions | None = None
    if args.sim_time and not args.no_sim:
        raise ConfigurationError("--sim-time only makes sense with --no-sim")
    if args.lockstep and not args.sim_time:
        raise ConfigurationError("--lockstep only makes sense with --no-sim --sim-time (a "
                                 "simulator of this process already steps in lockstep)")
    if args.no_sim:
        elsewhere = [d for d in devices if d.requires_simulator]
        devices = [d for d in devices if not d.requires_simulator]
    elif needed is not None:
        check_lockstep_loop()
        simulator = SIMULATORS.get(needed)()
        options = SimulationOptions(
            scenario=args.scenario, speed=args.speed, seed=args.seed,
            duration_s=args.duration, summary_path=args.summary, record_dir=args.record,
            trajectory_path=args.trajectory,
            record_every_s=args.record_every_s, judge_open_ended=args.judge,
            lockstep_participants=args.lockstep_participants,
            command_line=("python", "-m", "ubf_async.launch", *sys.argv[1:]))
        simulator.check(options)  # an unknown scenario is refused here, not after the bus opens
    if simulator is None:
        given = [flag for flag, value in (("--scenario", args.scenario),
                                          ("--summary", args.summary),
                                          ("--trajectory", args.trajectory))
                 if value is not None]
        if given:
            why = ("--no-sim is given" if args.no_sim
                   else f"no device of {robot.source} is simulated")
            raise ConfigurationError(f"{', '.join(given)}: there is no simulator ({why})")
    if args.trajectory is not None and args.record is not None:
        raise ConfigurationError(f"--trajectory: --record {args.record} writes the trajectory "
                                 f"already ({args.record / 'trajectory.csv'}); give one of them")
    check_outputs(args.summary, args.record, trajectory=args.trajectory)
    if args.record is not None:
        require_recording(who="launch --record")
    if args.foxglove is not None:
        extras.require("view", "foxglove", who="launch --foxglove")
    if args.monitor is not None:
        extras.require("monitor", "aiohttp", who="launch --monitor")
    if args.duration is not None and not args.duration > 0:
        raise ConfigurationError(f"--duration must be > 0, got {args.duration:g}")
    args.robot = args.robot or robot.name or DEFAULT_ROBOT
    controller = wiring.ControllerSettings.of(robot, mode=args.tick_mode,
                                              rate_hz=args.rate_hz, trigger=args.trigger,
                                              reflex=args.reflex)
    return wiring.RunPlan(robot=robot, devices=devices, elsewhere=elsewhere,
                          simulator=simulator, sim_options=options, controller=controller,
                          connection=connection_options(args),
                          seed_given=args.seed is not None, remotes=dict(args.remote),
                          lockstep=args.lockstep, status_on_robot_clock=args.lockstep)


def check_outputs(summary: Path | None, record: Path | None, *,
                  trajectory: Path | None = None) -> None:
    """Make the folders ``--summary``, ``--trajectory`` and ``--record`` write into, and check
    that a file can be created there, so a run never ends with nowhere to put its results.
    Raises :class:`ConfigurationError`."""
    for flag, file, example in (("--summary", summary, "summary.json"),
                                ("--trajectory", trajectory, "trajectory.csv")):
        if file is not None and file.is_dir():
            raise ConfigurationError(f"{flag} {file}: is a directory; give a file name, "
                                     f"e.g. {file / example}")
    if record is not None and record.exists() and not record.is_dir():
        raise ConfigurationError(f"--record {record}: exists and is not a directory")
    for flag, folder in (("--summary", summary.parent if summary else None),
                         ("--trajectory", trajectory.parent if trajectory else None),
                         ("--record", record)):
        if folder is None:
            continue
        try:
            folder.mkdir(parents=True, exist_ok=True)
            with tempfile.TemporaryFile(dir=folder):
                pass
        except OSError as exc:
            found = next((p for p in (folder, *folder.parents) if p.exists()), None)
            reason = (f"{found} is not a directory" if found is not None and not found.is_dir()
                      else exc.strerror or str(exc))
            raise ConfigurationError(f"{flag}: cannot write in {folder}: {reason}") from None


async def run_robot(plan: wiring.RunPlan, args: argparse.Namespace,
                    out: TextIO = sys.stdout) -> int:
    """Run the planned robot until ``--duration``, SIGTERM or Ctrl-C.

    Whatever ends the run (an error too), :func:`ubf_async.runs.wiring.end` saves the results,
    then closes every component and the session, each step bounded and done even if an earlier
    one failed."""
    run = await _open_session(plan, args)
    options = run.bus.options  # with the port really listened on for a `:0` endpoint
    try:
        _print_session(plan.robot, options, out)
        await _start_observers(run, args, out)
        wiring.build_robot(plan, run, out)
        assert run.robot is not None and run.controller is not None
        assert run.aggregator is not None
        _add_ros2_bridge(run.robot, run, options.robot, out)
        wiring.add_clock_components(plan, run)
        await wiring.start(run)
        _print_started(plan, run.robot, out)
        freeze_startup_objects()  # the start-up's objects: out of the collector's way
        await _run_until_done(args, out, options.robot, run.controller, run.aggregator,
                              run.health, run.sim_run)
    except asyncio.CancelledError:
        pass  # a stop signal: the end below is the same as for any other end
    finally:
        code = await wiring.end(run, out, saving=any(
            output is not None for output in (args.summary, args.record, args.trajectory)))
    return code


async def _open_session(plan: wiring.RunPlan, args: argparse.Namespace) -> wiring.RobotRun:
    """The run's clock (simulated time when a simulator runs here or ``--sim-time`` follows
    one elsewhere) and its zenoh session."""
    simulated = plan.simulator is not None
    clock: Clock = SimClock() if simulated or args.sim_time else WallClock()
    # A simulator's process and a lockstep participant hand samples over in the order they
    # were sent: a participant's acknowledgement never overtakes what it sent before it. So
    # does a follower of simulated time: a sample never overtakes the clock sent before it
    # (the first one above all: before it the follower has no time, and refuses the sample).
    bus = await Bus.open(plan.connection, clock=clock,
                         ordered=simulated or args.sim_time or args.lockstep)
    return wiring.RobotRun.on(bus)


def _print_session(robot: Robot, options: ConnectionOptions, out: TextIO) -> None:
    """Where the robot is on zenoh, and how other processes attach to it."""
    secure = ""
    if options.secure is not None:
        from ubf_async.net.secure import SecureSetup  # (cryptography: only secure mode)

        setup = SecureSetup.load(options.secure)
        secure = f" --secure {options.secure} --identity NAME"
        print(f"ubf_async: secure mode: mutual TLS with the set-up in {options.secure} "
              f"(identity {options.identity!r}; the certificate names {', '.join(setup.hosts)})"
              f": only its identities get in, each with its own rights (`python -m "
              f"ubf_async.secure show {options.secure}`)", file=out)
    if options.mode == "client":
        routers = " ".join(options.connect) or "(the --config file's router)"
        print(f"ubf_async: robot {options.robot!r} ({robot.source}) on zenoh, a client of "
              f"the router at {routers}", file=out)
        print(f"  attach with: --mode client --connect {routers.split()[0]} --robot "
              f"{options.robot}{secure}", file=out)
    else:
        endpoints = " ".join(options.listen) or "(not listening)"
        print(f"ubf_async: robot {options.robot!r} ({robot.source}) on zenoh, listening on "
              f"{endpoints}", file=out)
        if options.listen:
            where = options.listen[0]
            if options.secure is not None:  # dial a name the certificate carries
                where = re.sub(r"/(0\.0\.0\.0|\[::\]):", f"/{setup.hosts[0]}:", where)
            print(f"  attach with: --connect {where} --robot {options.robot}{secure}",
                  file=out)


async def _start_observers(run: wiring.RobotRun, args: argparse.Namespace, out: TextIO) -> None:
    """``--record``, ``--foxglove`` and ``--monitor``: started first (and closed last), they
    see the whole run; what they did is said at the end."""
    if args.record is not None:
        recorder = McapRecorder(bus=run.bus, out=args.record)
        await recorder.start()
        run.components.append(recorder)
        run.end_notes.append(lambda: _recorded(recorder))
        print(f"  recording the bus to {recorder.path}", file=out)
    if args.foxglove is not None:
        live = FoxgloveServer(bus=run.bus, port=args.foxglove, host=args.foxglove_host)
        await live.start()
        run.components.append(live)
        run.end_notes.append(lambda: f"  live view: {live.stats.summary()}")
        print(f"  live in Foxglove on {live.url} (layout: docs/foxglove-layout.json)",
              file=out)
    setup = run.bus.options.secure
    if setup is not None and run.bus.options.identity == ROBOT:
        # The robot holds the password dictionary and the ACL: it re-opens its session when
        # they change, so a revoked or rotated identity is cut off while it runs.
        transport = run.bus.transport
        assert isinstance(transport, ZenohTransport)  # (launch opened it: Bus.open)
        watch = SetupWatch(bus=run.bus, directory=setup, reopen=transport.reopen,
                           said=lambda line: print(line, file=out, flush=True))
        await watch.start()
        run.components.append(watch)
    if args.monitor is not None:
        secure = run.bus.options.secure is not None
        monitor = MonitorServer(
            bus=run.bus, port=args.monitor, host=args.monitor_host, allow_changes=not secure,
            refusal="in secure mode the robot's own page is read-only (a browser would get the "
                    "robot's rights): change the tree from python -m ubf_async.monitor run "
                    "with an identity that may (docs/monitor.md)")
        await monitor.start()
        run.components.append(monitor)
        print(f"  the tree live in a browser on {monitor.url}"
              + (" (read-only: secure mode)" if secure else ""), file=out)


def _recorded(recorder: McapRecorder) -> str:
    stats = recorder.stats
    return (f"  recorded {stats.written} messages"
            + (f" and {stats.live} in the live view's Foxglove channels" if stats.live else "")
            + f" to {', '.join(str(p) for p in stats.files)}"
            + (f" ({stats.dropped} dropped: the disk did not keep up)" if stats.dropped else "")
            + (f"; writing failed: {stats.error}" if stats.error else ""))


def _add_ros2_bridge(robot: Robot, run: wiring.RobotRun, robot_name: str, out: TextIO) -> None:
    """The ROS 2 bridge, if the robot file enables it (docs/ros2.md)."""
    spec = robot.spec
    if spec.ros2 is None or not spec.ros2.enabled:
        return
    from ubf_async.services.ros2.bridge import Ros2Bridge, settings_of_spec
    try:
        ros2 = settings_of_spec(spec.ros2, robot.remotes)
    except ValueError as exc:
        raise ConfigurationError(f"{robot.source}: {exc}") from None
    run.components.append(Ros2Bridge(bus=run.bus, settings=ros2))
    print(f"  ROS 2 bridge: {ros2.namespace_for(robot_name)}/{ros2.node}, domain "
          f"{ros2.domain_id}, {ros2.distro} (docs/ros2.md)", file=out)


def _print_started(plan: wiring.RunPlan, robot: Robot, out: TextIO) -> None:
    """What runs here: the devices, how the controller ticks, the tree."""
    here = ", ".join(f"{d.kind}/{d.name} ({d.backend})" for d in plan.devices)
    print(f"  devices: {here or 'none here'}", file=out)
    print(f"  controller: {plan.controller.planned(plan.sources())}; tree:", file=out)
    print_tree(robot, out)
    out.flush()


async def _run_until_done(
    args: argparse.Namespace, out: TextIO, robot: str, controller: Controller,
    aggregator: StateAggregator, health: HealthMonitor, sim_run: OpenSimulation | None,
) -> None:
    """Print the status line until the run's duration has passed (forever without one)."""
    wall_start = time.monotonic()
    duration = sim_run.duration_s if sim_run is not None else args.duration

    def elapsed() -> float:
        return sim_run.elapsed_s() if sim_run is not None else time.monotonic() - wall_start

    writer = StatusWriter(out)

    async def report() -> None:
        try:
            while True:
                await asyncio.sleep(args.status_period_s)
                writer.write(status_fields(
                    robot, elapsed(), controller, aggregator, health,
                    simulation=sim_run.status_suffix() if sim_run is not None
                    else status.followed_clock(controller.bus.clock)))
        finally:
            writer.end()

    if duration is None:
        await (asyncio.Event().wait() if args.quiet else report())
        return
    reporter = None if args.quiet else asyncio.create_task(report())
    try:
        # A simulated run ends the moment simulated time reaches its duration.
        await (sim_run.until_elapsed(duration) if sim_run is not None
               else asyncio.sleep(duration))
    finally:
        if reporter is not None:
            reporter.cancel()
            await asyncio.gather(reporter, return_exceptions=True)


def print_plan(plan: wiring.RunPlan, out: TextIO = sys.stdout) -> None:
    robot = plan.robot
    print(f"{robot.source}: robot {robot.name!r} — OK", file=out)
    for device in plan.devices + plan.elsewhere:
        sim = f", simulator {device.requires_simulator}" if device.requires_simulator else ""
        print(f"  device {device.kind}/{device.name}: backend {device.backend}{sim}", file=out)
    print(f"  controller: {plan.controller.planned(plan.sources())}", file=out)
    print_tree(robot, out)


def print_tree(robot: Robot, out: TextIO) -> None:
    """The robot's behaviour tree, and its remote behaviours' slots."""
    for line in robot.root.render_tree().splitlines():
        print(f"    {line}", file=out)
    for slot in robot.remotes:
        print(f"    remote slot {slot.key} [p={slot.priority} w={slot.weight:g}]", file=out)


OPTIONAL_PORTS = {"--foxglove": DEFAULT_FOXGLOVE_PORT, "--monitor": DEFAULT_MONITOR_PORT}
"""The flags whose PORT may be left out, and its default."""


def optional_port_only_if_numeric(argv: Sequence[str]) -> list[str]:
    """``--foxglove [PORT]``, ``--monitor [PORT]``: argparse gives an optional value whatever
    word follows, so ``launch --foxglove my_robot.yaml`` would read the robot file as the port.
    The word after such a flag is its PORT only if it is a number; otherwise the flag stands
    alone."""
    out = list(argv)
    for i, word in enumerate(out[:-1]):
        if word == "--":
            break
        following = out[i + 1]
        if (word in OPTIONAL_PORTS and not following.startswith("-")
                and not following.strip().isdigit()):
            out[i] = f"{word}={OPTIONAL_PORTS[word]}"
    return out


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    """The command line (``sys.argv[1:]`` by default), parsed by :func:`build_parser`."""
    words = sys.argv[1:] if argv is None else argv
    return build_parser().parse_args(optional_port_only_if_numeric(words))


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    # numpy's OpenBLAS starts a thread per core when numpy is first imported (by the devices,
    # below); a robot's numpy work is small arrays, so one is enough: 0.3-0.4 CPU-s less per
    # 3 s run of the simulated robot on 2 cores. A user's own setting is kept.
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    # Deprecations in what a user wrote (old scenario fields …) are for the user to see.
    warnings.filterwarnings("default", category=DeprecationWarning,
                            module=r"(ubf_async|components)(\.|$)")
    logging.basicConfig(
        level=args.log_level, format="%(asctime)s %(levelname)s %(name)s: %(message)s"
    )
    if logging.getLogger().level == logging.WARNING:
        # An accepted live tree change is news on the robot's console, as a refused one (a
        # warning) is: shown at the default level too, hidden only by --log-level ERROR.
        logging.getLogger("ubf_async.services.live").setLevel(logging.INFO)
    try:
        plan = plan_launch(args)
    except UbfError as exc:
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return 2
    if args.check:
        print_plan(plan)
        return 0
    log.info("ubf_async %s", __version__)
    # sys.stdout read at run time: run_main makes it a stream that cannot fail the end.
    return run_main(lambda: run_robot(plan, args, sys.stdout), prog=PROG)


if __name__ == "__main__":
    raise SystemExit(main())
