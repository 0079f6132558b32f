"""``python -m components.radio``: the text link as its own process (stdin in, stdout out)."""

from __future__ import annotations

import argparse

from components.radio.component import RadioComponent
from components.radio.stdio import StdioRadioBackend
from components.sim.remote import RemoteWorld
from components.standalone import run_device
from ubf_async.bus import Bus


def add_arguments(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("radio")
    group.add_argument("--name", default="link",
                       help="publishes received lines on ubf/<robot>/sensor/radio/<name>")


def build(bus: Bus, world: RemoteWorld | None, args: argparse.Namespace) -> RadioComponent:
    return RadioComponent(bus=bus, backend=StdioRadioBackend(), name=args.name)


def main() -> int:
    return run_device(prog="python -m components.radio",
                      description="The wireless text link: lines typed on standard input "
                                  "reach the robot's state; messages the behaviours send are "
                                  "printed.",
                      add_arguments=add_arguments, build=build,
                      uses_simulator=lambda args: False)


if __name__ == "__main__":
    raise SystemExit(main())
