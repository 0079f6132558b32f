"""``python -m components.motors``: the motor driver as its own process."""

from __future__ import annotations

import argparse
import sys
from typing import Any

from components.motors.component import DEFAULT_TIMEOUT_S
from components.standalone import add_backend_argument, run_device


def add_arguments(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("motors")
    group.add_argument("--name", default="main",
                       help="publishes what it applied on ubf/<robot>/sensor/motors/<name>")
    group.add_argument("--timeout-s", type=float, default=DEFAULT_TIMEOUT_S,
                       help="stop the wheels when no drive command arrived for this long")
    add_backend_argument(group, "motors", default="sim",
                         help="sim: drive the running simulator's motors over the bus; gpio: "
                              "real PWM pins (--backend-params '{left_pin: GPIO12, right_pin: "
                              "GPIO13}'). Check a real robot's wiring with --check "
                              "--robot-file FILE")
    # Only for --help: main() hands a command line with --check to the check before parsing.
    check = parser.add_argument_group("wiring check (instead of running the driver)")
    check.add_argument("--check", action="store_true",
                       help="spin each wheel of a real robot briefly, one at a time, and report "
                            "the encoder counts it produced, to verify the wiring: --check "
                            "--robot-file FILE (lift the robot first; --check --help lists "
                            "the check's options)")


def device_params(args: argparse.Namespace) -> dict[str, Any]:
    return {"timeout_s": args.timeout_s}


def main() -> int:
    if "--check" in sys.argv[1:]:  # the wiring check drives the pins directly: no bus
        from components.motors.check import main as check

        return check(sys.argv[1:])
    return run_device(kind="motors", prog="python -m components.motors",
                      description="The Mini-WHEGS motor driver (cmd/drive → PWM) as its own "
                                  "process, with the command watchdog.",
                      add_arguments=add_arguments, device_params=device_params)


if __name__ == "__main__":
    raise SystemExit(main())
