"""``python -m components.encoders``: the wheel encoders and odometry as their own process."""

from __future__ import annotations

import argparse

from components.encoders.component import EncodersComponent
from components.encoders.quadrature import DirectionMode
from components.sim.backends import SimEncoderBackend
from components.sim.remote import RemoteWorld
from components.standalone import run_device
from ubf_async.bus import Bus


def add_arguments(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("encoders")
    group.add_argument("--name", default="wheels",
                       help="publishes sensor/encoders/<name> and sensor/odometry/<name>")
    group.add_argument("--period-s", type=float, default=0.02, help="time between samples")
    group.add_argument("--direction", choices=["commanded", "phase"], default="commanded",
                       help="commanded: sign from the motors' command (the thesis); "
                            "phase: decoded from the A/B phase order")
    group.add_argument("--backend", choices=["sim"], default="sim",
                       help="sim: read the running simulator's wheel angles over the bus")


def build(bus: Bus, world: RemoteWorld | None, args: argparse.Namespace) -> EncodersComponent:
    assert world is not None
    backend = SimEncoderBackend(world)
    mode = DirectionMode.COMMANDED if args.direction == "commanded" else DirectionMode.PHASE
    return EncodersComponent(bus=bus, backend=backend, name=args.name, period_s=args.period_s,
                             mode=mode, initial_states=backend.current_states())


def main() -> int:
    return run_device(prog="python -m components.encoders",
                      description="Quadrature wheel encoders and odometry as their own process.",
                      add_arguments=add_arguments, build=build)


if __name__ == "__main__":
    raise SystemExit(main())
