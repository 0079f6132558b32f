"""``python -m ubf_async.secure``: generate and show a robot's secure-mode set-up.

The command line over :mod:`ubf_async.access.setup` (the policy: a robot file's identities and
what each may do; ``init``, ``revoke``) and :mod:`ubf_async.net.secure` (the mechanism: the
set-up's files, ``rotate``, ``export``, :func:`~ubf_async.net.secure.apply`); import those from
there. The library lives apart because reading a robot file (``init``) needs
:mod:`ubf_async.assembly.robotfile`, far above the connection code that applies a set-up.
``docs/security.md`` has the threat model, the set-up and the limits.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

from ubf_async.access import policy
from ubf_async.access.setup import init, init_fleet, revoke
from ubf_async.cli.run import run_sync
from ubf_async.errors import ConfigurationError
from ubf_async.net import pki
from ubf_async.net.secure import LISTENERS, SecureSetup, export, override, rotate

__all__ = ["build_parser", "describe", "main"]


# ---------------------------------------------------------------------------------------------
# Command line


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m ubf_async.secure",
        description="Generate and manage a robot's secure-mode set-up: a certificate "
                    "authority, one certificate and password per process (identity), and the "
                    "robot's access control (docs/security.md).")
    sub = parser.add_subparsers(dest="command", required=True)
    make = sub.add_parser("init", help="generate the CA, identities and the ACL for a robot "
                                       "file")
    make.add_argument("directory", type=Path, metavar="DIR")
    which = make.add_mutually_exclusive_group(required=True)
    which.add_argument("--robot-file", metavar="FILE",
                       help="the robot file (its name, devices and `remote:` slots)")
    which.add_argument("--fleet-file", metavar="FLEET.yaml",
                       help="a fleet file instead (docs/fleet.md): identities for its router, "
                            "world, launcher and each robot; the router holds the ACL")
    make.add_argument("--host", action="append", default=[], metavar="NAME_OR_IP",
                      help="a name or address clients dial the robot (a fleet's router) at: "
                           "its certificate carries it, and a client checks it (repeatable; "
                           "default: localhost and 127.0.0.1)")
    make.add_argument("--device", action="append", default=[], metavar="KIND/NAME",
                      help="also an identity for this device, run as its own process "
                           "(repeatable)")
    make.add_argument("--days", type=int, default=pki.IDENTITY_DAYS,
                      help="how long the identities' certificates are valid")
    make.add_argument("--force", action="store_true",
                      help="replace an existing set-up (a new CA: every host needs its new "
                           "export)")
    show = sub.add_parser("show", help="list the identities of a set-up and what each may do")
    show.add_argument("directory", type=Path, metavar="DIR")
    pack = sub.add_parser("export", help="pack what one host needs to run some identities "
                                         "(never the CA's key)")
    pack.add_argument("directory", type=Path, metavar="DIR")
    pack.add_argument("identity", nargs="+", metavar="IDENTITY")
    pack.add_argument("--output", "-o", type=Path, default=None, metavar="FILE.tar.gz",
                      help="where to write it (default: IDENTITY.tar.gz here)")
    again = sub.add_parser("rotate", help="issue one identity a new key, certificate and "
                                          "password; the others are untouched")
    again.add_argument("directory", type=Path, metavar="DIR")
    again.add_argument("identity", metavar="IDENTITY")
    again.add_argument("--host", action="append", default=[], metavar="NAME_OR_IP",
                       help=f"for {', '.join(LISTENERS)}: the names its new certificate "
                            "carries (repeatable; default: those it has)")
    again.add_argument("--days", type=int, default=pki.IDENTITY_DAYS,
                       help="how long the new certificate is valid")
    drop = sub.add_parser("revoke", help="remove an identity: from the ACL, the password "
                                         "dictionary and the set-up")
    drop.add_argument("directory", type=Path, metavar="DIR")
    drop.add_argument("identity", metavar="IDENTITY")
    ros = sub.add_parser("zenoh-override",
                         help="print the ZENOH_CONFIG_OVERRIDE that joins another zenoh node "
                              "(a ROS 2 node on rmw_zenoh) to the robot as IDENTITY")
    ros.add_argument("directory", type=Path, metavar="DIR")
    ros.add_argument("identity", metavar="IDENTITY")
    ros.add_argument("--connect", "-e", action="append", required=True, metavar="ENDPOINT",
                     help="the robot's tls/ endpoint (repeatable)")
    return parser


def describe(setup: SecureSetup) -> str:
    what = (f"fleet {setup.robot!r} of {', '.join(setup.fleet)}" if setup.fleet
            else f"robot {setup.robot!r}")
    listener = "the router's" if setup.fleet else "the robot's"
    lines = [f"secure set-up for {what} ({setup.source}) in {setup.directory}",
             f"  {listener} certificate carries: {', '.join(setup.hosts)} (clients dial "
             f"tls/<one of these>:PORT)"]
    for identity in setup.identities.values():
        lines.append(f"  {identity.name:<24} {policy.describe(identity)}")
        lines.append(f"  {'':<24} --secure {setup.directory} --identity {identity.name}")
    if setup.revoked:
        lines.append(f"  revoked: {', '.join(setup.revoked)}")
    return "\n".join(lines)


RESTART = ("a robot running on this set-up re-opens its session within 2 s and the old files "
           "are refused from then on (docs/security.md, 'Revoking and rotating while the robot "
           "runs'); a robot elsewhere needs the set-up's new `secure export DIR robot`")


def run(args: argparse.Namespace) -> str:
    """Do ``args.command``; what to print. Raises :class:`ConfigurationError`."""
    if args.command == "init" and args.fleet_file:
        from ubf_async.runs.fleet import load_fleet

        fleet = load_fleet(Path(args.fleet_file))
        if args.device:
            raise ConfigurationError("--device: a fleet's set-up has no device identities")
        return describe(init_fleet(args.directory, name=Path(args.fleet_file).stem,
                                   robots=[r.name for r in fleet.spec.robots],
                                   source=str(fleet.source), hosts=args.host,
                                   force=args.force, days=args.days))
    if args.command == "init":
        from ubf_async.assembly.robotfile import load_robot

        return describe(init(args.directory, robot=load_robot(args.robot_file),
                             devices=args.device, hosts=args.host, force=args.force,
                             days=args.days))
    if args.command == "show":
        return describe(SecureSetup.load(args.directory))
    if args.command == "export":
        output = args.output or Path(f"{'+'.join(args.identity)}.tar.gz")
        members = export(args.directory, args.identity, output)
        return (f"wrote {output} ({len(members)} files: {', '.join(members)}); on the host "
                f"that runs {', '.join(args.identity)}: mkdir -m 700 DIR && tar xzf {output.name}"
                f" -C DIR, then --secure DIR --identity {args.identity[0]}")
    if args.command == "rotate":
        setup = rotate(args.directory, args.identity, hosts=args.host, days=args.days)
        return (f"rotated {args.identity!r}: a new key, certificate and password; bring its "
                f"host `python -m ubf_async.secure export {setup.directory} {args.identity}`"
                f" and {RESTART}")
    if args.command == "zenoh-override":
        return override(args.directory, args.identity, connect=args.connect)
    revoke(args.directory, args.identity)
    return f"revoked {args.identity!r}: its files are gone; {RESTART}"


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)

    def said() -> int:
        print(run(args))
        return 0

    return run_sync(said, prog="python -m ubf_async.secure")


if __name__ == "__main__":
    raise SystemExit(main())
