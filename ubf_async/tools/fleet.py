"""A fleet: ``python -m ubf_async.fleet FLEET.yaml`` — router, one simulated world, robots.

A fleet file (YAML, ``docs/fleet.md``) lists the robots — a name, a robot file and a start pose
each — and the world they share (a scenario's arena, ball and scripts, the speed, the seed)::

    world: {scenario: ball-in-sight, speed: 1, duration_s: 30}
    robots:
      - {name: r1, robot_file: mini-whegs, start: {x_m: 0.0, y_m: 0.0, heading_deg: 0}}
      - {name: r2, start: {x_m: -0.4, y_m: 0.5, heading_deg: -45}}

The launcher starts, each in its own process:

1. a zenoh router (``python -m ubf_async.router``) on the file's ``router`` endpoint — unless
   ``--router EP`` names one already running;
2. one controller per robot: ``python -m ubf_async.launch ROBOT_FILE --no-sim --sim-time
   --robot NAME --mode client --connect ROUTER`` (its devices run in the world; it follows the
   world's simulated time);
3. the world (``python -m ubf_async.fleet FLEET.yaml --world-only``): the simulator plug-in the
   robots' devices need holds every robot in one world and runs their simulated devices, each
   on its robot's keys. It waits for every robot's controller before time starts, so a run is
   the same however long the processes took to start.

While it runs it prints one status line per period for the whole fleet (each robot's periodic
tick rate and who wins its drive command, from its controller's status), and at the end a
summary per robot (``--summary FILE.json``). The world's duration ends the run; Ctrl-C ends it
early. Each process's output goes to a log file in ``--log-dir``.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import dataclasses
import json
import os
import signal
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any, TextIO

from ubf_async.assembly.registry import SIMULATORS
from ubf_async.assembly.simulation import (
    CONTROLLER_SUMMARY_FIELDS,
)
from ubf_async.cli.args import HelpFormatter, add_event_loop_help, add_secure_arguments
from ubf_async.cli.run import run_main
from ubf_async.clocks.clock import SimClock
from ubf_async.clocks.simclock import follow_sim_clock
from ubf_async.errors import ConfigurationError
from ubf_async.net.options import ConnectionOptions, over_tls
from ubf_async.net.secure import FLEET, WORLD
from ubf_async.runs.fleet import (
    Fleet,
    load_fleet,
    members_of,
    world_options,
)
from ubf_async.runtime.bus import Bus
from ubf_async.wire.keys import ROOT
from ubf_async.wire.protocol import Message
from ubf_async.wire.topics import CONTROLLER_STATUS, PlainData

__all__ = ["CHILD_STOP_S", "CONTROLLERS_WAIT_S", "FLEET_STOP_BOUND_S", "PROG", "FleetStatus",
           "RobotView", "build_parser", "controller_arguments", "finish", "fleet_options",
           "fleet_router", "main", "main_async", "open_when_up", "run_controllers", "run_fleet",
           "run_world", "secure_flags", "spawn", "stop_all", "tail", "wait_for_controllers"]

PROG = "python -m ubf_async.fleet"
CONTROLLERS_WAIT_S = 60.0
"""How long the world waits for every robot's controller before giving up."""

# ---------------------------------------------------------------------------------------------
# The world process


async def run_world(fleet: Fleet, *, router: str, out: TextIO,
                    summary_path: Path | None, lockstep: bool = False,
                    secure: Path | None = None) -> int:
    """The world process. With ``lockstep`` simulated time starts once every robot's
    controller has joined its lockstep, and waits for each of them at every step."""
    spec = fleet.spec
    clock = SimClock()
    buses: list[Bus] = []
    try:
        for entry in spec.robots:
            buses.append(await Bus.open(fleet_options(entry.name, router, secure, WORLD),
                                        clock=clock, ordered=lockstep))
        await wait_for_controllers(buses[0], [r.name for r in spec.robots],
                                   timeout_s=CONTROLLERS_WAIT_S, lockstep=lockstep)
        members = members_of(fleet)
        options = world_options(fleet,
                                lockstep_participants=len(spec.robots) if lockstep else 0)
        simulator = SIMULATORS.get(fleet.simulator)()
        summary = await simulator.host_fleet(buses=buses, clock=clock, members=members,
                                             options=options, out=out)
        if summary_path is not None:
            await asyncio.to_thread(summary_path.write_text,
                                    json.dumps(summary, indent=2) + "\n", encoding="utf-8")
        return 0
    finally:
        for bus in buses:
            await bus.aclose()


async def wait_for_controllers(bus: Bus, robots: Sequence[str], *, timeout_s: float,
                               lockstep: bool = False) -> None:
    """Until every robot's controller is alive (its liveliness token) and, with
    ``lockstep``, has joined the lockstep (its participant token: by then its subscriptions
    are known here too, so nothing the world sends from its first instant on is lost to
    it); a :class:`ConnectionError` naming the missing after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    pattern = f"{ROOT}/*/lockstep/controller" if lockstep else f"{ROOT}/*/alive/controller"
    missing = list(robots)
    while missing:
        alive = {key.split("/")[1] for key in await bus.alive_tokens(pattern, timeout_s=1.0)}
        missing = [r for r in robots if r not in alive]
        if not missing:
            return
        if time.monotonic() > deadline:
            raise ConnectionError(f"no controller of {', '.join(missing)} came up within "
                                  f"{timeout_s:g} s (see their logs)")
        await asyncio.sleep(0.1)


def controller_arguments(fleet: Fleet, name: str, *, router: str, lockstep: bool,
                         secure: Path | None = None) -> list[str]:
    """Launch's command line for robot ``name``'s controller: its robot file, following the
    world's time through the router, its behaviours seeded with the world's seed when the
    fleet file sets one (as :func:`ubf_async.runs.fleet.run_fleet` seeds them); with
    ``secure`` (a fleet's set-up), as the fleet's identity of that robot."""
    seed = fleet.spec.world.seed
    return [fleet.robots[name].source, "--no-sim", "--sim-time", "--robot", name, "--mode",
            "client", "--connect", router, "--quiet",
            *(["--seed", str(seed)] if seed is not None else []),
            *(["--lockstep"] if lockstep else []),
            *(["--secure", str(secure), "--identity", name] if secure is not None else [])]


def secure_flags(secure: Path | None) -> list[str]:
    return ["--secure", str(secure)] if secure is not None else []


def fleet_options(robot: str, router: str, secure: Path | None, identity: str
                  ) -> ConnectionOptions:
    """A client of the fleet's router on robot ``robot``'s keys; in secure mode as
    ``identity`` of the fleet's set-up ``secure``."""
    return ConnectionOptions(robot=robot, mode="client", connect=[router], secure=secure,
                             identity=identity if secure is not None else None)


async def run_controllers(fleet: Fleet, names: Sequence[str], *, router: str,
                          out: TextIO, lockstep: bool = False,
                          secure: Path | None = None) -> int:
    """Several robots' controllers in this one process, each exactly as
    ``python -m ubf_async.launch ROBOT_FILE --no-sim --sim-time --robot NAME --mode client``
    runs it (its own session, aggregator, controller, remote behaviours, tree service), all
    on this process's event loop."""
    from ubf_async.tools import launch  # the composition root of one robot

    unknown = sorted(set(names) - set(fleet.robots))
    if unknown:
        raise ConfigurationError(f"--controllers-only: no robot {', '.join(unknown)} in "
                                 f"{fleet.source}")
    runs = []
    for name in names:
        args = launch.build_parser().parse_args(
            controller_arguments(fleet, name, router=router, lockstep=lockstep, secure=secure))
        runs.append(launch.run_robot(launch.plan_launch(args), args, out))
    tasks = [asyncio.ensure_future(run) for run in runs]
    try:
        return max(await asyncio.gather(*tasks))
    finally:  # one failing (or a Ctrl-C) ends them all, each saving and closing as launch does
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)


# ---------------------------------------------------------------------------------------------
# The launcher


@dataclasses.dataclass(slots=True)
class RobotView:
    """What the fleet's status line knows of one robot (its controller's last status)."""

    status: dict[str, Any] = dataclasses.field(default_factory=dict)
    heard_s: float | None = None


class FleetStatus:
    """Every robot's controller status, from ``ubf/<robot>/status/controller``."""

    def __init__(self, names: Sequence[str]) -> None:
        self.robots = {name: RobotView() for name in names}
        self.malformed: dict[str, int] = {}

    def on_status(self, key: str, message: Message[PlainData], received_ns: int) -> None:
        view = self.robots.get(key.split("/")[1])
        if view is None:
            return
        view.status = dict(message.data)
        view.heard_s = time.monotonic()

    def line(self, *, sim_s: float | None) -> str:
        parts = []
        for name, view in self.robots.items():
            status = view.status
            rate = status.get("periodic_rate_hz")
            hz = f"{rate:.0f}Hz" if isinstance(rate, int | float) else "--"
            winners = ",".join(status.get("winners") or []) or ("stop" if status else "--")
            parts.append(f"{name} {hz} {winners}")
        head = f"fleet t={sim_s:.1f}s" if sim_s is not None else "fleet"
        return f"{head} | " + " | ".join(parts)


async def spawn(args: Sequence[str], log: Path) -> asyncio.subprocess.Process:
    with log.open("wb") as sink:  # the child keeps its own descriptor
        return await asyncio.create_subprocess_exec(
            sys.executable, *args, stdout=sink, stderr=asyncio.subprocess.STDOUT,
            env={**os.environ, "PYTHONUNBUFFERED": "1"},
            # Its own process group: a Ctrl-C at the terminal reaches the launcher only, which
            # stops each child once (a second signal would make a child exit at once).
            start_new_session=True)


CHILD_STOP_S = 4.0
"""How long the launcher waits for its children after SIGTERM before SIGKILL: long enough for
a launch to save its results (it takes under a second; its own bound is 5 s)."""
FLEET_STOP_BOUND_S = CHILD_STOP_S + 2.0
"""The launcher's stop bound: its children's wait, then the router's (docs/fleet.md)."""
ROUTER_STOP_S = 1.0
"""The router's wait after SIGTERM, at least: more when the children left it more of the
launcher's stop bound. A router closes its session and waits for its callbacks to end
(``CALLBACK_END_WAIT_S`` at most): on a busy machine that outlasts a fixed second."""
OWN_EXIT_S = 0.5
"""What the launcher keeps of its stop bound for its own exit, after the router's wait."""


async def stop_all(procs: dict[str, asyncio.subprocess.Process], *,
                   grace_s: float = CHILD_STOP_S) -> list[str]:
    """SIGTERM to every child still running (a launch saves its results), wait for them all
    at most ``grace_s``, SIGKILL those still there and say which; return their names."""
    running = {name: proc for name, proc in procs.items() if proc.returncode is None}
    for proc in running.values():
        with contextlib.suppress(ProcessLookupError):
            proc.send_signal(signal.SIGTERM)
    if running:
        await asyncio.wait([asyncio.ensure_future(p.wait()) for p in running.values()],
                           timeout=grace_s)
    killed = [name for name, proc in running.items() if proc.returncode is None]
    for name in killed:
        with contextlib.suppress(ProcessLookupError):
            running[name].kill()
        await running[name].wait()
    if killed:
        print(f"fleet: {', '.join(killed)} did not stop within {grace_s:g} s of SIGTERM: "
              f"killed (SIGKILL)", file=sys.stderr)
    return killed


async def run_fleet(fleet: Fleet, args: argparse.Namespace, out: TextIO) -> int:
    spec = fleet.spec
    router = fleet_router(args, spec.router)
    logs = Path(args.log_dir) if args.log_dir else Path(tempfile.mkdtemp(prefix="ubf-fleet-"))
    logs.mkdir(parents=True, exist_ok=True)
    world_summary = logs / "world-summary.json"
    procs: dict[str, asyncio.subprocess.Process] = {}
    tool: Bus | None = None
    stop_deadline: float | None = None  # a stop signal's FLEET_STOP_BOUND_S, once it came
    try:
        if args.router is None:
            procs["router"] = await spawn(["-m", "ubf_async.router", "--listen", router,
                                           "--quiet", *secure_flags(args.secure)],
                                          logs / "router.log")
        print(f"fleet: {len(spec.robots)} robots on the router at {router}; logs in {logs}",
              file=out, flush=True)
        # The launcher's own session (on the first robot's keys, for the world's clock): it
        # retries until the router listens.
        tool = await open_when_up(fleet_options(spec.robots[0].name, router, args.secure,
                                                FLEET), timeout_s=20.0)
        per = args.controllers_per_process
        for group in (spec.robots[i:i + per] for i in range(0, len(spec.robots), per)):
            names = [entry.name for entry in group]
            command = (["-m", "ubf_async.launch",
                        *controller_arguments(fleet, names[0], router=router,
                                              lockstep=args.lockstep, secure=args.secure)]
                       if per == 1 else
                       ["-m", "ubf_async.fleet", str(fleet.source), "--controllers-only",
                        ",".join(names), "--router", router,
                        "--lockstep" if args.lockstep else "--no-lockstep",
                        *secure_flags(args.secure)])
            procs["+".join(names)] = await spawn(command, logs / f"{'+'.join(names)}.log")
        world_args = ["-m", "ubf_async.fleet", str(fleet.source), "--world-only", "--router",
                      router, "--summary", str(world_summary),
                      "--lockstep" if args.lockstep else "--no-lockstep",
                      *secure_flags(args.secure)]
        procs["world"] = world = await spawn(world_args, logs / "world.log")
        status = FleetStatus([r.name for r in spec.robots])
        tool.subscribe_topic(f"{ROOT}/*/status/controller", CONTROLLER_STATUS, status.on_status,
                             status.malformed, latest=False)
        clock = SimClock()
        follow_sim_clock(tool, clock, {})
        try:
            while world.returncode is None:
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(world.wait(), args.status_period_s)
                if not args.quiet:
                    print(status.line(sim_s=clock.now_ns() / 1e9 if clock.started.is_set()
                                      else None), file=out, flush=True)
                for name, proc in procs.items():
                    if name not in ("world",) and proc.returncode is not None:
                        print(f"fleet: {name} exited with status {proc.returncode} "
                              f"(log: {logs / (name + '.log')})", file=out, flush=True)
                        procs.pop(name)
                        break
        except asyncio.CancelledError:
            # A stop signal ends the run as the world's duration does: the world and the
            # controllers stop (the world writes its summary as it stops), then the summary.
            stop_deadline = time.monotonic() + FLEET_STOP_BOUND_S
            await stop_all({name: proc for name, proc in procs.items() if name != "router"})
        if world.returncode != 0:
            print(f"fleet: the world exited with status {world.returncode}: "
                  f"{tail(logs / 'world.log')}", file=sys.stderr)
        return await asyncio.to_thread(finish, fleet, status, world_summary, args, out,
                                       world.returncode or 0)
    finally:
        # The controllers and the world together (a world in lockstep stops waiting for a
        # controller that is gone), the router once they have left it, with what is left of
        # the stop bound (the run's end starts one as a signal does).
        if stop_deadline is None:
            stop_deadline = time.monotonic() + FLEET_STOP_BOUND_S
        router_proc = procs.pop("router", None)
        await stop_all(procs)
        if tool is not None:
            await tool.aclose()
        if router_proc is not None:
            left = stop_deadline - OWN_EXIT_S - time.monotonic()
            await stop_all({"router": router_proc}, grace_s=max(ROUTER_STOP_S, left))


def fleet_router(args: argparse.Namespace, default: str) -> str:
    """The router's endpoint: ``--router``, else the fleet file's; over TLS in secure mode."""
    router: str = args.router or default
    return over_tls(router) if args.secure is not None else router


async def open_when_up(options: ConnectionOptions, *, timeout_s: float) -> Bus:
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            return await Bus.open(options)
        except ConnectionError:
            if time.monotonic() > deadline:
                raise
            await asyncio.sleep(0.1)


def tail(path: Path, lines: int = 3) -> str:
    with contextlib.suppress(OSError):
        return " / ".join(path.read_text(errors="replace").strip().splitlines()[-lines:])
    return ""


def finish(fleet: Fleet, status: FleetStatus, world_summary: Path, args: argparse.Namespace,
           out: TextIO, code: int) -> int:
    world: dict[str, Any] = {}
    with contextlib.suppress(OSError, ValueError):
        world = json.loads(world_summary.read_text(encoding="utf-8"))
    robots: dict[str, Any] = {}
    for entry in fleet.spec.robots:
        in_world = dict(world.get("robots", {}).get(entry.name, {}))
        # The controller's figures as the world heard them in simulated time (the same at
        # any speed, in lockstep), else its last status heard here.
        heard = in_world.pop("controller", None) or status.robots[entry.name].status
        s = {field: heard.get(field) for field in CONTROLLER_SUMMARY_FIELDS}
        robots[entry.name] = {"robot_file": entry.robot_file, **s, **in_world}
        share = s.get("winner_share") or {}
        top = ", ".join(f"{k} {v:.0%}" for k, v in sorted(share.items(), key=lambda kv: -kv[1]))
        travelled = robots[entry.name].get("travelled_m")
        found_at = robots[entry.name].get("found_s")
        found = f"found the ball at {found_at} s" if found_at is not None else "no ball found"
        print(f"  {entry.name}: {s.get('ticks', '?')} ticks, "
              f"{travelled if travelled is not None else '?'} m travelled, {found}; "
              f"won: {top or '--'}", file=out)
    summary = {"fleet": str(fleet.source), "scenario": world.get("scenario"),
               "lockstep": args.lockstep,
               "sim_time_s": world.get("sim_time_s"),
               "real_time_factor": world.get("real_time_factor"),
               "first_found_s": world.get("first_found_s"),
               "all_found_s": world.get("all_found_s"), "robots": robots}
    if world.get("first_found_s") is not None:
        everyone = (f"all {len(robots)} by {world['all_found_s']} s"
                    if world.get("all_found_s") is not None else "not all of them")
        print(f"  the ball: first found at {world['first_found_s']} s (simulated), "
              f"{everyone}", file=out)
    if args.summary is not None:
        args.summary.write_text(json.dumps(summary, indent=2) + "\n", encoding="utf-8")
        print(f"  summary written to {args.summary}", file=out)  # as launch says it
    return code


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=PROG, formatter_class=HelpFormatter,
        description="Run a fleet of robots in one simulated world (docs/fleet.md): a zenoh "
                    "router, the world with every robot's simulated devices, and one "
                    "controller process per robot.")
    parser.add_argument("fleet_file", type=Path, metavar="FLEET.yaml")
    parser.add_argument("--router", default=None, metavar="ENDPOINT",
                        help="use the router already running at ENDPOINT instead of starting "
                             "one (default: start one on the fleet file's `router`)")
    parser.add_argument("--summary", type=Path, default=None, metavar="FILE.json",
                        help="write a summary per robot when the run ends")
    parser.add_argument("--log-dir", default=None, metavar="DIR",
                        help="where each process's output goes (default: a new temporary "
                             "directory, printed)")
    parser.add_argument("--status-period-s", type=float, default=2.0, metavar="S",
                        help="how often the fleet's status line is printed")
    parser.add_argument("--quiet", action="store_true", help="no status lines")
    parser.add_argument("--check", action="store_true",
                        help="load and check the fleet file and every robot file, and exit")
    parser.add_argument("--lockstep", action=argparse.BooleanOptionalAction, default=True,
                        help="the controllers take part in the world's lockstep (simulated "
                             "time waits for each of them at every step): a run is the same "
                             "on any machine, at any load; --no-lockstep: they follow the "
                             "world's clock as it goes (faster with many robots, not "
                             "repeatable)")
    parser.add_argument("--world-only", action="store_true",
                        help="run only the world (what the launcher starts as its own process)")
    parser.add_argument("--controllers-per-process", type=int, default=1, metavar="K",
                        help="run the robots' controllers K to a process (fewer processes for "
                             "a small machine; 1: each its own, as launch runs one)")
    add_secure_arguments(
        parser, secure_help="secure mode: the router, the world, the controllers and this "
                            "launcher over mutual TLS, each with its identity of the fleet's "
                            "set-up in DIR (`python -m ubf_async.secure init DIR --fleet-file "
                            "FLEET.yaml`; docs/security.md)")
    parser.add_argument("--controllers-only", default=None, metavar="NAME,...",
                        help="run only these robots' controllers, in this one process (what the "
                             "launcher starts with --controllers-per-process above 1)")
    add_event_loop_help(parser)
    return parser


async def main_async(args: argparse.Namespace, out: TextIO) -> int:
    fleet = load_fleet(args.fleet_file)
    if args.check:
        for entry in fleet.spec.robots:
            print(f"{entry.name}: {fleet.robots[entry.name].source} at ({entry.start.x_m:g}, "
                  f"{entry.start.y_m:g}) m, heading {entry.start.heading_deg:g}°", file=out)
        return 0
    if args.world_only:
        return await run_world(fleet, router=fleet_router(args, fleet.spec.router), out=out,
                               summary_path=args.summary, lockstep=args.lockstep,
                               secure=args.secure)
    if args.controllers_only is not None:
        return await run_controllers(fleet, args.controllers_only.split(","),
                                     router=fleet_router(args, fleet.spec.router), out=out,
                                     lockstep=args.lockstep, secure=args.secure)
    if args.controllers_per_process < 1:
        raise ConfigurationError(f"--controllers-per-process must be ≥ 1, got "
                                 f"{args.controllers_per_process}")
    return await run_fleet(fleet, args, out)


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return run_main(lambda: main_async(args, sys.stdout), prog=PROG,
                    stop_bound_s=FLEET_STOP_BOUND_S)


if __name__ == "__main__":
    raise SystemExit(main())
