"""Scripted teleoperation as a remote behaviour that outranks seek-the-pink-ball.

    python examples/teleop_override.py --connect tcp/127.0.0.1:7447 --speed -30 --turn 50
    python examples/teleop_override.py --connect tcp/127.0.0.1:7447 \\
        --script "1.5:40:0, 1:0:80, 1:-30:0" --once

It joins the robot's ``seek_pink_ball`` composite at priority 10 — above search (2) and
chase/flee (1) — so while this process lives its commands win. Kill it (even with ``kill
-9``) and control returns to seek-the-pink-ball: at once when the robot sees its liveliness
token go, at the latest when its last vote's TTL (``--ttl-s``, 0.5 s) runs out.

The protocol it speaks is in docs/protocol.md, section "Remote behaviours".
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from typing import NamedTuple

from ubf_async.core.action import Action
from ubf_async.core.behavior import Behavior
from ubf_async.core.state import State
from ubf_async.tools.remote_host import remote_parser, run_remote_behavior


class Step(NamedTuple):
    duration_s: float
    speed: float
    turn: float


def parse_script(text: str) -> list[Step]:
    """``"DURATION:SPEED:TURN, ..."`` → steps; speed and turn within ±100."""
    steps = []
    for part in text.split(","):
        try:
            duration, speed, turn = (float(x) for x in part.strip().split(":"))
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"bad step {part.strip()!r}: expected DURATION:SPEED:TURN, e.g. 1.5:40:0"
            ) from None
        if not duration > 0 or not (-100 <= speed <= 100 and -100 <= turn <= 100):
            raise argparse.ArgumentTypeError(
                f"bad step {part.strip()!r}: duration > 0, speed and turn within ±100"
            )
        steps.append(Step(duration, speed, turn))
    return steps


class ScriptedTeleop(Behavior):
    """Plays ``steps`` (speed/turn for a duration each) on the robot clock, looping unless
    ``loop`` is false, after which it abstains. The script starts at the first tick."""

    def __init__(self, *, steps: Sequence[Step], loop: bool = True,
                 name: str = "teleop") -> None:
        super().__init__(name=name)
        if not steps:
            raise ValueError("a script needs at least one step")
        self.steps = list(steps)
        self.loop = loop
        self.total_s = sum(s.duration_s for s in self.steps)
        self.start_ns: int | None = None

    def reset(self) -> None:
        self.start_ns = None

    def step_at(self, elapsed_s: float) -> Step | None:
        if elapsed_s >= self.total_s:
            if not self.loop:
                return None
            elapsed_s %= self.total_s
        for step in self.steps:
            if elapsed_s < step.duration_s:
                return step
            elapsed_s -= step.duration_s
        return self.steps[-1]

    def act(self, state: State) -> Action | None:
        if self.start_ns is None:
            self.start_ns = state.now_ns
        step = self.step_at((state.now_ns - self.start_ns) / 1e9)
        if step is None:
            return None
        return Action(speed=step.speed, turn=step.turn)


def build_parser() -> argparse.ArgumentParser:
    parser = remote_parser(
        prog="python examples/teleop_override.py",
        description=__doc__.split("\n\n")[0]
        + " Without --script it drives a constant --speed/--turn.",
        name="teleop", composite="seek_pink_ball", priority=10,
    )
    teleop = parser.add_argument_group("teleoperation")
    teleop.add_argument("--speed", type=float, default=0.0, help="constant speed, ±100")
    teleop.add_argument("--turn", type=float, default=0.0, help="constant turn, ±100 (+ left)")
    teleop.add_argument("--script", type=parse_script, default=None,
                        metavar="D:S:T[,D:S:T...]",
                        help="steps of DURATION s at SPEED and TURN, played in a loop")
    teleop.add_argument("--once", action="store_true",
                        help="play the script once, then abstain (seek-the-pink-ball "
                             "takes over while this process still runs)")
    return parser


def make_behavior(args: argparse.Namespace) -> Behavior:
    steps = args.script or [Step(1.0, args.speed, args.turn)]
    return ScriptedTeleop(steps=steps, loop=not args.once, name=args.name)


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not (-100 <= args.speed <= 100 and -100 <= args.turn <= 100):
        parser.error("--speed and --turn must be within ±100")
    return run_remote_behavior(make_behavior, args)


if __name__ == "__main__":
    sys.exit(main())
