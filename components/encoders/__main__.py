"""``python -m components.encoders``: the wheel encoders and odometry as their own process."""

from __future__ import annotations

import argparse
from typing import Any

from components.standalone import add_backend_argument, run_device


def add_arguments(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("encoders")
    group.add_argument("--name", default="wheels",
                       help="publishes sensor/encoders/<name> and sensor/odometry/<name>")
    group.add_argument("--period-s", type=float, default=0.02, help="time between samples")
    group.add_argument("--direction", choices=["commanded", "phase"], default="commanded",
                       help="commanded: sign from the motors' command (the thesis); "
                            "phase: decoded from the A/B phase order")
    add_backend_argument(group, "encoders", default="sim",
                         help="sim: read the running simulator's wheel angles over the bus")


def device_params(args: argparse.Namespace) -> dict[str, Any]:
    return {"period_s": args.period_s, "direction": args.direction}


def main() -> int:
    return run_device(kind="encoders", prog="python -m components.encoders",
                      description="Quadrature wheel encoders and odometry as their own process.",
                      add_arguments=add_arguments, device_params=device_params)


if __name__ == "__main__":
    raise SystemExit(main())
