"""``python -m components.radio``: the text link as its own process (stdin in, stdout out)."""

from __future__ import annotations

import argparse

from components.standalone import add_backend_argument, run_device


def add_arguments(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("radio")
    group.add_argument("--name", default="link",
                       help="publishes received lines on ubf/<robot>/sensor/radio/<name>")
    add_backend_argument(group, "radio", default="stdio",
                         help="stdio: lines typed on standard input arrive, messages sent are "
                              "printed; sim: an in-memory link (for tests)")


def main() -> int:
    return run_device(kind="radio", prog="python -m components.radio",
                      description="The wireless text link: lines typed on standard input "
                                  "reach the robot's state; messages the behaviours send are "
                                  "printed.",
                      add_arguments=add_arguments)


if __name__ == "__main__":
    raise SystemExit(main())
