"""``python -m components.range``: one IR range finder as its own process."""

from __future__ import annotations

import argparse
from typing import Any

from components.range.ir import IR_MODELS
from components.standalone import add_backend_argument, run_device


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
    add_backend_argument(group, "range", default="sim",
                         help="sim: measure in the running simulator's world")


def device_params(args: argparse.Namespace) -> dict[str, Any]:
    return {"model": args.model, "x_m": args.x_m, "y_m": args.y_m, "yaw_deg": args.yaw_deg,
            "period_s": args.period_s}


def main() -> int:
    return run_device(kind="range", prog="python -m components.range",
                      description="An IR range finder of the Mini-WHEGS as its own process.",
                      add_arguments=add_arguments, device_params=device_params,
                      seed=lambda args: args.seed)


if __name__ == "__main__":
    raise SystemExit(main())
