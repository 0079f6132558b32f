"""``tree show | set-arbiter | set-child | load``: the running behaviour tree, and live changes
to it through the robot's tree service (``ubf/<robot>/tree``, docs/protocol.md, "Live tree
changes")."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any, TextIO

import yaml

from ubf_async.errors import ProtocolError, QueryError
from ubf_async.runtime.bus import Bus
from ubf_async.services.live import encode_request, render_tree_data
from ubf_async.services.live import request as tree_request
from ubf_async.tools.inspector import common, state

__all__ = ["add_tree_parser", "cmd_tree", "param", "tree_request_data"]


def param(text: str) -> tuple[str, Any]:
    """``--param KEY=VALUE``: VALUE is read as YAML (``3`` an int, ``true`` a bool, ``[1, 2]``
    a list, anything else a string)."""
    key, sep, value = text.partition("=")
    key = key.strip()
    if not sep or not key:
        raise argparse.ArgumentTypeError(f"{text!r}: expected KEY=VALUE, e.g. hold_ticks=5")
    try:
        return key, yaml.safe_load(value) if value.strip() else ""
    except yaml.YAMLError as exc:
        raise argparse.ArgumentTypeError(f"{text!r}: VALUE is not valid YAML: {exc}") from None


def add_tree_parser(sub: Any, connection: argparse.ArgumentParser) -> None:
    tree = sub.add_parser(
        "tree", parents=[connection], help="show the running behaviour tree, or change it live",
        description="Show the robot's running behaviour tree or change it while it runs, "
                    "through its tree service (ubf/<robot>/tree; docs/protocol.md, 'Live tree "
                    "changes'). A change applies between two ticks, after the robot has "
                    "validated it; a refused change leaves the tree as it was. Without a "
                    "verb: show. Exit status: 0 done, 1 refused by the robot, 2 no robot "
                    "answered.",
    )
    # `tree` alone shows the tree; the usage lists the verbs (no metavar hides them).
    verbs = tree.add_subparsers(dest="tree_command", title="verbs")
    tree.set_defaults(tree_command="show", json=False)
    show = verbs.add_parser("show", parents=[connection], help="print the running tree",
                            description="Print the running tree: composites with their "
                                        "arbiter, children with [p=priority w=weight].")
    arbiter = verbs.add_parser(
        "set-arbiter", parents=[connection], help="swap a composite's arbiter",
        description="Give COMPOSITE a new arbiter, e.g. HighestPriority, or MonteCarlo with "
                    "--param hold_ticks=5. The robot builds it and checks it against the "
                    "composite's children first.")
    arbiter.add_argument("composite", metavar="COMPOSITE")
    arbiter.add_argument("arbiter", metavar="ARBITER",
                         help="a registered arbiter name or a 'module:factory' reference")
    arbiter.add_argument("--param", "-p", type=param, action="append", default=[],
                         metavar="KEY=VALUE",
                         help="a parameter of the arbiter (repeatable; VALUE is read as YAML)")
    child = verbs.add_parser(
        "set-child", parents=[connection], help="change a child's priority and/or weight",
        description="Change the priority and/or weight of CHILD in COMPOSITE.")
    child.add_argument("composite", metavar="COMPOSITE")
    child.add_argument("child", metavar="CHILD")
    child.add_argument("--priority", type=int, default=None, metavar="N")
    child.add_argument("--weight", type=float, default=None, metavar="W")
    load = verbs.add_parser(
        "load", parents=[connection], help="replace the whole tree from a robot-file fragment",
        description="Replace the running tree with the one FRAGMENT describes: a robot file's "
                    "`tree:` node (docs/robot-file.md), alone or as `tree: ...`. Every "
                    "behaviour, arbiter and parameter is checked before the new tree takes "
                    "over.")
    load.add_argument("fragment", type=Path, metavar="FRAGMENT.yaml")
    for verb in (show, arbiter, child, load):
        verb.add_argument("--json", action="store_true", help="print the reply as JSON")
    state.add_watch_arguments(show)


def tree_request_data(args: argparse.Namespace) -> dict[str, Any]:
    """The ``tree.request`` data a ``tree`` verb sends (ValueError for unusable input)."""
    verb = args.tree_command
    if verb == "show":
        return {"op": "show"}
    if verb == "set-arbiter":
        params = dict(args.param)
        return {"op": "set_arbiter", "composite": args.composite,
                "arbiter": {"type": args.arbiter, "params": params} if params else args.arbiter}
    if verb == "set-child":
        if args.priority is None and args.weight is None:
            raise ValueError("set-child: give --priority and/or --weight")
        data: dict[str, Any] = {"op": "set_child", "composite": args.composite,
                                "child": args.child}
        if args.priority is not None:
            data["priority"] = args.priority
        if args.weight is not None:
            data["weight"] = args.weight
        return data
    try:
        fragment = args.fragment.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(f"{args.fragment}: cannot read it: {exc}") from None
    # Long fragments travel as UTF-8 bytes: protocol strings are at most 4096 characters.
    return {"op": "load", "tree": fragment if len(fragment) <= 4096 else fragment.encode()}


async def cmd_tree(bus: Bus, args: argparse.Namespace, out: TextIO) -> int:
    try:
        data = tree_request_data(args)
        encode_request(data, stamp_ns=0)  # refuse what the robot would refuse, before sending
    except ValueError as exc:  # ProtocolError is a ValueError
        common.say_error(exc)
        return 2
    if getattr(args, "watch", False):
        async def block() -> str | None:
            code, text = await _tree_once(bus, args, data)
            if code:
                common.say_error(text)
                return None
            return text

        return 2 if await state.watch(block, args, out) else 0
    code, text = await _tree_once(bus, args, data)
    if code:
        common.say_error(text)
    else:
        print(text, file=out)
    return code


async def _tree_once(bus: Bus, args: argparse.Namespace, data: dict[str, Any]
                     ) -> tuple[int, str]:
    """One tree request: the exit status and what to print."""
    try:
        reply = await tree_request(bus, data, timeout_s=args.timeout)
    except TimeoutError:
        return 2, (f"no robot {bus.robot!r} answered on ubf/{bus.robot}/tree within "
                   f"{args.timeout:g}s: is it running, with its tree service (--robot, "
                   f"--connect)?")
    except (QueryError, ProtocolError) as exc:
        return 2, f"robot {bus.robot!r} gave no usable reply: {exc}"
    if not reply["ok"]:
        return 1, (f"robot {bus.robot!r} refused {args.tree_command}: "
                   f"{reply['error']} (tree unchanged, version {reply.get('version', '?')})")
    if args.json:
        return 0, common.to_json(reply)
    version = reply.get("version", "?")
    lines = [f"robot {bus.robot!r}: tree version {version}" if args.tree_command == "show"
             else f"robot {bus.robot!r}: {args.tree_command} applied, tree version {version}",
             render_tree_data(reply["tree"])]
    lines.extend(f"remote slot {slot['composite']}/{slot['name']} [p={slot['priority']} "
                 f"w={slot['weight']:g}]" for slot in reply.get("slots") or ())
    return 0, "\n".join(lines)
