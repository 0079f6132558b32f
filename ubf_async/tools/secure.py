"""``python -m ubf_async.secure``: generate and show a robot's secure-mode set-up.

The command line over :mod:`ubf_async.net.secure` (the library: identities, the ACL,
:func:`~ubf_async.net.secure.apply`; import those from there). The library lives apart because
reading a robot file (``init``) needs :mod:`ubf_async.assembly.robotfile`, far above the
connection code that applies a set-up.
``docs/security.md`` has the threat model, the set-up and the limits.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from ubf_async.errors import ConfigurationError
from ubf_async.net.secure import SecureSetup, init

__all__ = ["build_parser", "describe", "main"]


# ---------------------------------------------------------------------------------------------
# Command line


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m ubf_async.secure",
        description="Generate and show a robot's secure-mode set-up: per-process zenoh "
                    "credentials and the robot's access control (docs/security.md).")
    sub = parser.add_subparsers(dest="command", required=True)
    make = sub.add_parser("init", help="generate identities and the ACL for a robot file")
    make.add_argument("directory", type=Path, metavar="DIR")
    make.add_argument("--robot-file", required=True, metavar="FILE",
                      help="the robot file (its name, devices and `remote:` slots)")
    make.add_argument("--device", action="append", default=[], metavar="KIND/NAME",
                      help="also an identity for this device, run as its own process "
                           "(repeatable)")
    make.add_argument("--force", action="store_true",
                      help="replace an existing set-up (new passwords for everyone)")
    show = sub.add_parser("show", help="list the identities of a set-up and what each may do")
    show.add_argument("directory", type=Path, metavar="DIR")
    return parser


def describe(setup: SecureSetup) -> str:
    lines = [f"secure set-up for robot {setup.robot!r} ({setup.source}) in {setup.directory}"]
    for identity in setup.identities.values():
        lines.append(f"  {identity.name:<24} {identity.describe()}")
        lines.append(f"  {'':<24} --secure {setup.directory} --identity {identity.name}")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        if args.command == "init":
            from ubf_async.assembly.robotfile import load_robot

            setup = init(args.directory, robot=load_robot(args.robot_file),
                         devices=args.device, force=args.force)
        else:
            setup = SecureSetup.load(args.directory)
    except ConfigurationError as exc:
        print(f"python -m ubf_async.secure: error: {exc}", file=sys.stderr)
        return 2
    print(describe(setup))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
