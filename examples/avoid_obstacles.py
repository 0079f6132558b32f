"""IR obstacle avoidance as a remote behaviour, in its own process.

    python examples/avoid_obstacles.py --connect tcp/127.0.0.1:7447

It reads the robot's IR range finders (every ``range/*`` source of the state, or the
``--source`` ones) from the same samples the robot sees. When something is within
``--near-mm`` (250 mm) it backs away and turns — away from the side of the sensor when its
name says ``left`` or ``right``, else to the left — with a vote that grows as the obstacle
gets nearer, and keeps doing so for ``--hold-s`` (1.5 s) after the last such reading, so the
robot's body, not just the thin IR beam, turns clear of the obstacle's edge; otherwise it
abstains. It joins the robot's ``seek_pink_ball`` composite at priority 3, above search (2)
and chase/flee (1), so it interrupts seeking only while an obstacle is near. In the built-in
``obstacle-course`` scenario it is what gets the robot round the box
(``python -m ubf_async.launch --scenario obstacle-course``, then this).

The behaviour itself is the built-in ``avoid`` (ubf_async/behaviors/obstacles.py), which a
robot file can also run inside the robot; this example runs it in a process of its own. The
protocol it speaks is in docs/protocol.md, section "Remote behaviours".
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from typing import Any

from ubf_async.behaviors.obstacles import DEFAULT_HOLD_S, Avoid
from ubf_async.core.behavior import Behavior
from ubf_async.tools.remote_host import remote_parser, run_remote_behavior


class AvoidObstacles(Avoid):
    """The built-in ``avoid`` behaviour (:class:`ubf_async.behaviors.obstacles.Avoid`) under
    the name this example has always used, ``avoid_obstacles``."""

    def __init__(self, *, name: str = "avoid_obstacles", **params: Any) -> None:
        super().__init__(name=name, **params)


def build_parser() -> argparse.ArgumentParser:
    parser = remote_parser(
        prog="python examples/avoid_obstacles.py",
        description=__doc__.split("\n\n")[0],
        name="avoid_obstacles", composite="seek_pink_ball", priority=3, rate_hz=25.0,
    )
    avoid = parser.add_argument_group("obstacle avoidance")
    avoid.add_argument("--source", action="append", default=[], metavar="SOURCE",
                       help="range source to watch, e.g. range/front (repeatable; default: "
                            "every range/* source)")
    avoid.add_argument("--near-mm", type=int, default=250,
                       help="react to obstacles at or within this distance")
    avoid.add_argument("--back-speed", type=float, default=-30.0,
                       help="speed while avoiding (negative: back away)")
    avoid.add_argument("--avoid-turn", type=float, default=60.0,
                       help="turn while avoiding (sign chosen from the sensor's side)")
    avoid.add_argument("--hold-s", type=float, default=DEFAULT_HOLD_S,
                       help="keep backing and turning this long after the last near reading "
                            "(0: let go at once)")
    return parser


def make_behavior(args: argparse.Namespace) -> Behavior:
    return AvoidObstacles(name=args.name, sources=args.source, near_mm=args.near_mm,
                          speed=args.back_speed, turn=args.avoid_turn, hold_s=args.hold_s)


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.near_mm <= 0:
        parser.error("--near-mm must be > 0")
    if not (-100 <= args.back_speed <= 100 and 0 <= args.avoid_turn <= 100):
        parser.error("--back-speed must be within ±100 and --avoid-turn within 0..100")
    if not 0 <= args.hold_s <= 60:
        parser.error("--hold-s must be within 0..60")
    return run_remote_behavior(make_behavior, args)


if __name__ == "__main__":
    sys.exit(main())
