"""``python -m components.bringup ROBOT_FILE``: bring a real robot up one device at a time.

Every device of the robot file is checked in turn through its own backend, with what can be
done without moving the robot, and gets one line: ``ok``, ``FAIL`` with what to do, or ``--``
(nothing to check here: a simulated backend, or the motors, which move — their check is
``python -m components.motors --check``, the wheels lifted):

* a **range finder** is read five times: its bus opens, its address answers, its distance;
* a **camera** takes a frame, saved with the pink pixels marked and the five bins' counts
  drawn (``--out``), and says what it counts;
* the **encoders** listen ``--turn-s`` seconds while you turn each wheel by hand, and say
  which wheel's lines moved;
* the **LEDs** (a backend that lights real ones) light one at a time, LED 0 first, twice
  round, while you watch that each lights;
* the rest (radio, LEDs in memory) have nothing to check here.

Nothing of the robot starts: no zenoh, no controller. Exit status 1 if any device failed.
The checks are plain classes (:class:`RangeCheck`, :class:`CameraCheck`,
:class:`EncodersCheck`, :class:`LedsCheck`) run on whatever backend they are given, fakes
included.
"""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import cv2

from components.camera.seekcolor import PINK, ColorRange, seekcolor
from components.camera.view import draw_view
from components.leds.component import DEFAULT_COUNT
from components.range.backend import MountPose
from ubf_async.assembly.robotfile import ResolvedDevice, load_robot
from ubf_async.cli.run import run_sync
from ubf_async.errors import DeviceError, UbfError

__all__ = ["CHECKS", "PROG", "CameraCheck", "DeviceCheck", "EncodersCheck", "LedsCheck",
           "Line", "RangeCheck", "bring_up", "main"]

PROG = "python -m components.bringup"
RANGE_READS = 5
DEFAULT_TURN_S = 5.0
BLINK_ROUNDS = 2
BLINK_S = 0.4
"""How long each LED stays lit while the LEDs blink in turn."""


@dataclass(frozen=True, slots=True)
class Line:
    """One device's verdict: ``status`` is ``ok``, ``FAIL`` or ``--`` (nothing checked)."""

    device: str
    status: str
    text: str

    def __str__(self) -> str:
        return f"{self.status:<4}  {self.device}: {self.text}"


class DeviceCheck(Protocol):
    """What can be checked of one kind of device without moving the robot."""

    def check(self, device: ResolvedDevice, backend: Any) -> Line: ...


class RangeCheck:
    """Five reads: each a distance (or nothing in range); a read the bus refuses fails."""

    def check(self, device: ResolvedDevice, backend: Any) -> Line:
        name = f"range/{device.name}"
        params = device.params
        mount = MountPose(x_m=params.get("x_m", 0.05), y_m=params.get("y_m", 0.0),
                          yaw_rad=math.radians(params.get("yaw_deg", 0.0)))
        readings, errors = [], []
        for _ in range(RANGE_READS):
            try:
                readings.append(backend.distance_m(mount, max_range_m=2.0))
            except DeviceError as exc:
                errors.append(str(exc))
        if errors:
            return Line(name, "FAIL", f"{len(errors)} of {RANGE_READS} reads failed: "
                                      f"{errors[0]} — is it wired, at the address the file "
                                      f"says? (i2cdetect -y BUS lists what answers)")
        seen = [r for r in readings if r is not None]
        return Line(name, "ok", (f"{RANGE_READS} reads, {min(seen) * 100:.1f}–"
                                 f"{max(seen) * 100:.1f} cm" if seen else
                                 f"{RANGE_READS} reads, nothing in range: hold a hand in "
                                 f"front of it and check again"))


class CameraCheck:
    """One frame, saved with what seekcolor counts in it (the camera's ``seek_color``, else
    ``color``)."""

    def __init__(self, out: Path, color: ColorRange = PINK) -> None:
        self.out = out
        self.color = color

    def check(self, device: ResolvedDevice, backend: Any) -> Line:
        name = f"camera/{device.name}"
        try:
            backend.prepare()
            frame = backend.capture()
        except DeviceError as exc:
            return Line(name, "FAIL", f"{exc} — is the camera connected, and yours to open "
                                      f"(group video)?")
        seek_color = device.params.get("seek_color")
        color = seek_color.color_range() if seek_color is not None else self.color
        result = seekcolor(frame, color)
        self.out.mkdir(parents=True, exist_ok=True)
        picture = self.out / f"camera-{device.name}.png"
        cv2.imwrite(str(picture), draw_view(frame, result, color=color))
        height, width = frame.shape[:2]
        return Line(name, "ok", f"a {width}×{height} frame, {result.total} pink pixels "
                                f"(bins {list(result.bins)}): {picture}")


class EncodersCheck:
    """``turn_s`` seconds of listening while each wheel is turned by hand."""

    def __init__(self, turn_s: float, *, say: Callable[[str], None],
                 wait: Callable[[float], None] = time.sleep) -> None:
        self.turn_s = turn_s
        self.say = say
        self.wait = wait

    def check(self, device: ResolvedDevice, backend: Any) -> Line:
        name = f"encoders/{device.name}"
        backend.read_phases()  # what came before is not the hand's
        self.say(f"{name}: turn each wheel by hand now ({self.turn_s:g} s) ...")
        self.wait(self.turn_s)
        left, right = (len(edges) for edges in backend.read_phases())
        still = [wheel for wheel, edges in (("left", left), ("right", right)) if not edges]
        counted = f"left {left} edges, right {right} edges"
        if still:
            pins = device.backend_params
            lines = " and ".join(f"{wheel}: {pins.get(f'{wheel}_a')}/{pins.get(f'{wheel}_b')}"
                                 for wheel in still)
            return Line(name, "FAIL", f"{counted}: no edges from the {' and '.join(still)} "
                                      f"wheel — check its A/B lines ({lines}), their power and "
                                      f"the pull-ups")
        return Line(name, "ok", counted)


class LedsCheck:
    """Each LED lit alone in turn, LED 0 first, :data:`BLINK_ROUNDS` times round, then all
    off: the pins are driven, and you see whether each LED lights, in its place."""

    def __init__(self, *, say: Callable[[str], None],
                 wait: Callable[[float], None] = time.sleep) -> None:
        self.say = say
        self.wait = wait

    def check(self, device: ResolvedDevice, backend: Any) -> Line:
        name = f"leds/{device.name}"
        if not backend.physical:
            return Line(name, "--", f"{device.backend} backend: LEDs in memory, nothing to "
                                    f"light here")
        count = backend.count or device.params.get("count") or DEFAULT_COUNT
        pins = device.backend_params.get("pins") or [f"LED {i}" for i in range(count)]
        self.say(f"{name}: watch the LEDs light one at a time, LED 0 ({pins[0]}) first ...")
        try:
            for _ in range(BLINK_ROUNDS):
                for led in range(count):
                    backend.set_leds(1 << led)
                    self.wait(BLINK_S)
        finally:
            backend.set_leds(0)
        return Line(name, "ok", f"{count} LEDs lit in turn ({', '.join(pins)}); one that "
                                f"stayed dark: check its wiring, its resistor and polarity, "
                                f"and active_high")


CHECKS: dict[str, Callable[[argparse.Namespace, Callable[[str], None]], DeviceCheck]] = {
    "range": lambda args, say: RangeCheck(),
    "camera": lambda args, say: CameraCheck(args.out),
    "encoders": lambda args, say: EncodersCheck(args.turn_s, say=say),
    "leds": lambda args, say: LedsCheck(say=say),
}
"""What is checked per kind of device (the others have nothing to check here)."""

NOT_HERE = {
    "motors": "not moved here: python -m components.motors --backend gpio --check "
              "--robot-file FILE, the wheels lifted",
}


def bring_up(devices: Sequence[ResolvedDevice], checks: dict[str, DeviceCheck]) -> list[Line]:
    """Each device checked in turn through its backend (built, then closed)."""
    lines = []
    for device in devices:
        name = f"{device.kind}/{device.name}"
        if device.requires_simulator:
            lines.append(Line(name, "--", f"{device.backend} backend (simulated): nothing to "
                                          f"bring up"))
            continue
        check = checks.get(device.kind)
        if check is None:
            lines.append(Line(name, "--", NOT_HERE.get(device.kind, f"{device.backend} "
                                                                     f"backend: nothing to "
                                                                     f"check here")))
            continue
        try:  # real backends use no bus or clock (python -m components.motors --check alike)
            backend = device.backend_factory(context=None, **device.backend_params)
        except UbfError as exc:
            lines.append(Line(name, "FAIL", str(exc)))
            continue
        try:
            lines.append(check.check(device, backend))
        finally:
            backend.close()
    return lines


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=PROG, description=__doc__.split("\n\n")[0].split(": ", 1)[1],
        epilog=f"example:\n  {PROG} examples/robots/pi-whegs.yaml --out bringup",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("robot_file", metavar="ROBOT_FILE")
    parser.add_argument("--out", type=Path, default=Path("bringup"), metavar="DIR",
                        help="where the cameras' frames are saved (default: bringup)")
    parser.add_argument("--turn-s", type=float, default=DEFAULT_TURN_S, metavar="S",
                        help=f"how long to turn the wheels by hand (default: "
                             f"{DEFAULT_TURN_S:g})")
    return parser


def _say(text: str) -> None:
    print(text, flush=True)


def _main(args: argparse.Namespace) -> int:
    robot = load_robot(args.robot_file)
    checks = {kind: make(args, _say) for kind, make in CHECKS.items()}
    lines = bring_up(robot.devices, checks)
    for line in lines:
        print(line)
    failed = sum(line.status == "FAIL" for line in lines)
    print(f"{failed} of {len(lines)} devices failed" if failed
          else f"{robot.name}: every device checked is up")
    return 1 if failed else 0


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if not args.turn_s > 0:
        build_parser().error(f"--turn-s must be > 0, got {args.turn_s:g}")
    return run_sync(lambda: _main(args), prog=PROG)


if __name__ == "__main__":
    raise SystemExit(main())
