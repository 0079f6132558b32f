"""``python -m components.motors --check --robot-file FILE``: verify a real robot's wiring.

Spins each wheel briefly forward and backward, one at a time, through the robot file's
``motors`` and ``encoders`` backends (real pins; nothing else of the robot starts, no zenoh),
and reports the encoder edges each wheel produced. A step passes when the commanded wheel
moved (at least ``--min-edges``), the other one did not, and its edges had the commanded
sign; a failed step says what to fix (pins, A/B order, the motor's dead zone). The wheels are
stopped after each step and at the end, whatever ends the check.

Lift the robot (wheels off the ground) before running it.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, TextIO

from components.encoders.quadrature import DirectionMode, QuadratureDecoder
from components.miniwhegs import MINI_WHEGS
from components.motors.pwm import DEFAULT_PWM, MotorCalibration
from ubf_async.errors import ConfigurationError, UbfError

WHEELS = ("left", "right")


@dataclass(frozen=True, slots=True, kw_only=True)
class Step:
    """One spin of one wheel and what the encoders saw."""

    wheel: str
    direction: int
    edges: dict[str, int]
    """Signed edges per wheel (phase-decoded), left and right."""
    passed: bool
    advice: str


def run_check(*, motors: Any, encoders: Any, left: MotorCalibration, right: MotorCalibration,
              u: float = 30.0, spin_s: float = 1.0, settle_s: float = 0.3,
              min_edges: int = 40, out: TextIO = sys.stdout,
              sleep: Callable[[float], None] = time.sleep) -> list[Step]:
    """Spin each wheel at wheel command ``±u`` for ``spin_s`` and judge the encoders."""
    calibrations = {"left": left, "right": right}
    stop = {"left_ms": left.zero_ms, "right_ms": right.zero_ms}
    decoders = {w: QuadratureDecoder(mode=DirectionMode.PHASE, initial_state=s)
                for w, s in zip(WHEELS, encoders.current_states(), strict=True)}
    steps: list[Step] = []
    try:
        motors.apply_pulses(left_ms=DEFAULT_PWM.init_ms, right_ms=DEFAULT_PWM.init_ms)
        motors.apply_pulses(**stop)
        sleep(settle_s)
        encoders.read_phases()  # forget what arming the drivers moved
        for wheel in WHEELS:
            for direction in (1, -1):
                pulse = calibrations[wheel].pulse_ms(direction * u)
                motors.apply_pulses(**{**stop, f"{wheel}_ms": pulse})
                sleep(spin_s)
                motors.apply_pulses(**stop)
                sleep(settle_s)
                phases = dict(zip(WHEELS, encoders.read_phases(), strict=True))
                edges = {w: decoders[w].feed(phases[w]) for w in WHEELS}
                step = _judge(wheel, direction, edges, min_edges=min_edges)
                steps.append(step)
                revs = edges[wheel] / MINI_WHEGS.edges_per_rev
                print(f"{wheel:>5} {'forward' if direction > 0 else 'reverse':<8} "
                      f"({pulse:.3f} ms): left {edges['left']:+6d} edges, right "
                      f"{edges['right']:+6d} edges ({revs:+.2f} rev)  "
                      f"{'ok' if step.passed else 'FAIL: ' + step.advice}", file=out,
                      flush=True)
    finally:
        motors.apply_pulses(**stop)
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
    try:
        motors, encoders, left, right = _backends(args.robot_file)
    except UbfError as exc:
        print(f"{parser.prog}: {exc}", file=sys.stderr)
        return 2
    print(f"checking the wiring of {args.robot_file}: each wheel {args.spin_s:g} s forward, "
          f"then reverse, at u={args.u:g} (Ctrl-C stops the wheels and ends it)", flush=True)
    try:
        steps = run_check(motors=motors, encoders=encoders, left=left, right=right, u=args.u,
                          spin_s=args.spin_s, min_edges=args.min_edges)
    except KeyboardInterrupt:
        print("stopped", file=sys.stderr)
        return 130
    finally:
        encoders.close()
        motors.close()
    failed = [s for s in steps if not s.passed]
    print("wiring ok" if not failed else f"{len(failed)} of {len(steps)} steps failed")
    return 0 if not failed else 1


def _backends(robot_file: str) -> tuple[Any, Any, MotorCalibration, MotorCalibration]:
    from components.motors.component import DEFAULT_LEFT_CALIBRATION, DEFAULT_RIGHT_CALIBRATION
    from ubf_async.robotfile import load_robot

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
    except Exception:
        motors.close()
        raise
    left, right = motors_dev.params.get("left"), motors_dev.params.get("right")
    return (motors, encoders,
            left.calibration() if left is not None else DEFAULT_LEFT_CALIBRATION,
            right.calibration() if right is not None else DEFAULT_RIGHT_CALIBRATION)
