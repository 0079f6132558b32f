"""``python -m components.motors``: the motor driver as its own process."""

from __future__ import annotations

import argparse

from components.motors.component import MotorsComponent
from components.sim.backends import SimMotorBackend
from components.sim.remote import RemoteWorld
from components.standalone import run_device
from ubf_async.bus import Bus


def add_arguments(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("motors")
    group.add_argument("--name", default="main",
                       help="publishes what it applied on ubf/<robot>/sensor/motors/<name>")
    group.add_argument("--timeout-s", type=float, default=0.2,
                       help="stop the wheels when no drive command arrived for this long")
    group.add_argument("--backend", choices=["sim"], default="sim",
                       help="sim: drive the running simulator's motors over the bus")


def build(bus: Bus, world: RemoteWorld | None, args: argparse.Namespace) -> MotorsComponent:
    assert world is not None
    return MotorsComponent(bus=bus, backend=SimMotorBackend(world), name=args.name,
                           timeout_s=args.timeout_s)


def main() -> int:
    return run_device(prog="python -m components.motors",
                      description="The Mini-WHEGS motor driver (cmd/drive → PWM) as its own "
                                  "process, with the 200 ms command watchdog.",
                      add_arguments=add_arguments, build=build)


if __name__ == "__main__":
    raise SystemExit(main())
