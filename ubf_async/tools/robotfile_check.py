"""``python -m ubf_async.robotfile``: check robot files, print their JSON Schema, list the
plug-ins. The robot files themselves are :mod:`ubf_async.assembly.robotfile`."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from ubf_async import __version__
from ubf_async.assembly import registry
from ubf_async.assembly.robotfile import load_robot, schema_text
from ubf_async.cli.run import run_sync, say_error
from ubf_async.errors import ConfigurationError

__all__ = ["PROG", "list_plugins", "main", "run"]

PROG = "python -m ubf_async.robotfile"


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog=PROG,
        description="Check robot files, print their JSON Schema, list the plug-ins.")
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    check = sub.add_parser("check", help="load robot files as launch would; print the tree")
    check.add_argument("files", nargs="+", metavar="FILE")
    schema = sub.add_parser("schema", help="print the JSON Schema (or write it with --write)")
    schema.add_argument("--write", type=Path, default=None, metavar="FILE")
    sub.add_parser("plugins", help="list the registered behaviours, arbiters, devices …")
    args = parser.parse_args(argv)
    return run_sync(lambda: run(args), prog=PROG)


def run(args: argparse.Namespace) -> int:
    """The command's work; a file that fails its check is this command's finding (status 1,
    the next file still checked), not an error of the command."""
    if args.command == "schema":
        if args.write is None:
            sys.stdout.write(schema_text())
        else:
            args.write.write_text(schema_text(), encoding="utf-8")
        return 0
    if args.command == "plugins":
        list_plugins()
        return 0
    status = 0
    for file in args.files:
        try:
            robot = load_robot(file)
        except ConfigurationError as exc:
            say_error(PROG, exc)
            status = 1
            continue
        print(f"{robot.source}: robot {robot.name!r}, {len(robot.devices)} device(s)"
              + (f" {', '.join(f'{d.kind}/{d.name} ({d.backend})' for d in robot.devices)}"
                 if robot.devices else ""))
        print(robot.root.render_tree())
        for slot in robot.remotes:
            print(f"  remote slot {slot.key} [p={slot.priority} w={slot.weight:g}]")
    return status


def list_plugins() -> None:
    """Every name of every group read, where each comes from; then the entry points under
    ``ubf_async.*`` groups that nothing reads, with the group each was likely meant for."""
    for reg in registry.READ.values():
        print(f"{reg.group}:")
        for name in reg.names():
            print(f"  {name:<20} {reg.origin(name)}")
    for group, points in registry.unread_groups().items():
        meant = registry.meant_group(group)
        print(f"{group}: read by nothing, so left out"
              + (f" (did you mean group {meant}?)" if meant else "")
              + f"; the groups read: {', '.join(registry.READ)}")
        for point in sorted(points, key=lambda p: p.name):
            print(f"  {point.name:<20} {point.value}")


if __name__ == "__main__":
    raise SystemExit(main())
