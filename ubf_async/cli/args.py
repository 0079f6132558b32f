"""The connection flags every entry point shares (``--connect/-e``, ``--listen/-l``,
``--mode/-m``, ``--config``, ``--robot``, ``--secure``, ``--identity``, …), turned into
:class:`~ubf_async.net.options.ConnectionOptions`; and the help formatter of every tool."""

from __future__ import annotations

import argparse
from collections.abc import Iterable
from pathlib import Path

from ubf_async.errors import ConfigurationError, ProtocolError
from ubf_async.net.options import (
    DEFAULT_ROBOT,
    ConnectionOptions,
    config_endpoints,
    config_value,
    load_zenoh_config,
    over_tls,
)
from ubf_async.runtime import lending
from ubf_async.wire.keys import Keys

__all__ = ["HelpFormatter", "add_bind_host_argument", "add_connection_arguments",
           "add_event_loop_help", "add_secure_arguments", "connection_options"]


class HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Shows an option's default unless its help already speaks of it or there is none; and a
    usage line of one line: ``PROG [options] POSITIONALS``."""

    def add_usage(self, usage: str | None, actions: Iterable[argparse.Action],
                  groups: Iterable[argparse._MutuallyExclusiveGroup],
                  prefix: str | None = None) -> None:
        if usage is None:
            # The usage argparse builds lists every option: twenty lines before a mistake's
            # one-line error. --help explains each option below it anyway.
            actions = list(actions)
            usage = " ".join(["%(prog)s", "[options]", *(
                self._format_args(a, self._get_default_metavar_for_positional(a))
                for a in actions if not a.option_strings and a.help is not argparse.SUPPRESS)])
        super().add_usage(usage, actions, groups, prefix)

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        default = action.default
        if ("default" in text or default is None or default is False or default == []
                or default is argparse.SUPPRESS):
            return text
        return super()._get_help_string(action) or text


def add_event_loop_help(parser: argparse.ArgumentParser) -> None:
    """Say in ``parser``'s help which event loop runs and what is opt-in
    (:data:`ubf_async.runtime.lending.LOOP_HELP`); :func:`add_connection_arguments` does it."""
    parser.add_argument_group("event loop (environment)", description=lending.LOOP_HELP)


def add_connection_arguments(
    parser: argparse.ArgumentParser, *, default_listen: list[str] | None = None,
    default_identity: str | None = None, default_connect: list[str] | None = None,
    robot_elsewhere: str | None = None,
) -> None:
    """Add ``--mode/-m --connect/-e --listen/-l --config --robot --multicast-scouting``,
    ``--secure DIR --identity NAME`` (and ``--version``) to ``parser``, and the event loop's
    help (:func:`add_event_loop_help`).

    ``default_connect``: where a tool attaching to a robot connects when neither the flags
    nor the ``--config`` file give an endpoint (typically ``[DEFAULT_LISTEN]``, where
    ``python -m ubf_async.launch`` listens); applied by :func:`connection_options`.
    ``robot_elsewhere``: for a tool that learns its robot elsewhere (replay: from the file),
    what ``--robot`` defaults to, in words for the help; ``--robot`` then defaults to ``None``
    and the tool sets ``args.robot`` before :func:`connection_options`."""
    from ubf_async import __version__

    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    group = parser.add_argument_group("connection (shared by every ubf_async entry point)")
    group.add_argument("--mode", "-m", choices=("peer", "client"), default=None,
                       help="zenoh session mode (default: the --config file's, else peer)")
    connect_help = "endpoint to connect to, e.g. tcp/127.0.0.1:7447 (repeatable)"
    if default_connect:
        connect_help = (f"endpoint of the robot (repeatable; default: "
                        f"{' '.join(default_connect)}, where launch listens, unless --listen "
                        f"is given)")
    group.add_argument("--connect", "-e", action="append", default=[], metavar="ENDPOINT",
                       help=connect_help)
    listen_help = "endpoint to listen on, e.g. tcp/127.0.0.1:7448 (repeatable)"
    if default_listen:
        listen_help += (f"; default: {' '.join(default_listen)} unless the --config file "
                        "sets listen endpoints or --mode is client")
    group.add_argument("--listen", "-l", action="append", default=None, metavar="ENDPOINT",
                       help=listen_help)
    group.add_argument("--config", type=Path, default=None, metavar="FILE",
                       help="zenoh JSON5 configuration file (the flags given override it)")
    group.add_argument("--robot", default=DEFAULT_ROBOT if robot_elsewhere is None else None,
                       help="robot name: keys live under ubf/<robot>/" + (
                           f" (default: {robot_elsewhere})" if robot_elsewhere else ""))
    group.add_argument("--multicast-scouting", action="store_true",
                       help="also discover peers by UDP multicast (off by default)")
    identity_help = ("with --secure: who this process is (robot, inspector, operator, a "
                     "remote behaviour's slot name, device-KIND-NAME); all but robot connect "
                     "as clients")
    if default_identity:
        identity_help += f"; default: {default_identity}"
    add_secure_arguments(group, secure_help="secure mode: mutual TLS (tls/ endpoints only) with "
                         "the certificates and credentials in DIR (made by `python -m "
                         "ubf_async.secure init`, or a host's `secure export`); see "
                         "docs/security.md", identity_help=identity_help)
    parser.set_defaults(_default_listen=default_listen or [],
                        _default_identity=default_identity,
                        _default_connect=default_connect or [])
    add_event_loop_help(parser)


def add_secure_arguments(group: argparse._ActionsContainer, *, secure_help: str,
                         identity_help: str | None = None) -> None:
    """Secure mode's flags, the same in every entry point: ``--secure DIR`` and, given its
    help, ``--identity NAME`` (both default ``None``)."""
    group.add_argument("--secure", type=Path, default=None, metavar="DIR", help=secure_help)
    if identity_help is not None:
        group.add_argument("--identity", default=None, metavar="NAME", help=identity_help)


def _over_tls(endpoints: Iterable[str], args: argparse.Namespace) -> list[str]:
    """An entry point's default endpoints; in secure mode (``--secure``) the same over TLS."""
    if getattr(args, "secure", None) is None:
        return list(endpoints)
    return [over_tls(e) for e in endpoints]


def connection_options(args: argparse.Namespace) -> ConnectionOptions:
    """Build :class:`ConnectionOptions` from parsed :func:`add_connection_arguments` flags.

    A ``--config`` file is read here (so a missing or malformed one is refused before anything
    starts) and only the flags actually given override it: ``--listen`` replaces its
    ``listen/endpoints`` and ``--connect`` its ``connect/endpoints``; without the flag, the
    file's endpoints (and ``mode``, when ``--mode`` defaults to ``None``) are kept, and the
    entry point's default listen endpoint (launch's) applies only when neither sets one, and
    not to a ``client`` (it joins a router); a tool's default connect endpoint only when
    neither sets any endpoint.
    Raises :class:`~ubf_async.errors.ConfigurationError`.
    """
    file_conf = load_zenoh_config(args.config) if args.config is not None else None
    mode = getattr(args, "mode", None) or config_value(file_conf, "mode") or "peer"
    if not isinstance(mode, str):
        raise ConfigurationError(f"--config {args.config}: `mode` must be a string, got {mode!r}")
    listen = args.listen
    if listen is None:
        from_file = config_endpoints(file_conf, "listen", mode)
        default = [] if mode == "client" else getattr(args, "_default_listen", [])
        listen = from_file if from_file is not None else _over_tls(default, args)
    connect = list(args.connect) or config_endpoints(file_conf, "connect", mode) or []
    if not connect and not listen:  # a tool's default: the robot's endpoint
        connect = _over_tls(getattr(args, "_default_connect", []), args)
    try:
        Keys(args.robot)
    except ProtocolError as exc:
        raise ConfigurationError(f"--robot: {exc}") from None
    options = ConnectionOptions(
        robot=args.robot, mode=mode, connect=connect, listen=list(listen),
        config=args.config, multicast_scouting=args.multicast_scouting,
        **ConnectionOptions.secure_fields(args),
    )
    options.zenoh_config()  # every endpoint and value is checked now, not at the session
    return options


def add_bind_host_argument(parser: argparse.ArgumentParser | argparse._ArgumentGroup, flag: str,
                           *, default: str, server: str) -> None:
    """``flag HOST``: the address ``server`` (a server without authentication: the live view,
    the tree monitor) binds — loopback by default, wider only on a network one trusts."""
    parser.add_argument(flag, default=default, metavar="HOST",
                        help=f"address {server} binds (loopback by default: it has no "
                             f"authentication; 0.0.0.0 serves every interface — only on a "
                             f"network you trust)")
