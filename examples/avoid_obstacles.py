"""IR obstacle avoidance as a remote behaviour, in its own process.

    python examples/avoid_obstacles.py --connect tcp/127.0.0.1:7447

It reads the robot's IR range finders (every ``range/*`` source of the state, or the
``--source`` ones) from the same samples the robot sees. When something is within
``--near-mm`` (250 mm) it backs away and turns — away from the side of the sensor when its
name says ``left`` or ``right``, else to the left — with a vote that grows as the obstacle
gets nearer; otherwise it abstains. It joins the robot's ``seek_pink_ball`` composite at
priority 3, above search (2) and chase/flee (1), so it interrupts seeking only while an
obstacle is near.

The protocol it speaks is in docs/protocol.md, section "Remote behaviours".
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from ubf_async.action import Action
from ubf_async.behavior import Behavior
from ubf_async.remote import remote_parser, run_remote_behavior
from ubf_async.state import State


class AvoidObstacles(Behavior):
    """Back away from the nearest obstacle closer than ``near_mm``; abstain otherwise.

    A reading counts when it is fresh and either ``status == "ok"`` with ``range_mm ≤
    near_mm``, or ``status == "too_close"`` (nearer than the sensor can measure: 0 mm).
    ``too_far`` and stale readings never trigger it.
    """

    def __init__(
        self,
        *,
        name: str = "avoid_obstacles",
        sources: Sequence[str] = (),
        near_mm: int = 250,
        speed: float = -30.0,
        turn: float = 60.0,
    ) -> None:
        super().__init__(name=name)
        if near_mm <= 0:
            raise ValueError(f"near_mm must be > 0, got {near_mm}")
        self.sources = list(sources)
        self.near_mm = near_mm
        self.speed = speed
        self.turn = turn

    def nearest(self, state: State) -> tuple[str, int] | None:
        """``(source, mm)`` of the nearest obstacle within ``near_mm``, if any."""
        best: tuple[str, int] | None = None
        sources = self.sources or [s for s in state if s.startswith("range/")]
        for source in sources:
            reading = state.fresh(source)
            if reading is None:
                continue
            status = reading.value.get("status")
            mm = reading.value.get("range_mm")
            if status == "too_close":
                mm = 0
            elif status != "ok" or mm is None:
                continue
            if mm <= self.near_mm and (best is None or mm < best[1]):
                best = (source, mm)
        return best

    def act(self, state: State) -> Action | None:
        found = self.nearest(state)
        if found is None:
            return None
        source, mm = found
        side = source.partition("/")[2]
        turn = -self.turn if "left" in side else self.turn  # obstacle on the left: go right
        closeness = 1.0 - mm / self.near_mm
        return Action(speed=self.speed, turn=turn, vote=1.0 + closeness)


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
    return parser


def make_behavior(args: argparse.Namespace) -> Behavior:
    return AvoidObstacles(name=args.name, sources=args.source, near_mm=args.near_mm,
                          speed=args.back_speed, turn=args.avoid_turn)


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.near_mm <= 0:
        parser.error("--near-mm must be > 0")
    if not (-100 <= args.back_speed <= 100 and 0 <= args.avoid_turn <= 100):
        parser.error("--back-speed must be within ±100 and --avoid-turn within 0..100")
    return run_remote_behavior(make_behavior, args)


if __name__ == "__main__":
    sys.exit(main())
