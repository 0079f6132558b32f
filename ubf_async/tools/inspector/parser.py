"""The inspector's command line: the top-level parser with its examples, and the connection flags
every verb takes, before or after it. Each verb's own arguments are defined by the module
that runs the verb."""

from __future__ import annotations

import argparse

from ubf_async.cli.args import add_connection_arguments
from ubf_async.net.options import DEFAULT_LISTEN
from ubf_async.tools.inspector import common, conform, graph, pub, samples, schemas, state, tree

__all__ = ["PROG", "build_parser", "common_parser"]

PROG = common.PROG


def common_parser(*, suppress: bool = False) -> argparse.ArgumentParser:
    """The connection flags. ``suppress``: defaults left out, for the subcommands, so that
    flags given before the subcommand (parsed by the top level, with the defaults) are not
    overwritten by the subcommand's defaults — the flags work before or after it."""
    common = argparse.ArgumentParser(add_help=False)
    add_connection_arguments(common, default_connect=[DEFAULT_LISTEN])
    for action in common._actions:  # the tool's default mode differs from a component's
        if action.dest == "mode":
            action.default = "client"
            action.help = ("zenoh session mode (default: client — the robot's peer then "
                           "answers for every process attached to it)")
    common.add_argument("--timeout", type=float, default=5.0, metavar="S",
                        help="how long to wait for the robot to answer (default: 5)")
    if suppress:
        for action in common._actions:
            if not isinstance(action, argparse._VersionAction):
                action.default = argparse.SUPPRESS
    return common


def build_parser() -> argparse.ArgumentParser:
    common = common_parser(suppress=True)
    parser = argparse.ArgumentParser(
        prog=PROG, parents=[common_parser()],
        description="Inspect a running ubf_async robot over zenoh: its live components, "
                    "its keys and their rates, decoded samples, and the controller's state "
                    "with the last tick's explanation.",
        epilog=f"examples:\n  {PROG} components --connect tcp/127.0.0.1:7447\n"
               f"  {PROG} keys --seconds 3\n"
               f"  {PROG} echo sensor/range/front --count 5\n"
               f"  {PROG} echo 'cmd/**' --json\n"
               f"  {PROG} state --robot mini\n"
               f"  {PROG} tree show\n"
               f"  {PROG} tree set-arbiter seek_pink_ball MonteCarlo --param hold_ticks=5\n"
               f"  {PROG} tree set-child seek_pink_ball chase --priority 3\n"
               f"  {PROG} tree load my-tree.yaml\n"
               f"  {PROG} hz cmd/drive\n"
               f"  {PROG} bw 'sensor/**'\n"
               f"  {PROG} info sensor/camera/front\n"
               f"  {PROG} pub cmd/leds '{{mask: 1}}'\n"
               f"  {PROG} state --watch\n"
               f"  {PROG} schemas heartbeat range\n"
               f"  {PROG} conform my_ir --key sensor/range/ext\n"
               f"connection flags (--connect, --robot, ...) go before or after COMMAND.\n"
               f"run `{PROG} COMMAND --help` for a command's options.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    graph.add_components_parser(sub, common)
    graph.add_keys_parser(sub, common)
    samples.add_echo_parser(sub, common)
    state.add_state_parser(sub, common)
    graph.add_robots_parser(sub, common)
    tree.add_tree_parser(sub, common)
    samples.add_rate_parsers(sub, common)
    graph.add_info_parser(sub, common)
    pub.add_pub_parser(sub, common)
    schemas.add_schemas_parser(sub)
    conform.add_conform_parser(sub, common)
    return parser
