"""``python -m components.motors --check --robot-file FILE``: verify a real robot's wiring.

Spins each wheel briefly forward and backward, one at a time, through the robot file's
``motors`` and ``encoders`` backends (real pins; nothing else of the robot starts, no zenoh),
and reports the encoder counts (and edges) each wheel produced. A step passes when the
commanded wheel moved (at least ``--min-edges``), the other one did not, and its edges had the
commanded sign; a failed step says what to fix (pins, A/B order, the motor's dead zone). The
wheels are stopped after each step and at the end, whatever ends the check.

Lift the robot (wheels off the ground) before running it.

Stopping: SIGTERM or Ctrl-C (SIGINT) raises :class:`Interrupted` in the check wherever it is;
the check then applies the stop pulses, holds them for the backend's ``hold_s`` (two PWM
periods) and releases the pins, and exits with 128 + the signal's number. Signals after the
first are ignored while that bounded shutdown runs, so they cannot cut the stop pulse short.
The check runs on no event loop: its waits are plain sleeps.
"""

from __future__ import annotations

import argparse
import contextlib
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from types import FrameType
from typing import Protocol, TextIO

import numpy as np

from components.miniwhegs import MINI_WHEGS
from components.motors.backend import MotorBackend
from components.motors.pwm import DEFAULT_PWM, MotorCalibration
from components.quadrature import DirectionMode, QuadratureDecoder, edges_to_counts
from ubf_async.errors import ConfigurationError, UbfError

__all__ = ["STOP_SIGNALS", "WHEELS", "EncoderLines", "Interrupted", "Step", "hold", "main",
           "release", "run_check", "signals_interrupt"]

WHEELS = ("left", "right")
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


class Interrupted(BaseException):
    """SIGTERM or Ctrl-C during the check. A ``BaseException``, like ``KeyboardInterrupt``, so
    that no ``except Exception`` on the way swallows it."""

    def __init__(self, signum: int) -> None:
        super().__init__(signum)
        self.signum = signum

    @property
    def name(self) -> str:
        return signal.Signals(self.signum).name


@contextlib.contextmanager
def signals_interrupt() -> Iterator[None]:
    """While the block runs (in the main thread), the first SIGINT or SIGTERM raises
    :class:`Interrupted`; later ones are ignored (the shutdown they would interrupt is the
    stop pulse's bounded hold and the release of the pins)."""
    if threading.current_thread() is not threading.main_thread():
        yield  # signals reach only the main thread
        return
    received: list[int] = []

    def handle(signum: int, frame: FrameType | None) -> None:
        received.append(signum)
        if len(received) == 1:
            raise Interrupted(signum)

    previous = {sig: signal.signal(sig, handle) for sig in STOP_SIGNALS}
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def hold(seconds: float, sleep: Callable[[float], None] = time.sleep,
         clock: Callable[[], float] = time.monotonic) -> None:
    """Sleep ``seconds`` of wall time in full, even through an :class:`Interrupted`, which is
    raised once the time is up: a pulse being held is never cut short. ``clock`` is the time
    ``sleep`` lets pass (seconds), what the hold is measured on."""
    deadline = clock() + seconds
    interrupted: Interrupted | None = None
    while (left := deadline - clock()) > 0:
        try:
            sleep(left)
        except Interrupted as exc:
            interrupted = exc
    if interrupted is not None:
        raise interrupted


@dataclass(frozen=True, slots=True, kw_only=True)
class Step:
    """One spin of one wheel and what the encoders saw."""

    wheel: str
    direction: int
    edges: dict[str, int]
    """Signed edges per wheel (phase-decoded), left and right."""
    passed: bool
    advice: str

    @property
    def counts(self) -> dict[str, float]:
        """Signed encoder counts per wheel (full quadrature cycles: four edges each)."""
        return {w: edges_to_counts(e, MINI_WHEGS) for w, e in self.edges.items()}


class EncoderLines(Protocol):
    """What the check reads of the robot file's encoders backend (an encoders backend: the
    motors package does not import that package's interface, devices being independent)."""

    def current_states(self) -> tuple[int, int] | None: ...

    def read_phases(self) -> tuple[np.ndarray, np.ndarray]: ...

    def close(self) -> None: ...


def run_check(*, motors: MotorBackend, encoders: EncoderLines, left: MotorCalibration,
              right: MotorCalibration,
              u: float = 30.0, spin_s: float = 1.0, settle_s: float = 0.3,
              min_edges: int = 40, out: TextIO = sys.stdout,
              sleep: Callable[[float], None] = time.sleep,
              clock: Callable[[], float] = time.monotonic) -> list[Step]:
    """Spin each wheel at wheel command ``±u`` for ``spin_s`` and judge the encoders.

    The init pulse and the final stop pulse are held for the motors' ``hold_s`` (two PWM
    periods) with ``sleep``, whatever ends the check: the caller may release the pins as soon
    as this returns or raises. ``sleep`` and ``clock`` go together: the time ``sleep`` lets
    pass is what ``clock`` reads (a test gives both on a virtual clock)."""
    calibrations = {"left": left, "right": right}
    stop = {"left_ms": left.zero_ms, "right_ms": right.zero_ms}
    held = motors.hold_s
    states = encoders.current_states() or (None, None)
    decoders = {w: QuadratureDecoder(mode=DirectionMode.PHASE, initial_state=s)
                for w, s in zip(WHEELS, states, strict=True)}
    steps: list[Step] = []
    try:
        motors.apply_pulses(left_ms=DEFAULT_PWM.init_ms, right_ms=DEFAULT_PWM.init_ms)
        sleep(held)  # the drivers arm on whole periods of the init pulse
        motors.apply_pulses(**stop)
        sleep(settle_s)
        encoders.read_phases()  # forget what arming the drivers moved
        for wheel in WHEELS:
            for direction in (1, -1):
                pulse = calibrations[wheel].pulse_ms(direction * u)
                name = "forward" if direction > 0 else "reverse"
                motors.apply_pulses(**{**stop, f"{wheel}_ms": pulse})
                # Said as it spins: the builder watching the robot knows which wheel should
                # be turning.
                print(f"{wheel} {name}: {pulse:.3f} ms for {spin_s:g} s ...", file=out,
                      flush=True)
                sleep(spin_s)
                motors.apply_pulses(**stop)
                sleep(settle_s)
                phases = dict(zip(WHEELS, encoders.read_phases(), strict=True))
                edges = {w: decoders[w].feed(phases[w]) for w in WHEELS}
                step = _judge(wheel, direction, edges, min_edges=min_edges)
                steps.append(step)
                counts = step.counts
                revs = edges[wheel] / MINI_WHEGS.edges_per_rev
                print(f"  left {counts['left']:+8.2f} counts ({edges['left']:+d} edges), "
                      f"right {counts['right']:+8.2f} counts ({edges['right']:+d} edges): "
                      f"{revs:+.2f} rev of the {wheel} wheel  "
                      f"{'ok' if step.passed else 'FAIL: ' + step.advice}", file=out,
                      flush=True)
    finally:
        motors.apply_pulses(**stop)
        hold(held, sleep, clock)  # whole periods of the stop pulse before the pins are released
    return steps


def _judge(wheel: str, direction: int, edges: dict[str, int], *, min_edges: int) -> Step:
    other = "right" if wheel == "left" else "left"
    moved, still = edges[wheel], edges[other]
    advice = ""
    if abs(moved) < min_edges and abs(still) >= min_edges:
        advice = (f"the {other} encoder moved instead: the motor pins or the encoder pins of "
                  f"the two wheels are swapped")
    elif abs(moved) < min_edges:
        advice = (f"the {wheel} encoder saw {abs(moved)} edges: check the {wheel} motor's pin "
                  f"and power, its dead_zone_ms, and the encoder's {wheel}_a/{wheel}_b pins")
    elif abs(still) >= min_edges:
        advice = f"the {other} wheel moved too ({still:+d} edges): are the encoders shorted?"
    elif (moved > 0) != (direction > 0):
        advice = (f"the {wheel} wheel counted backwards: swap {wheel}_a and {wheel}_b (or the "
                  f"motor's leads, if the wheel itself turned the wrong way)")
    return Step(wheel=wheel, direction=direction, edges=edges, passed=not advice, advice=advice)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m components.motors --check",
        description=__doc__.split("\n\n")[1] + " Lift the robot first.")
    parser.add_argument("--check", action="store_true", required=True,
                        help="run the wiring check (this command)")
    parser.add_argument("--robot-file", required=True, metavar="FILE",
                        help="the robot file whose motors and encoders to check")
    parser.add_argument("--backend", default=None,
                        help="(ignored: the robot file names the backends)")
    parser.add_argument("--u", type=float, default=30.0,
                        help="wheel command of each spin, 1–100 (default 30)")
    parser.add_argument("--spin-s", type=float, default=1.0, help="length of each spin")
    parser.add_argument("--min-edges", type=int, default=40,
                        help="edges a spinning wheel must produce (default 40 = 10 counts)")
    args = parser.parse_args(argv)
    if not 0 < args.u <= 100:
        parser.error(f"--u must be within (0, 100], got {args.u}")
    with signals_interrupt():
        try:
            steps = _check(args)
        except UbfError as exc:
            print(f"{parser.prog}: {exc}", file=sys.stderr)
            return 2
        except Interrupted as stop:
            print(f"{parser.prog}: {stop.name}: the wheels were stopped and the pins released",
                  file=sys.stderr)
            return 128 + stop.signum
    failed = [s for s in steps if not s.passed]
    print("wiring ok" if not failed else f"{len(failed)} of {len(steps)} steps failed")
    return 0 if not failed else 1


def _check(args: argparse.Namespace) -> list[Step]:
    motors, encoders, left, right = _backends(args.robot_file)
    try:
        print(f"checking the wiring of {args.robot_file}: each wheel {args.spin_s:g} s "
              f"forward, then reverse, at u={args.u:g} (Ctrl-C or SIGTERM stops the wheels "
              f"and ends it)", flush=True)
        return run_check(motors=motors, encoders=encoders, left=left, right=right, u=args.u,
                         spin_s=args.spin_s, min_edges=args.min_edges)
    finally:  # run_check has held the stop pulse: the pins can go
        release(encoders.close, motors.close)


def release(*closers: Callable[[], object]) -> None:
    """Call every closer, even if an :class:`Interrupted` arrives during one (raised after)."""
    interrupted: Interrupted | None = None
    for close in closers:
        try:
            close()
        except Interrupted as exc:
            interrupted = exc
    if interrupted is not None:
        raise interrupted


def _backends(robot_file: str) -> tuple[MotorBackend, EncoderLines, MotorCalibration,
                                        MotorCalibration]:
    from components.motors.pwm import DEFAULT_LEFT_CALIBRATION, DEFAULT_RIGHT_CALIBRATION
    from ubf_async.assembly.robotfile import load_robot

    robot = load_robot(robot_file)
    found = {d.kind: d for d in reversed(robot.devices)}
    missing = [k for k in ("motors", "encoders") if k not in found]
    if missing:
        raise ConfigurationError(f"{robot_file}: no {' or '.join(missing)} device to check")
    motors_dev, encoders_dev = found["motors"], found["encoders"]
    if motors_dev.requires_simulator or encoders_dev.requires_simulator:
        raise ConfigurationError(f"{robot_file}: the check drives real hardware; its motors "
                                 f"and encoders use simulated backends")
    # The GPIO backends use no bus or clock: the check runs without a robot around them.
    motors = motors_dev.backend_factory(context=None, **motors_dev.backend_params)
    try:
        encoders = encoders_dev.backend_factory(context=None, **encoders_dev.backend_params)
    except BaseException:  # Interrupted too: the motor pins are released either way
        motors.close()
        raise
    left, right = motors_dev.params.get("left"), motors_dev.params.get("right")
    return (motors, encoders,
            left.calibration() if left is not None else DEFAULT_LEFT_CALIBRATION,
            right.calibration() if right is not None else DEFAULT_RIGHT_CALIBRATION)
