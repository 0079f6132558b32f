"""``python -m components.range``: one IR range finder as its own process."""

from __future__ import annotations

import argparse
import math

from components.range.backend import MountPose
from components.range.component import RangeComponent
from components.range.ir import IR_MODELS
from components.sim.backends import SimRangeBackend
from components.sim.remote import RemoteWorld
from components.standalone import run_device
from ubf_async.bus import Bus


def add_arguments(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("IR range finder")
    group.add_argument("--name", default="front",
                       help="sensor name: publishes ubf/<robot>/sensor/range/<name>")
    group.add_argument("--model", choices=sorted(IR_MODELS), default="ir-10-80",
                       help="thesis model by range in cm")
    group.add_argument("--x-m", type=float, default=0.05, help="mount: ahead of robot centre")
    group.add_argument("--y-m", type=float, default=0.0, help="mount: left of robot centre")
    group.add_argument("--yaw-deg", type=float, default=0.0,
                       help="mount: beam direction, + to the left of straight ahead")
    group.add_argument("--period-s", type=float, default=0.04, help="time between readings")
    group.add_argument("--seed", type=int, default=0, help="seed of the 5–10 %% error")
    group.add_argument("--backend", choices=["sim"], default="sim",
                       help="sim: measure in the running simulator's world")


def build(bus: Bus, world: RemoteWorld | None, args: argparse.Namespace) -> RangeComponent:
    assert world is not None
    mount = MountPose(x_m=args.x_m, y_m=args.y_m, yaw_rad=math.radians(args.yaw_deg))
    return RangeComponent(bus=bus, backend=SimRangeBackend(world), name=args.name,
                          model=IR_MODELS[args.model], mount=mount, period_s=args.period_s,
                          seed=args.seed)


def main() -> int:
    return run_device(prog="python -m components.range",
                      description="An IR range finder of the Mini-WHEGS as its own process.",
                      add_arguments=add_arguments, build=build)


if __name__ == "__main__":
    raise SystemExit(main())
