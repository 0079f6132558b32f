"""``python -m components.leds``: the LED device as its own process."""

from __future__ import annotations

import argparse
from typing import Any

from components.standalone import add_backend_argument, run_device


def add_arguments(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("leds")
    group.add_argument("--name", default="panel",
                       help="publishes what is lit on ubf/<robot>/sensor/leds/<name>")
    group.add_argument("--count", type=int, help="how many LEDs (1–8; default: the backend's "
                                                 "pins, else 2)")
    add_backend_argument(group, "leds", default="sim",
                         help="sim: LEDs in memory, drawn on the simulator's recorded frames; "
                              "gpio: LEDs on GPIO pins (--backend-params '{pins: [GPIO17, "
                              "GPIO27]}', docs/hardware.md)")


def device_params(args: argparse.Namespace) -> dict[str, Any]:
    return {} if args.count is None else {"count": args.count}


def main() -> int:
    return run_device(kind="leds", prog="python -m components.leds",
                      description="The robot's LEDs (cmd/leds → lit LEDs) as their own process.",
                      add_arguments=add_arguments, device_params=device_params)


if __name__ == "__main__":
    raise SystemExit(main())
