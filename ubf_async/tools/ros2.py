"""``python -m ubf_async.ros2``: the ROS 2 bridge as a process of its own (docs/ros2.md).

    python -m ubf_async.ros2 --connect tcp/127.0.0.1:7447 --distro jazzy --domain-id 0
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import os
import sys
from collections.abc import Sequence

from ubf_async.cli import attach
from ubf_async.cli.args import HelpFormatter, add_connection_arguments, connection_options
from ubf_async.cli.attach import wait_for_robot
from ubf_async.cli.run import run_main
from ubf_async.clocks import follow
from ubf_async.net.options import DEFAULT_LISTEN
from ubf_async.net.secure import ROS2_BRIDGE
from ubf_async.runtime.bus import Bus
from ubf_async.runtime.component import ensure_name_free
from ubf_async.services.ros2 import messages as rm
from ubf_async.services.ros2.bridge import DEFAULT_UNITS, Ros2Bridge, Ros2Settings

__all__ = ["PROG", "build_parser", "default_domain_id", "main", "report", "serve", "settings_of",
           "status_line", "totals"]

PROG = "python -m ubf_async.ros2"


def default_domain_id() -> int:
    text = os.environ.get("ROS_DOMAIN_ID", "").strip()
    return int(text) if text.isdigit() else 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=PROG, formatter_class=HelpFormatter,
        description="The robot as a ROS 2 node over rmw_zenoh's wire format, with no ROS "
                    "installation: its drive command, odometry, range finders, camera, "
                    "trace and clock as ROS topics, and Twist on cmd_vel_in as a remote vote "
                    "(docs/ros2.md).")
    add_connection_arguments(parser, default_connect=[DEFAULT_LISTEN],
                             default_identity=ROS2_BRIDGE)
    attach.add_attach_arguments(parser, name="ros2", who="the bridge")
    ros = parser.add_argument_group("ROS 2")
    ros.add_argument("--domain-id", type=int, default=default_domain_id(),
                     help="ROS domain id (default: $ROS_DOMAIN_ID, else 0)")
    ros.add_argument("--distro", choices=rm.DISTROS, default=rm.DEFAULT_DISTRO,
                     help="the ROS 2 distro of the other side: message layouts and type "
                          "hashes (Humble: TypeHashNotSupported)")
    ros.add_argument("--namespace", default=None,
                     help="the node's namespace and its topics' (default: /<robot>)")
    ros.add_argument("--node", default="ubf_bridge", help="the ROS node name")
    ros.add_argument("--cmd-vel-in", default="cmd_vel_in",
                     help="the topic whose Twists drive the robot")
    ros.add_argument("--slot", default="teleop",
                     help="the remote behaviour the Twists vote as (a `remote:` slot)")
    ros.add_argument("--composite", default="seek_pink_ball",
                     help="the composite of the tree holding the slot")
    ros.add_argument("--ttl-s", type=float, default=0.5,
                     help="how long one Twist holds on the robot")
    ros.add_argument("--max-linear-m-s", type=float, default=DEFAULT_UNITS.max_linear_m_s,
                     help="m/s of speed +100 (the robot file's ros2: calibration)")
    ros.add_argument("--max-angular-rad-s", type=float,
                     default=DEFAULT_UNITS.max_angular_rad_s,
                     help="rad/s of turn +100 (to the left)")
    parser.add_argument("--status-period-s", type=float, default=5.0, metavar="S",
                        help="print what was sent and refused every S seconds (0: never)")
    parser.add_argument("--log-level", default="WARNING",
                        choices=["DEBUG", "INFO", "WARNING", "ERROR"])
    return parser


def settings_of(args: argparse.Namespace) -> Ros2Settings:
    return Ros2Settings(
        domain_id=args.domain_id, distro=args.distro, namespace=args.namespace,
        node=args.node, cmd_vel_in=args.cmd_vel_in, slot=args.slot, composite=args.composite,
        ttl_s=args.ttl_s, units=rm.Units(args.max_linear_m_s, args.max_angular_rad_s))


async def serve(args: argparse.Namespace, settings: Ros2Settings) -> int:
    bus = await Bus.open(connection_options(args))
    try:
        await wait_for_robot(bus, timeout_s=args.wait_for_robot_s)
        clock = await follow.follow_robot_clock(bus, mode="auto")
        await ensure_name_free(bus, args.name, hint="start it with another --name")
        bridge = Ros2Bridge(bus=bus, settings=settings, name=args.name)
        await bridge.start()
        try:
            print(f"ROS 2 bridge of robot {bus.robot!r}: node "
                  f"{bridge.namespace.rstrip('/')}/{settings.node}, domain "
                  f"{settings.domain_id}, {settings.distro}; clock: "
                  f"{follow.describe(clock, robot=bus.robot)}", flush=True)
            status = asyncio.create_task(report(bridge, args.status_period_s))
            try:
                await attach.run_until_stopped(args.duration)
            finally:
                status.cancel()
        finally:
            done = totals(bridge)  # before closing: its ROS publishers close with it
            await bridge.aclose()
            # The closing line every tool prints (record, liveview, replay): what it did.
            print(f"{PROG}: stopped; {done}", flush=True)
        return 0
    finally:
        await bus.aclose()


def totals(bridge: Ros2Bridge) -> str:
    """What the bridge sent and took in so far, and what it refused (per reason)."""
    sent = ", ".join(f"{p.topic} {p.sent}" for p in bridge.ros_publishers() if p.sent)
    refused = ", ".join(f"{reason} {n}" for reason, n in sorted(bridge.inbound.refused.items()))
    return (f"sent: {sent or 'nothing yet'} | {bridge.settings.cmd_vel_in}: "
            f"{bridge.inbound.accepted} taken, refused: {refused or 'none'}")


def status_line(bridge: Ros2Bridge) -> str:
    """The periodic status line: :func:`totals` so far."""
    return f"[ros2] {totals(bridge)}"


async def report(bridge: Ros2Bridge, period_s: float) -> None:
    while period_s > 0:
        await asyncio.sleep(period_s)
        print(status_line(bridge), flush=True)


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        settings = settings_of(args)
    except ValueError as exc:
        parser.error(str(exc))
    logging.basicConfig(level=args.log_level,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    return run_main(lambda: serve(args, settings), prog=PROG)


if __name__ == "__main__":
    sys.exit(main())
