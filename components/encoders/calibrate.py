"""Fit the skid-steer robot's effective track for odometry: ``python -m
components.encoders.calibrate``.

A skid-steer robot yaws only a fraction of what its wheel speed difference and physical
track imply (its wheel-legs slide sideways), so odometry integrates the heading with an
*effective* track (:data:`~components.encoders.odometry.EFFECTIVE_TRACK_M`, the encoders
device's ``effective_track_m``). This command drives the robot through turns — the thesis's
chase, search and spin commands, both ways — and for each one takes the wheel rotations the
encoders measured and the yaw the robot really made; the least-squares fit of

    true yaw = wheel_radius · (Δθ_right − Δθ_left) / effective_track

over all turns is the effective track. It prints the fit, each turn's residual and the
robot-file line to use.

Two ways to drive the robot:

* **a running robot, simulated or real** — with connection flags (``--connect ENDPOINT
  --robot NAME``, the shared ones of every entry point) it attaches over zenoh and joins the
  robot's behaviour tree as a remote behaviour (docs/protocol.md, "Remote behaviours") in a
  slot that outranks the tree — by default ``teleop``, which the shipped robot files place at
  priority 10 (a robot without such a slot: launch it with ``--remote teleop=10``) — so its
  commands go through the robot's own arbitration, motors and watchdog like
  ``examples/teleop_override.py``'s. For each turn it holds the robot still for ``--rest-s``,
  drives the command for ``--drive-s``, stops and lets it come to rest again; the wheel
  rotations come from the encoders' samples (``sensor/encoders/<--encoders>``) at rest before
  and after. The angle really turned (from rest to rest) comes from the simulator's truth
  (``ubf/<robot>/sim/truth``) when the robot is simulated, else from ``--turned-deg`` (one
  value per turn) or, without it, from you: after each turn it asks how many degrees the robot
  turned (counter-clockwise positive), holding the robot still until you answer. When it is
  done the robot's own tree takes over again. With ``direction: commanded`` encoders (the
  thesis's) the edges of a wheel still coasting after the stop have no commanded direction and
  are not counted, so the fit comes out ≈ 2 % small (0.413 m for the simulated Mini-WHEGS's
  0.420 m); ``direction: phase`` counts them.
* **the simulator's turn rig** — without connection flags it drives the ``mini-whegs``
  simulator plug-in's rig in this process (``turn_rig()``, found through the registry like any
  simulator): an empty world, fixed motor pulses, the yaw measured over a steady window.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import math
import sys
from collections.abc import Awaitable, Callable, Sequence
from dataclasses import dataclass
from typing import TextIO

from components.encoders.odometry import EFFECTIVE_TRACK_M, wrap_angle
from components.miniwhegs import MINI_WHEGS, MiniWhegsGeometry
from components.quadrature import edges_to_radians
from ubf_async.assembly.simulation import Simulator, TurnRig
from ubf_async.behaviors.basic import ConstantDrive
from ubf_async.cli.args import add_connection_arguments
from ubf_async.cli.attach import DEFAULT_ATTACH_TIMEOUT_S, attached_bus
from ubf_async.cli.run import run_main
from ubf_async.core.action import Action
from ubf_async.errors import ConfigurationError
from ubf_async.runtime.bus import Bus
from ubf_async.services.remote import RemoteBehaviorHost
from ubf_async.wire.protocol import Message
from ubf_async.wire.topics import ENCODERS, SIM_TRUTH, Encoders, SimTruth

__all__ = ["DEFAULT_TURNS", "Latest", "RobotTurnRig", "TrackFit", "Turn", "WheelReading",
           "ask_turned_deg", "calibrate_robot", "fit_effective_track", "format_fit",
           "given_turned_deg", "main", "measure_turns", "parse_commands", "parse_degrees",
           "simulated_rig"]

DEFAULT_TURNS: tuple[tuple[float, float], ...] = (
    (40.0, 30.0), (40.0, -30.0), (40.0, 60.0), (40.0, -60.0), (10.0, 80.0), (10.0, -80.0),
    (0.0, 100.0), (0.0, -100.0),
)
"""speed/turn commands driven: chase ±30 and ±60, search's ±80 at speed 10, spins ±100."""


@dataclass(frozen=True, slots=True, kw_only=True)
class Turn:
    """One turn as measured: the wheels' rotations (what the encoders count) and the yaw the
    body really made, over the same interval."""

    speed: float
    turn: float
    d_left_rad: float
    d_right_rad: float
    true_yaw_rad: float


@dataclass(frozen=True, slots=True, kw_only=True)
class TrackFit:
    effective_track_m: float
    turns: tuple[Turn, ...]
    geometry: MiniWhegsGeometry

    def predicted_yaw_rad(self, turn: Turn) -> float:
        r = self.geometry.wheel_radius_m
        return r * (turn.d_right_rad - turn.d_left_rad) / self.effective_track_m

    def relative_errors(self) -> list[float]:
        """Per turn: |predicted − true| / |true| (odometry's heading error with the fit)."""
        return [abs(self.predicted_yaw_rad(t) - t.true_yaw_rad) / max(abs(t.true_yaw_rad), 1e-9)
                for t in self.turns]


def fit_effective_track(turns: Sequence[Turn],
                        geometry: MiniWhegsGeometry = MINI_WHEGS) -> TrackFit:
    """Least-squares effective track: minimises Σ (r·Δθ_diff / T − yaw)² over 1/T.

    Raises :class:`~ubf_async.errors.ConfigurationError` when the turns did not turn (no
    wheel speed difference or no yaw) or the fit comes out non-positive."""
    r = geometry.wheel_radius_m
    num = sum((r * (t.d_right_rad - t.d_left_rad)) ** 2 for t in turns)
    den = sum(r * (t.d_right_rad - t.d_left_rad) * t.true_yaw_rad for t in turns)
    if num <= 0.0 or den <= 0.0:
        raise ConfigurationError("the turns measured no usable yaw (the robot did not turn "
                                 "the way its wheels did): cannot fit an effective track")
    return TrackFit(effective_track_m=num / den, turns=tuple(turns), geometry=geometry)


def measure_turns(rig: TurnRig, commands: Sequence[tuple[float, float]] = DEFAULT_TURNS, *,
                  settle_s: float = 1.0, measure_s: float = 3.0) -> list[Turn]:
    """Drive each speed/turn command on ``rig``."""
    turns = []
    for speed, turn in commands:
        d_left, d_right, yaw = rig.drive(speed=speed, turn=turn, settle_s=settle_s,
                                         measure_s=measure_s)
        turns.append(Turn(speed=speed, turn=turn, d_left_rad=d_left, d_right_rad=d_right,
                          true_yaw_rad=yaw))
    return turns


def simulated_rig(simulator: str = "mini-whegs") -> TurnRig:
    """The turn rig of a simulator plug-in (registry ``ubf_async.simulators``)."""
    from ubf_async.assembly.registry import SIMULATORS

    plugin: Simulator = SIMULATORS.get(simulator)()
    return plugin.turn_rig()


def format_fit(fit: TrackFit) -> str:
    lines = [f"{'speed/turn':>10} {'true yaw °':>11} {'physical-track °':>17} "
             f"{'fitted °':>9} {'error':>7}"]
    r, physical = fit.geometry.wheel_radius_m, fit.geometry.track_width_m
    for t, err in zip(fit.turns, fit.relative_errors(), strict=True):
        naive = math.degrees(r * (t.d_right_rad - t.d_left_rad) / physical)
        lines.append(f"{t.speed:+4.0f}/{t.turn:+4.0f} {math.degrees(t.true_yaw_rad):+11.1f} "
                     f"{naive:+17.1f} {math.degrees(fit.predicted_yaw_rad(t)):+9.1f} "
                     f"{100 * err:6.1f}%")
    lines.append(f"effective track: {fit.effective_track_m:.4f} m (physical "
                 f"{physical:.3f} m; built-in default {EFFECTIVE_TRACK_M:.4f} m)")
    lines.append(f"robot file: encoders params {{effective_track_m: "
                 f"{fit.effective_track_m:.3f}}}")
    return "\n".join(lines)


# ---------------------------------------------------------------------------------------------
# A running robot, over zenoh


@dataclass(frozen=True, slots=True, kw_only=True)
class WheelReading:
    """One ``sensor/encoders`` sample: stamp and the edges counted so far, each wheel."""

    stamp_ns: int
    left_edges: int
    right_edges: int


class Latest:
    """The newest stamp seen on a subscription and a way to wait for one at or after a time
    (robot clock): a reading taken once the robot has been at rest long enough."""

    def __init__(self) -> None:
        self.stamp_ns = -1
        self._arrived = asyncio.Event()

    def arrived(self, stamp_ns: int) -> None:
        if stamp_ns > self.stamp_ns:
            self.stamp_ns = stamp_ns
            self._arrived.set()

    async def at_or_after(self, stamp_ns: int, *, timeout_s: float, what: str) -> None:
        """Return once a sample stamped ``stamp_ns`` or later has arrived; ``ConnectionError``
        after ``timeout_s`` wall seconds without one."""
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout_s
        while self.stamp_ns < stamp_ns:
            self._arrived.clear()
            remaining = deadline - loop.time()
            if remaining <= 0:
                raise ConnectionError(f"no {what} within {timeout_s:g} s")
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._arrived.wait(), remaining)


class RobotTurnRig:
    """Drives a running robot through turns over the bus (see the module docstring): a remote
    behaviour in the slot ``name`` of ``composite`` — a
    :class:`~ubf_async.behaviors.basic.ConstantDrive`
    whose action is the turn's command while it is driven, a stop otherwise: never an
    abstention, so the robot's own tree cannot move it between turns (a person may be
    measuring) — the wheels from the encoders ``encoders``' samples, the true yaw from the
    simulator's truth (``truth``) or from ``answer`` (given or asked per turn: see
    :func:`ask_turned_deg`)."""

    def __init__(self, *, bus: Bus, encoders: str = "wheels", name: str = "teleop",
                 composite: str = "seek_pink_ball", priority: int = 10,
                 drive_s: float = 3.0, rest_s: float = 1.0, timeout_s: float = 10.0,
                 out: TextIO = sys.stdout) -> None:
        self.bus = bus
        self.drive_s = drive_s
        self.rest_s = rest_s
        self.timeout_s = timeout_s
        self.out = out
        self.commands = ConstantDrive(name=name)
        self.host = RemoteBehaviorHost(bus=bus, behavior=self.commands, composite=composite,
                                       rate_hz=25.0, ttl_s=0.5, priority=priority)
        self.wheels: WheelReading | None = None
        self.encoder_mode: str | None = None
        self._wheels = Latest()
        self.heading_rad: float | None = None
        """The simulator's true heading, unwrapped (full turns count), while it publishes."""
        self._truth = Latest()
        self.malformed: dict[str, int] = {}
        self._encoders_key = ENCODERS.key(bus.keys, encoders)
        self._subs = [
            bus.subscribe_topic(self._encoders_key, ENCODERS, self._on_encoders, self.malformed),
            bus.subscribe_topic(SIM_TRUTH.key(bus.keys), SIM_TRUTH, self._on_truth,
                                self.malformed),
        ]

    def _on_encoders(self, key: str, message: Message[Encoders], received_ns: int) -> None:
        self.wheels = WheelReading(stamp_ns=message.stamp_ns,
                                   left_edges=message.data.left_edges,
                                   right_edges=message.data.right_edges)
        self.encoder_mode = message.data.mode
        self._wheels.arrived(message.stamp_ns)

    def _on_truth(self, key: str, message: Message[SimTruth], received_ns: int) -> None:
        heading = message.data.robot.heading_rad
        if self.heading_rad is None:
            self.heading_rad = heading
        else:  # 20 truth samples a second: far less than half a turn apart
            self.heading_rad += wrap_angle(heading - self.heading_rad)
        self._truth.arrived(message.stamp_ns)

    async def start(self, *, truth_wait_s: float = 2.0) -> bool:
        """Take control of the robot (its drive commands name this behaviour as the winner)
        and wait for the encoders; return whether the simulator's truth is there."""
        await self.host.start()
        name = self.commands.name
        await self._until(lambda: self.host.robot_winners == [name],
                          lambda: f"the robot to follow {name!r} (its drive commands name "
                          f"{self.host.robot_winners or 'no winner'}): it needs a remote slot "
                          f"{name!r} that outranks its tree, e.g. launch --remote {name}=10")
        await self._wheels.at_or_after(0, timeout_s=self.timeout_s,
                                       what=f"encoder samples on {self._encoders_key}")
        with contextlib.suppress(ConnectionError):
            await self._truth.at_or_after(0, timeout_s=truth_wait_s, what="truth")
        return self.heading_rad is not None

    async def _until(self, condition: Callable[[], bool], what: Callable[[], str]) -> None:
        """Wait for ``condition``; :class:`ConnectionError` after ``timeout_s`` saying
        ``what()`` — built then, so it tells what the robot does at that moment."""
        loop = asyncio.get_running_loop()
        deadline = loop.time() + self.timeout_s
        while not condition():
            if loop.time() > deadline:
                raise ConnectionError(f"timed out after {self.timeout_s:g} s waiting for "
                                      f"{what()}")
            await asyncio.sleep(0.02)

    async def _at_rest(self) -> tuple[WheelReading, float | None]:
        """Hold the robot still for ``rest_s`` (robot clock), then the wheels and (simulated)
        the heading read after it."""
        self.commands.action = Action(speed=0.0, turn=0.0)
        await self.bus.clock.sleep(self.rest_s)
        now = self.bus.clock.now_ns()
        await self._wheels.at_or_after(now, timeout_s=self.timeout_s, what="encoder samples")
        if self.heading_rad is not None:
            await self._truth.at_or_after(now, timeout_s=self.timeout_s, what="truth samples")
        assert self.wheels is not None
        return self.wheels, self.heading_rad

    async def drive(self, speed: float, turn: float) -> tuple[float, float, float | None]:
        """One turn from rest to rest: ``(Δθ_left, Δθ_right, true yaw or None)`` in radians
        (None without the simulator's truth)."""
        before, heading0 = await self._at_rest()
        self.commands.action = Action(speed=speed, turn=turn)
        await self.bus.clock.sleep(self.drive_s)
        after, heading1 = await self._at_rest()
        yaw = heading1 - heading0 if heading0 is not None and heading1 is not None else None
        return (edges_to_radians(after.left_edges - before.left_edges),
                edges_to_radians(after.right_edges - before.right_edges), yaw)

    async def measure(self, commands: Sequence[tuple[float, float]], *,
                      answer: Callable[[int, float, float], Awaitable[float]] | None = None
                      ) -> list[Turn]:
        """ConstantDrive each command; the true yaw from ``answer(index, speed, turn)`` in degrees
        when given (the robot is held still while it is awaited), else from the simulator's
        truth."""
        turns = []
        for index, (speed, turn) in enumerate(commands):
            d_left, d_right, yaw = await self.drive(speed, turn)
            if answer is not None:
                yaw = math.radians(await answer(index, speed, turn))
                source = "given"
            elif yaw is None:
                raise ConfigurationError("no simulator truth and no way to learn the angle "
                                         "turned (--turned-deg or a terminal)")
            else:
                source = "simulator's truth"
            print(f"turn {index + 1}/{len(commands)}: speed {speed:+.0f} turn {turn:+.0f} for "
                  f"{self.drive_s:g} s: wheels {d_left:+.2f} / {d_right:+.2f} rad, turned "
                  f"{math.degrees(yaw):+.1f}° ({source})", file=self.out, flush=True)
            turns.append(Turn(speed=speed, turn=turn, d_left_rad=d_left, d_right_rad=d_right,
                              true_yaw_rad=yaw))
        return turns

    async def aclose(self) -> None:
        """Hand the robot back to its tree (the host's last vote abstains) and unsubscribe."""
        await self.host.aclose()
        for sub in self._subs:
            sub.close()


def ask_turned_deg(read_line: Callable[[str], str] = input) -> Callable[[int, float, float],
                                                                        Awaitable[float]]:
    """The person measuring: after each turn, the angle the robot turned from rest to rest,
    in degrees, counter-clockwise positive (asked again until it is a number). ``read_line``
    runs in a worker thread: the event loop keeps the robot held still meanwhile."""

    async def answer(index: int, speed: float, turn: float) -> float:
        while True:
            try:
                text = await asyncio.to_thread(
                    read_line, f"turn {index + 1} (speed {speed:+.0f}, turn {turn:+.0f}): "
                               "degrees turned, counter-clockwise positive? ")
            except EOFError:
                raise ConfigurationError("no answer (end of input): give the angles with "
                                         "--turned-deg instead") from None
            try:
                value = float(text.strip().rstrip("°"))
            except ValueError:
                continue
            if math.isfinite(value):
                return value

    return answer


def given_turned_deg(values: Sequence[float]) -> Callable[[int, float, float],
                                                          Awaitable[float]]:
    """``--turned-deg``: the angle of each turn, in order."""

    async def answer(index: int, speed: float, turn: float) -> float:
        return values[index]

    return answer


def parse_commands(text: str) -> list[tuple[float, float]]:
    """``"SPEED:TURN,..."`` → commands, each within ±100."""
    commands = []
    for part in text.split(","):
        try:
            speed, turn = (float(v) for v in part.strip().split(":"))
        except ValueError:
            raise argparse.ArgumentTypeError(f"bad command {part.strip()!r}: expected "
                                             "SPEED:TURN, e.g. 0:100") from None
        if not (abs(speed) <= 100 and abs(turn) <= 100):
            raise argparse.ArgumentTypeError(f"bad command {part.strip()!r}: speed and turn "
                                             "within ±100")
        commands.append((speed, turn))
    return commands


def parse_degrees(text: str) -> list[float]:
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected degrees separated by commas, got "
                                         f"{text!r}") from None
    if not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError("angles must be finite")
    return values


async def calibrate_robot(args: argparse.Namespace, out: TextIO = sys.stdout) -> int:
    """The robot path of :func:`main`."""
    commands = args.commands or list(DEFAULT_TURNS)
    if args.secure is not None and args.identity is None:
        args.identity = args.name  # in secure mode a remote slot's identity is its name
    if args.turned_deg is not None and len(args.turned_deg) != len(commands):
        raise ConfigurationError(f"--turned-deg gives {len(args.turned_deg)} angles for "
                                 f"{len(commands)} turns")
    async with attached_bus(args) as bus:
        rig = RobotTurnRig(bus=bus, encoders=args.encoders, name=args.name,
                           composite=args.composite, priority=args.priority,
                           drive_s=args.drive_s, rest_s=args.rest_s,
                           timeout_s=args.wait_for_robot_s, out=out)
        try:
            simulated = await rig.start()
            if args.turned_deg is not None:  # the angles given win over any truth
                answer = given_turned_deg(args.turned_deg)
                truth = "the angles given (--turned-deg)"
            elif simulated:
                answer, truth = None, f"the simulator's truth on {SIM_TRUTH.key(bus.keys)}"
            else:
                answer, truth = ask_turned_deg(), "you (after each turn)"
            print(f"driving robot {bus.robot!r} through {len(commands)} turns as remote "
                  f"behaviour {args.name!r} in {args.composite!r}; wheels from "
                  f"sensor/encoders/{args.encoders} ({rig.encoder_mode or 'unknown'} "
                  f"direction), angles turned from {truth}", file=out, flush=True)
            turns = await rig.measure(commands, answer=answer)
        finally:
            await rig.aclose()
    print(format_fit(fit_effective_track(turns)), file=out)
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m components.encoders.calibrate",
        description=(__doc__ or "").replace("``", ""),
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="examples:\n"
               "  python -m components.encoders.calibrate          # the simulator's turn rig\n"
               "  python -m components.encoders.calibrate --connect tcp/192.168.1.20:7447 "
               "--robot pi\n"
               "  python -m components.encoders.calibrate --connect tcp/127.0.0.1:7447 "
               "--commands 0:100,0:-100 --turned-deg 275,-270")
    add_connection_arguments(parser)
    rig = parser.add_argument_group("the simulator's turn rig (no connection flags)")
    rig.add_argument("--simulator", default="mini-whegs",
                     help="simulator plug-in whose robot is driven (default mini-whegs)")
    rig.add_argument("--settle-s", type=float, default=1.0,
                     help="seconds driven before each measurement (default 1)")
    rig.add_argument("--measure-s", type=float, default=3.0,
                     help="seconds measured per command (default 3)")
    robot = parser.add_argument_group("a running robot (with connection flags)")
    robot.add_argument("--encoders", default="wheels", metavar="NAME",
                       help="the encoders device whose samples are read (default wheels)")
    robot.add_argument("--name", default="teleop",
                       help="the remote behaviour's name: a slot of the robot's tree that "
                            "outranks it (default teleop, priority 10 in the shipped robot "
                            "files)")
    robot.add_argument("--composite", default="seek_pink_ball",
                       help="the composite of the robot's tree to join")
    robot.add_argument("--priority", type=int, default=10,
                       help="priority asked for (the robot's slot decides; default 10)")
    robot.add_argument("--commands", type=parse_commands, default=None,
                       metavar="S:T[,S:T...]", help="speed:turn of each turn (default: "
                       + ", ".join(f"{s:g}:{t:g}" for s, t in DEFAULT_TURNS) + ")")
    robot.add_argument("--drive-s", type=float, default=3.0,
                       help="robot-clock seconds each turn is driven (default 3)")
    robot.add_argument("--rest-s", type=float, default=1.0,
                       help="robot-clock seconds held still before and after each turn "
                            "(default 1)")
    robot.add_argument("--turned-deg", type=parse_degrees, default=None,
                       metavar="DEG[,DEG...]",
                       help="the angle each turn really made, from rest to rest, counter-"
                            "clockwise positive, one per turn (default: the simulator's truth "
                            "if the robot is simulated, else asked after each turn)")
    robot.add_argument("--wait-for-robot-s", type=float, default=DEFAULT_ATTACH_TIMEOUT_S,
                       metavar="S", help="how long to wait for the robot, its encoders and "
                                         "its obeying the commands")
    args = parser.parse_args(argv)
    prog = parser.prog
    attach = bool(args.connect or args.listen or args.config or args.mode == "client")
    if not attach:
        if not (args.settle_s >= 0 and args.measure_s > 0):
            parser.error("--settle-s must be >= 0 and --measure-s > 0")
        try:
            fit = fit_effective_track(measure_turns(simulated_rig(args.simulator),
                                                    settle_s=args.settle_s,
                                                    measure_s=args.measure_s))
        except ConfigurationError as exc:
            print(f"{prog}: error: {exc}", file=sys.stderr)
            return 2
        print(format_fit(fit))
        return 0
    if not (args.drive_s > 0 and args.rest_s > 0):
        parser.error("--drive-s and --rest-s must be > 0")
    return run_main(lambda: calibrate_robot(args), prog=prog)


if __name__ == "__main__":
    raise SystemExit(main())
