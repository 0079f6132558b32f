"""``python -m ubf_async.deploy``: a systemd unit that starts a robot at boot (docs/deploy.md).

The unit runs ``python -m ubf_async.launch ROBOT_FILE`` with this very interpreter (the venv
the robot was installed in), as a normal user in the groups its devices' backends need (GPIO,
I²C, video), listening where the laptop will dial it, in secure mode when given the set-up;
it restarts on failure (not after a clean stop), ends with SIGTERM (launch's clean end:
motors stopped, files saved) and logs to journald under its own name. The robot file is loaded
first: a unit is never written for a file that does not load.
"""

from __future__ import annotations

import argparse
import getpass
import re
import sys
from collections.abc import Sequence
from pathlib import Path

from ubf_async.assembly.robotfile import Robot, load_robot
from ubf_async.cli.run import run_sync
from ubf_async.errors import ConfigurationError

__all__ = ["BACKEND_GROUPS", "PROG", "build_parser", "main", "systemd_quote", "systemd_text",
           "unit_text"]

PROG = "python -m ubf_async.deploy"

BACKEND_GROUPS: dict[str, tuple[str, ...]] = {
    "gpio": ("gpio",),
    "i2c": ("i2c",),
    "ads1115": ("i2c",),
    "video": ("video",),
}
"""The groups (as Raspberry Pi OS names them) that let a normal user open the device files a
backend uses: ``/dev/gpiochip*``, ``/dev/i2c-*``, ``/dev/video*`` (docs/hardware.md,
Permissions). A backend of your own adds its groups with ``--group``."""

_SAFE = re.compile(r"[A-Za-z0-9_@%+=:,./-]+")


def systemd_quote(argument: str) -> str:
    """One argument of ``ExecStart=`` as systemd reads it: ``%`` doubled (a specifier
    otherwise), quoted when it holds anything but plain characters."""
    text = argument.replace("%", "%%")
    if _SAFE.fullmatch(text):
        return text
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"') + '"'


def systemd_text(value: str) -> str:
    """A whole value of a setting that takes the rest of its line (``Description=``,
    ``WorkingDirectory=``): its ``%`` doubled, nothing quoted."""
    return value.replace("%", "%%")


def _groups(robot: Robot, extra: Sequence[str]) -> list[str]:
    found = [group for device in robot.devices
             for group in BACKEND_GROUPS.get(device.backend, ())]
    return sorted(set(found) | set(extra))


def unit_text(robot: Robot, robot_file: Path, *, user: str, python: Path, listen: str,
              secure: Path | None, identity: str, groups: Sequence[str] = ()) -> str:
    """The unit's text for ``robot`` (loaded from ``robot_file``, an absolute path)."""
    # A status line a minute in the journal, not two a second.
    command = [str(python), "-m", "ubf_async.launch", str(robot_file), "--listen", listen,
               "--status-period-s", "60"]
    if secure is not None:
        command += ["--secure", str(secure), "--identity", identity]
    needed = _groups(robot, groups)
    name = f"ubf-robot-{robot.name}"
    lines = [
        "# Written by python -m ubf_async.deploy (docs/deploy.md). Install it with",
        f"#   sudo cp {name}.service /etc/systemd/system/ && sudo systemctl daemon-reload",
        f"#   sudo systemctl enable --now {name}",
        f"# and follow it with: journalctl -u {name} -f",
    ]
    if secure is None:
        lines.append(f"# Open mode: anyone who reaches {listen} may drive the robot; "
                     f"--secure DIR makes it mutual TLS (docs/security.md).")
    lines += [
        "",
        "[Unit]",
        f"Description={systemd_text(f'ubf_async robot {robot.name!r} ({robot_file})')}",
        "Wants=network-online.target",
        "After=network-online.target",
        "",
        "[Service]",
        "Type=exec",
        f"User={user}",
        *([f"SupplementaryGroups={' '.join(needed)}"] if needed else []),
        f"WorkingDirectory={systemd_text(str(robot_file.parent))}",
        "Environment=PYTHONUNBUFFERED=1",
        "ExecStart=" + " ".join(systemd_quote(part) for part in command),
        "# launch's clean end on SIGTERM: the motors stopped, the recordings finished",
        "KillSignal=SIGTERM",
        "TimeoutStopSec=20",
        "Restart=on-failure",
        "RestartSec=2",
        "StandardOutput=journal",
        "StandardError=journal",
        f"SyslogIdentifier={name}",
        "",
        "[Install]",
        "WantedBy=multi-user.target",
        "",
    ]
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=PROG,
        description="Write a systemd unit that starts the robot of ROBOT_FILE at boot: "
                    "python -m ubf_async.launch with this interpreter, as USER in the groups "
                    "its devices need, restarted on failure, logging to journald "
                    "(docs/deploy.md). The robot file is loaded first.",
        epilog=f"example:\n  {PROG} ~/robot/pi-whegs.yaml --listen tls/0.0.0.0:7447 "
               f"--secure ~/.ubf/mini-secure --out ubf-robot-mini.service",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("robot_file", metavar="ROBOT_FILE", type=Path)
    parser.add_argument("--out", type=Path, default=None, metavar="FILE",
                        help="write the unit there (default: print it)")
    parser.add_argument("--user", default=None,
                        help="the user it runs as (default: you; never root)")
    parser.add_argument("--listen", default=None, metavar="ENDPOINT",
                        help="where the robot listens (default: tcp/0.0.0.0:7447, or "
                             "tls/0.0.0.0:7447 with --secure)")
    parser.add_argument("--secure", type=Path, default=None, metavar="DIR",
                        help="the secure set-up's folder (python -m ubf_async.secure init)")
    parser.add_argument("--identity", default="robot",
                        help="the robot's identity in the set-up (default: robot)")
    parser.add_argument("--group", action="append", default=[], metavar="GROUP",
                        help="another group it needs (a backend of your own); repeatable")
    parser.add_argument("--python", type=Path, default=Path(sys.executable), metavar="PATH",
                        help="the interpreter (default: this one, the venv you are in)")
    return parser


def _main(args: argparse.Namespace) -> int:
    robot_file = args.robot_file.expanduser().resolve()
    if not robot_file.is_file():
        raise ConfigurationError(f"{args.robot_file}: no such robot file")
    robot = load_robot(robot_file)
    if robot.simulators():
        print(f"{PROG}: note: {robot_file.name} runs the simulator "
              f"({', '.join(robot.simulators())}), not real devices", file=sys.stderr)
    secure = args.secure.expanduser().resolve() if args.secure is not None else None
    if secure is not None and not (secure / "secure.json").is_file():
        raise ConfigurationError(f"{args.secure}: no secure set-up there (python -m "
                                 f"ubf_async.secure init {args.secure} ...)")
    listen = args.listen or ("tls/0.0.0.0:7447" if secure is not None else "tcp/0.0.0.0:7447")
    if secure is not None and not listen.startswith("tls/"):
        raise ConfigurationError(f"--secure needs a tls/ endpoint, got --listen {listen}")
    user = args.user or getpass.getuser()
    if user == "root":
        raise ConfigurationError("the robot does not run as root: --user a normal user in the "
                                 "devices' groups (docs/hardware.md, Permissions)")
    text = unit_text(robot, robot_file, user=user, python=args.python.absolute(),
                     listen=listen, secure=secure, identity=args.identity, groups=args.group)
    if args.out is None:
        sys.stdout.write(text)
    else:
        args.out.write_text(text, "utf-8")
        name = f"ubf-robot-{robot.name}"
        print(f"unit written to {args.out}; install it: sudo cp {args.out} "
              f"/etc/systemd/system/{name}.service && sudo systemctl daemon-reload && sudo "
              f"systemctl enable --now {name}")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return run_sync(lambda: _main(args), prog=PROG)
