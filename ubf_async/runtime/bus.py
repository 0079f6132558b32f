"""The runtime's side of the network: connection options, the bus, and the bridge into asyncio.

A :class:`Bus` moves its bytes through a transport (:mod:`ubf_async.net.transport`): a zenoh
session (:meth:`Bus.open`, what runs) or the in-process transport (``Bus(transport=...)``,
for unit tests). Everything below is the same on both.

zenoh-python is synchronous and runs subscriber callbacks on its own threads. The bridge
here is deliberate about that hand-off:

* the transport's callback does almost nothing: it copies the key and payload bytes, stores
  them and, if no drain is already pending, schedules one with ``loop.call_soon_threadsafe``
  (``loop.call_soon`` for a transport whose callbacks run on the loop) — it never calls the
  transport, never blocks and never runs user code;
* the drain runs on the event loop and calls the handler for each stored sample;
* in **latest** mode a burst on one key coalesces to the newest sample (what a state
  aggregator wants); in **every** mode samples queue up to a bound, and overflow drops the
  oldest and is counted.

A handler that raises is logged with its traceback and counted; the subscription keeps going
(a handler bug must not take the robot down). Measure the hand-off with ``bench/handoff.py``
and ``bench/latency``.

A **direct** subscription (``subscribe(..., direct=True)``: the state aggregator's) skips the
hand-off when it can: on a
:class:`~ubf_async.runtime.lending.LendingEventLoop` — the loop every entry point runs on — a sample
that finds the loop idle and nothing of its subscription pending is drained at once on the
transport's thread, with the loop lent to it (:mod:`ubf_async.runtime.lending`): same handler, same
order, same counters, one thread at a time, and no wake-up of the loop thread on the way — up
to :data:`DIRECT_RATE_HZ` samples a second; a flood beyond it takes the usual road and
coalesces.

Samples between components of the **same** :class:`Bus` (one process) never take that detour:
a :class:`Publisher` hands them straight to the matching subscriptions of its bus, on the loop
(``loop.call_soon``), and transport subscribers are declared **remote only** (zenoh:
``allowed_origin=REMOTE``) so they only bring in samples from other buses. A sample published
on the loop is therefore handled on the loop's next iterations without waiting for a zenoh
thread to get the GIL — which is what lets a simulated robot run several times faster than
real time without its own commands arriving late in simulated time. Semantics (latest/every,
counters, handler errors) are the same for both paths.

Queries take the same road: :meth:`Bus.declare_queryable` answers each query on the event
loop (the transport's callback only hands it over), and :meth:`Bus.query` awaits the first
reply without blocking the loop (zenoh's query runs in a worker thread).
"""

from __future__ import annotations

import argparse
import asyncio
import dataclasses
import itertools
import json
import logging
import re
import secrets
import socket
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import zenoh

from ubf_async import throttle
from ubf_async.errors import ConfigurationError, UbfError
from ubf_async.net.transport import (
    Connection,
    Declaration,
    IncomingQuery,
    Transport,
    ZenohConnection,
    ZenohTransport,
    intersects,
)
from ubf_async.runtime import lending
from ubf_async.runtime.clock import Clock, SimClock, WallClock
from ubf_async.runtime.timesource import ClockAction, ClockFollower
from ubf_async.wire.protocol import INT64_MAX, ROOT, Keys, ProtocolError, decode, encode
from ubf_async.wire.topics import CLOCK, Data, Topic

log = logging.getLogger(__name__)

DEFAULT_ROBOT = "mini"
DEFAULT_LISTEN = "tcp/127.0.0.1:7447"

_monotonic_ns = time.monotonic_ns

DRAIN_BATCH = 256
"""Samples a subscription hands to its handler in one pass of the event loop."""
MAX_COUNTED_KEYS = 1024
"""Keys whose malformed-sample counts :func:`decode_or_count` keeps (the oldest goes first)."""
DIRECT_RATE_HZ = 1000.0
"""Samples per second a direct subscription may have handled on the transport's thread
(:mod:`~ubf_async.runtime.lending`), beyond a burst of :data:`DIRECT_BURST`: a robot's sensors send
a few hundred; above that — a flood — samples take the usual road and coalesce, so the
transport's threads never hold the GIL for long against the loop."""
DIRECT_BURST = 100
"""Samples a direct subscription may have handled on the transport's thread back to back,
before :data:`DIRECT_RATE_HZ` paces it."""

SampleHandler = Callable[[str, bytes, int], None]
"""``handler(key, payload, received_ns)`` — runs on the event loop."""

QueryHandler = Callable[[str, bytes], bytes]
"""``handler(key, payload) -> reply payload`` — runs on the event loop (see
:meth:`Bus.declare_queryable`)."""


# ---------------------------------------------------------------------------------------------
# Connection options shared by every entry point (the zenoh examples' flags)

RECONNECT_RETRY = {"period_init_ms": 250, "period_max_ms": 1000, "period_increase_factor": 2}
"""How often a session retries a lost connection (zenoh's ``connect/retry``): from 250 ms,
backing off to at most 1 s — zenoh's default backs off to 4 s — so a client whose router
restarts is back within about a second of the router's return (``docs/fleet.md``)."""


@dataclass(kw_only=True)
class ConnectionOptions:
    """How to join the zenoh network, plus which robot to talk about."""

    robot: str = DEFAULT_ROBOT
    mode: str = "peer"
    connect: list[str] = field(default_factory=list)
    listen: list[str] = field(default_factory=list)
    config: Path | None = None
    multicast_scouting: bool = False
    """Off by default: a robot is found through explicit endpoints, never by accident."""
    secure: Path | None = None
    """Secure mode: a set-up directory made by ``python -m ubf_async.secure init``."""
    identity: str | None = None
    """Secure mode: who this process is (``robot``, ``inspector``, a remote behaviour's name
    …); its credentials are ``<secure>/identities/<identity>.json``."""

    @staticmethod
    def secure_fields(args: argparse.Namespace) -> dict[str, Any]:
        """``secure`` and ``identity`` from :func:`add_connection_arguments` flags: the
        entry point's default identity applies only with ``--secure``."""
        secure = getattr(args, "secure", None)
        identity = getattr(args, "identity", None)
        if secure is not None and identity is None:
            identity = getattr(args, "_default_identity", None)
        return {"secure": secure, "identity": identity}

    def zenoh_config(self) -> zenoh.Config:
        """The zenoh configuration: the ``config`` file, then these options over it; in secure
        mode the identity's credentials (and for ``robot`` the password dictionary and the
        ACL), and client mode for every identity but ``robot`` (see :mod:`ubf_async.net.secure`).
        Raises :class:`~ubf_async.errors.ConfigurationError` for a bad secure set-up."""
        conf = zenoh.Config.from_file(str(self.config)) if self.config else zenoh.Config()
        conf.insert_json5("mode", json.dumps(self.mode))
        if self.connect:
            conf.insert_json5("connect/endpoints", json.dumps(self.connect))
        if self.listen:
            conf.insert_json5("listen/endpoints", json.dumps(self.listen))
        if not self.multicast_scouting:
            conf.insert_json5("scouting/multicast/enabled", "false")
        if conf.get_json("connect/retry") == "null":  # the file's own retry wins
            conf.insert_json5("connect/retry", json.dumps(RECONNECT_RETRY))
        if self.secure is not None:
            from ubf_async.net import secure as secure  # only secure mode needs it

            secure.apply(conf, directory=self.secure, identity=self.identity, robot=self.robot,
                         listen=self.listen)
        elif self.identity is not None:
            raise ConfigurationError(f"--identity {self.identity} needs --secure DIR")
        return conf


class HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Shows an option's default unless its help already speaks of it or there is none."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        default = action.default
        if ("default" in text or default is None or default is False or default == []
                or default is argparse.SUPPRESS):
            return text
        return super()._get_help_string(action) or text


def add_connection_arguments(
    parser: argparse.ArgumentParser, *, default_listen: list[str] | None = None,
    default_identity: str | None = None, default_connect: list[str] | None = None,
    robot_elsewhere: str | None = None,
) -> None:
    """Add ``--mode/-m --connect/-e --listen/-l --config --robot --multicast-scouting``,
    ``--secure DIR --identity NAME`` (and ``--version``) to ``parser``.

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
    group.add_argument("--secure", type=Path, default=None, metavar="DIR",
                       help="secure mode: authenticate with the credentials in DIR (made by "
                            "`python -m ubf_async.secure init`); see docs/security.md")
    identity_help = ("with --secure: who this process is (robot, inspector, operator, a "
                     "remote behaviour's slot name, device-KIND-NAME); all but robot connect "
                     "as clients")
    if default_identity:
        identity_help += f"; default: {default_identity}"
    group.add_argument("--identity", default=None, metavar="NAME", help=identity_help)
    parser.set_defaults(_default_listen=default_listen or [],
                        _default_identity=default_identity,
                        _default_connect=default_connect or [])


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
    mode = getattr(args, "mode", None) or _config_value(file_conf, "mode") or "peer"
    if not isinstance(mode, str):
        raise ConfigurationError(f"--config {args.config}: `mode` must be a string, got {mode!r}")
    listen = args.listen
    if listen is None:
        from_file = _config_endpoints(file_conf, "listen", mode)
        default = [] if mode == "client" else getattr(args, "_default_listen", [])
        listen = from_file if from_file is not None else list(default)  # clients: the router
    connect = list(args.connect) or _config_endpoints(file_conf, "connect", mode) or []
    if not connect and not listen:  # a tool's default: the robot's endpoint
        connect = list(getattr(args, "_default_connect", []))
    try:
        Keys(args.robot)
    except ProtocolError as exc:
        raise ConfigurationError(f"--robot: {exc}") from None
    options = ConnectionOptions(
        robot=args.robot, mode=mode, connect=connect, listen=list(listen),
        config=args.config, multicast_scouting=args.multicast_scouting,
        **ConnectionOptions.secure_fields(args),
    )
    try:  # every endpoint and value is checked now, not when the session opens
        options.zenoh_config()
    except zenoh.ZError as exc:
        raise ConfigurationError(f"zenoh configuration: {zenoh_message(exc)}") from None
    return options


def load_zenoh_config(path: Path) -> zenoh.Config:
    """Read a zenoh JSON5 configuration file; :class:`ConfigurationError` if it cannot be."""
    if not path.is_file():
        raise ConfigurationError(f"--config {path}: no such file")
    try:
        return zenoh.Config.from_file(str(path))
    except zenoh.ZError as exc:
        raise ConfigurationError(f"--config {path}: {zenoh_message(exc)}") from None


def _config_value(conf: zenoh.Config | None, key: str) -> Any:
    """``key`` of a configuration read from a file, or ``None`` where the file leaves zenoh's
    default (zenoh reports its defaults as if they were set)."""
    if conf is None:
        return None
    try:
        value = conf.get_json(key)
        if value == zenoh.Config().get_json(key):
            return None
        return json.loads(value)
    except (zenoh.ZError, ValueError):
        return None


def _config_endpoints(conf: zenoh.Config | None, section: str, mode: str) -> list[str] | None:
    """``<section>/endpoints`` set by a configuration file (a list, or one list per mode:
    this ``mode``'s); ``None`` if the file sets none."""
    value = _config_value(conf, f"{section}/endpoints")
    if value is None:
        return None
    if isinstance(value, dict):
        value = value.get(mode, [])
    if isinstance(value, list) and all(isinstance(e, str) for e in value):
        return list(value)
    return None


_RUST_LOCATION = re.compile(r"\s*\bat /\S+\.rs:\d+\.?")


def zenoh_message(exc: BaseException) -> str:
    """A zenoh error's message without the Rust source locations it carries."""
    text = _RUST_LOCATION.sub("", str(exc)).strip()
    if (wrapped := re.search(r'msg: "((?:[^"\\]|\\.)*)"', text)) is not None:
        text = wrapped[1]  # Json5Err(Message { msg: "...", location: ... }) -> the message
    return re.sub(r"\s+", " ", text).rstrip(" .!") or type(exc).__name__


_PORT_ZERO = re.compile(
    r"^(?P<proto>tcp|udp|tls|quic|ws)/(?P<host>\[[^\]]*\]|[^:/?#\[\]]+):0(?P<rest>[?#].*)?$")


def bind_free_ports(endpoints: list[str]) -> list[str]:
    """The endpoints with each ``…:0`` port replaced by a port free now, so the endpoints a
    process prints are the ones it listens on (zenoh-python 1.10 does not say which port it
    bound: ``SessionInfo`` has no locators, and its admin space is off by default). The OS
    picks the port (bind to port 0, read it, release it); another program could take it in
    the instant before zenoh binds it, and opening then fails as "port in use"."""
    resolved = []
    for endpoint in endpoints:
        match = _PORT_ZERO.match(endpoint)
        if match is None:
            resolved.append(endpoint)
            continue
        host = match["host"].strip("[]")
        kind = socket.SOCK_DGRAM if match["proto"] in ("udp", "quic") else socket.SOCK_STREAM
        try:
            family, *_, address = socket.getaddrinfo(host, 0, type=kind)[0]
            with socket.socket(family, kind) as probe:
                probe.bind(address)
                port = probe.getsockname()[1]
        except OSError:  # an address we cannot bind: zenoh will say what is wrong with it
            resolved.append(endpoint)
            continue
        resolved.append(f"{match['proto']}/{match['host']}:{port}{match['rest'] or ''}")
    return resolved


class SessionError(UbfError, ConnectionError):
    """A zenoh session that cannot be opened, or does not reach the robot (one line that
    says what to do)."""


class PortInUseError(SessionError):
    """A listen endpoint whose port another process already holds."""


class NoRobotError(SessionError):
    """Nothing to connect to: no robot answers at the endpoints given."""


class RefusedError(SessionError):
    """Something listens at the robot's endpoint but did not accept this process's zenoh
    session: a robot in secure mode refusing its credentials, as far as can be told."""


START_ROBOT_HINT = ("is the robot running? `python -m ubf_async.launch` prints the endpoint "
                    "to pass to --connect")

_TCP_ENDPOINT = re.compile(
    r"^(?:tcp|tls|ws)/(?P<host>\[[^\]]*\]|[^:/?#\[\]]+):(?P<port>\d+)(?:[?#].*)?$")


def listening(endpoint: str, *, timeout_s: float = 1.0) -> bool:
    """Whether a TCP connection to ``endpoint`` (``tcp/``, ``tls/``, ``ws/``) opens: something
    listens there. zenoh reports a refused handshake (a secure robot's authentication) exactly
    as it reports nothing listening, so this tells the two apart. Blocking."""
    match = _TCP_ENDPOINT.match(endpoint)
    if match is None:
        return False  # udp, quic, unix sockets …: not probed
    try:
        with socket.create_connection((match["host"].strip("[]"), int(match["port"])),
                                      timeout=timeout_s):
            return True
    except (OSError, ValueError):
        return False


def refused_error(options: ConnectionOptions, *, timeout_s: float = 1.0) -> RefusedError | None:
    """For a session that reached nothing: a :class:`RefusedError` saying so if something
    listens at one of its ``connect`` endpoints (:func:`listening`), else ``None``. Blocking:
    run it in a thread."""
    open_at = [e for e in options.connect if listening(e, timeout_s=timeout_s)]
    if not open_at:
        return None
    if options.secure is None:
        credentials = ("this process gave none: pass the robot's set-up with --secure DIR "
                       "--identity NAME")
    else:
        credentials = (f"this process gave identity {options.identity!r} of {options.secure}, "
                       f"which the robot's set-up does not have with that password (another "
                       f"set-up, or one made again with `python -m ubf_async.secure init "
                       f"--force`)")
    tls = ("; over tls/, a certificate the robot does not trust looks the same"
           if any(e.startswith("tls/") for e in open_at) else "")
    return RefusedError(
        f"the robot at {' '.join(open_at)} refused the connection: something listens there but "
        f"did not let this process's zenoh session in, as a robot in secure mode does without "
        f"valid credentials (docs/security.md); {credentials}{tls}")


def session_error(options: ConnectionOptions, exc: zenoh.ZError) -> SessionError:
    """Turn zenoh's error on opening a session into a one-line :class:`SessionError`."""
    text = zenoh_message(exc)
    if "Address already in use" in text or "address already in use" in text.lower():
        bound = re.search(r"bound to (\S+?):? \[", text)
        where = bound[1] if bound else " ".join(options.listen)
        return PortInUseError(
            f"cannot listen on {where}: the port is already in use (another robot or program "
            f"listens there); stop it, or choose another endpoint with --listen "
            f"(e.g. --listen tcp/127.0.0.1:0 for any free port)")
    if "Unable to connect" in text:
        return NoRobotError(f"no robot to connect to: nothing answered at "
                            f"{' '.join(options.connect)} ({START_ROBOT_HINT})")
    return SessionError(f"cannot open a zenoh session (listen={' '.join(options.listen) or '-'}"
                        f", connect={' '.join(options.connect) or '-'}): {text}")


DEFAULT_ATTACH_TIMEOUT_S = 10.0

CONNECT_GRACE_S = 2.0
"""How long a peer's ``connect`` endpoint may stay unanswered before it is reported."""
CONNECT_CHECK_S = 0.5
"""How often the links to the ``connect`` endpoints are looked at."""
CONNECT_REMIND_S = 60.0
"""While an endpoint stays unanswered, the warning is repeated this often."""
_IP_ENDPOINT = re.compile(r"^(?P<proto>tcp|udp|tls|quic|ws)/(?P<host>\[[^\]]*\]|[^:/?#\[\]]+)"
                          r":(?P<port>\d+)")


def endpoint_locators(endpoint: str) -> set[str]:
    """The locators a link to ``endpoint`` may have as its destination: the endpoint without
    its ``?``/``#`` options and, for an IP endpoint given by host name, one per address the
    name resolves to (``tcp/localhost:7447`` → ``tcp/127.0.0.1:7447``, ``tcp/[::1]:7447``)."""
    plain = re.split(r"[?#]", endpoint, maxsplit=1)[0]
    found = {plain}
    match = _IP_ENDPOINT.match(plain)
    if match is None:
        return found
    proto, host, port = match["proto"], match["host"].strip("[]"), int(match["port"])
    try:
        addresses = {info[4][0] for info in socket.getaddrinfo(host, port)}
    except OSError:  # a name that does not resolve now: zenoh will keep trying it too
        return found
    for address in addresses:
        address = str(address)
        found.add(f"{proto}/[{address}]:{port}" if ":" in address
                  else f"{proto}/{address}:{port}")
    return found


async def watch_connect_endpoints(bus: Bus, endpoints: list[str], *,
                                  grace_s: float = CONNECT_GRACE_S,
                                  check_s: float = CONNECT_CHECK_S,
                                  remind_s: float = CONNECT_REMIND_S) -> None:
    """Report, as warnings, the ``connect`` endpoints of a peer session that nothing answers
    at (after ``grace_s``, then every ``remind_s``), and when one answers after all or its link
    is lost; zenoh retries them meanwhile (:data:`RECONNECT_RETRY`). Runs until cancelled
    (the bus closes)."""
    connection = bus._connection
    links = getattr(connection, "link_destinations", None)
    if links is None:
        return  # a transport without links to look at (the in-process one)
    locators = {e: await asyncio.to_thread(endpoint_locators, e) for e in endpoints}
    loop = asyncio.get_running_loop()
    opened = loop.time()
    up: dict[str, bool] = dict.fromkeys(endpoints, False)
    warned_at: dict[str, float] = {}  # endpoints reported unanswered, and when last
    ever_up: set[str] = set()
    while True:
        try:
            destinations = set(links())
        except Exception:  # a closing session: nothing left to watch
            return
        now = loop.time()
        for endpoint in endpoints:
            reached = bool(locators[endpoint] & destinations)
            if reached and not up[endpoint]:
                if endpoint in warned_at:
                    log.warning("connected to %s%s", endpoint, " again" if endpoint in ever_up
                                else f" after {now - opened:.0f} s")
                    del warned_at[endpoint]
                ever_up.add(endpoint)
            elif not reached and up[endpoint]:
                log.warning("lost the connection to %s: retrying until it answers again",
                            endpoint)
                warned_at[endpoint] = now
            elif not reached and (
                    (endpoint not in warned_at and now - opened >= grace_s)
                    or (endpoint in warned_at and now - warned_at[endpoint] >= remind_s)):
                if await asyncio.to_thread(listening, endpoint):
                    # Something accepts TCP there and still no link: it refuses this session.
                    log.warning("%s (--connect) does not let this session in after %.0f s: "
                                "something listens there, as a robot in secure mode does to a "
                                "process without valid credentials (docs/security.md); "
                                "retrying every second", endpoint, now - opened)
                else:
                    log.warning("nothing answers at %s (--connect) after %.0f s: retrying "
                                "every second until it does (%s)", endpoint, now - opened,
                                START_ROBOT_HINT)
                warned_at[endpoint] = now
            up[endpoint] = reached
        await asyncio.sleep(check_s)


async def wait_for_robot(bus: Bus, *, timeout_s: float = DEFAULT_ATTACH_TIMEOUT_S,
                         any_robot: bool = False) -> None:
    """For a process attaching to a running robot: wait until the session reaches another
    zenoh node and one of the robot's components is alive there (its liveliness token
    ``ubf/<robot>/alive/*``). Raises :class:`NoRobotError` after ``timeout_s``, saying whether
    nothing answered at the endpoints or the robot there has another name, or
    :class:`RefusedError` when something listens there but never let the session in.

    Returns at once for a session that only listens (in ``peer`` mode without ``connect``
    endpoints others come to it). Call it right after :meth:`Bus.open`, before starting
    anything. ``any_robot``: any robot's component will do (a tool looking at a fleet)."""
    options = bus.options
    if not options.connect and options.mode != "client":
        return
    where = " ".join(options.connect) or "(the configured router)"
    deadline = time.monotonic() + timeout_s
    reached = False
    while True:
        reached = reached or bus.reached_peers()
        alive = f"{ROOT}/*/alive/*" if any_robot else bus.keys.all_alive
        if reached and await bus.alive_tokens(alive, timeout_s=1.0):
            return
        if time.monotonic() >= deadline:
            break
        await asyncio.sleep(0.05)
    if not reached:
        refused = await asyncio.to_thread(refused_error, options)
        if refused is not None:
            raise refused
        raise NoRobotError(f"no robot to connect to: nothing answered at {where} within "
                           f"{timeout_s:g}s ({START_ROBOT_HINT})")
    seen = sorted({key.split("/")[1] for key in await bus.alive_tokens(
        f"{ROOT}/*/alive/*", timeout_s=1.0)} - {bus.robot})
    other = f"; robots there: {', '.join(seen)} (check --robot)" if seen else ""
    raise NoRobotError(f"no robot {bus.robot!r} answered at {where} within {timeout_s:g}s: "
                       f"a zenoh node is there, but none of the robot's components is alive"
                       f"{other}")


# ---------------------------------------------------------------------------------------------
# The bridge


@dataclass
class BridgeStats:
    received: int = 0
    delivered: int = 0
    coalesced: int = 0
    """Samples overwritten by a newer one on the same key before the loop drained them."""
    dropped: int = 0
    """Samples dropped from a full queue (``every`` mode)."""
    handler_errors: int = 0
    direct: int = 0
    """Hand-offs run on the transport's thread while the loop was idle (``direct=True``)."""


class Subscription:
    """A subscriber whose samples are delivered on the event loop (the bridge)."""

    def __init__(
        self,
        loop: asyncio.AbstractEventLoop,
        handler: SampleHandler,
        *,
        latest: bool,
        max_queue: int = 1024,
        name: str = "",
        direct: bool = False,
    ) -> None:
        self._loop = loop
        self._handler = handler
        self._latest = latest
        self._run_if_idle = lending.run_if_idle(loop) if direct else None
        """Runs the drain on the transport's thread while the loop waits (:mod:`.lending`)."""
        self._direct_tokens = float(DIRECT_BURST)
        self._direct_refilled_ns = _monotonic_ns()
        self._lock = threading.Lock()
        self._pending_latest: dict[str, tuple[bytes, int]] = {}
        self._pending_queue: deque[tuple[str, bytes, int]] = deque(maxlen=max_queue)
        self._max_pending = max_queue
        """Distinct keys waiting in latest mode (a new key beyond them is dropped)."""
        self._scheduled = False
        self._closed = False
        self._declaration: Declaration | None = None
        self._on_close: Callable[[Subscription], None] | None = None
        self.name = name
        self.stats = BridgeStats()

    # transport thread --------------------------------------------------------------------
    def push_from_loop(self, key: str, payload: bytes) -> None:
        """:meth:`push` for callbacks that run on the loop's own thread (in-process)."""
        self.push(key, payload, on_loop=True)

    @property
    def pending(self) -> bool:
        """Whether samples wait for a drain."""
        return self._scheduled

    def push(self, key: str, payload: bytes, *, on_loop: bool = False) -> None:
        """Hand one sample to the loop; callable from any thread, never blocks for long.

        ``on_loop=True`` (only from the loop's own thread) schedules the drain with
        ``call_soon``, skipping the thread-safe wake-up."""
        received_ns = _monotonic_ns()
        stats = self.stats
        with self._lock:
            if self._closed:
                return
            stats.received += 1
            if self._latest:
                pending = self._pending_latest
                if key in pending:
                    stats.coalesced += 1
                elif len(pending) >= self._max_pending:
                    # A flood of distinct keys must not grow memory or the loop's next batch.
                    stats.dropped += 1
                    return
                pending[key] = (payload, received_ns)
            else:
                queue = self._pending_queue
                if len(queue) == self._max_pending:  # full: append drops the oldest
                    stats.dropped += 1
                queue.append((key, payload, received_ns))
            if self._scheduled:
                return
            self._scheduled = True
            lend = self._run_if_idle
            if on_loop or (lend is not None and not self._take_direct_token(received_ns)):
                lend = None
        if on_loop:
            self._loop.call_soon(self._drain)
            return
        if lend is not None and lend(self._drain):
            stats.direct += 1
            return
        try:  # noqa: SIM105 — contextlib.suppress would add ≈ 0.4 µs to every hand-off
            self._loop.call_soon_threadsafe(self._drain)
        except RuntimeError:  # a closed loop: nothing left to deliver to
            pass

    def _take_direct_token(self, now_ns: int) -> bool:
        """The budget of samples handled on the transport's thread (:data:`DIRECT_RATE_HZ`);
        call with the lock held."""
        tokens = min(float(DIRECT_BURST), self._direct_tokens
                     + (now_ns - self._direct_refilled_ns) * (DIRECT_RATE_HZ / 1e9))
        self._direct_refilled_ns = now_ns
        if tokens < 1.0:
            self._direct_tokens = tokens
            return False
        self._direct_tokens = tokens - 1.0
        return True

    # event loop --------------------------------------------------------------------------
    def _drain(self) -> None:
        with self._lock:
            if self._latest:
                pending = self._pending_latest
                if len(pending) <= DRAIN_BATCH:  # the usual case: take the whole dict
                    self._pending_latest = {}
                    batch = [(k, p, t) for k, (p, t) in pending.items()]
                    more = False
                else:
                    keys = list(itertools.islice(pending, DRAIN_BATCH))
                    batch = [(k, *pending.pop(k)) for k in keys]
                    more = True
            else:
                queue = self._pending_queue
                if len(queue) <= DRAIN_BATCH:
                    batch = list(queue)
                    queue.clear()
                    more = False
                else:
                    batch = [queue.popleft() for _ in range(DRAIN_BATCH)]
                    more = True
            # With more waiting the drain stays scheduled, but yields to the loop first:
            # a flood is handled in slices, never in one pass that starves other tasks.
            self._scheduled = more
        if more:
            self._loop.call_soon(self._drain)
        handler = self._handler
        stats = self.stats
        for key, payload, received_ns in batch:
            if self._closed:
                return
            try:
                handler(key, payload, received_ns)
            except Exception:
                stats.handler_errors += 1
                log.exception("handler of subscription %s failed on %s", self.name, key)
            else:
                stats.delivered += 1

    def close(self) -> None:
        """Stop delivering; idempotent."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
        if self._on_close is not None:
            self._on_close(self)
        if self._declaration is not None:
            self._declaration.undeclare()


class Publisher:
    """Publishes validated messages of one schema on one key, numbering them.

    Every instance draws a random publisher identity (``pub``: 1 ≤ pub < 2**63) that goes in
    each envelope, so receivers order its samples by ``seq`` per publisher and recognise a
    restarted component (a new instance, a new ``pub``, ``seq`` from 1 again) as a new
    publisher rather than as a replay (:mod:`ubf_async.runtime.ordering`)."""

    def __init__(self, bus: Bus, key: str, schema: str, *, period_s: float | None) -> None:
        self.key = key
        self.schema = schema
        self.period_s = period_s
        self.seq = 0
        self.pub = secrets.randbelow(INT64_MAX) + 1
        self._bus = bus
        self._out = bus._connection.declare_publisher(key)
        self._closed = False

    def publish(self, data: Data | Mapping[str, Any], *,
                stamp_ns: int | None = None) -> tuple[int, int]:
        """Encode and send one sample (the topic's typed message, or a map of its fields,
        validated either way): to the matching subscriptions of this bus (on the loop)
        and through the transport to other buses. Returns ``(seq, stamp_ns)`` of what was sent.
        Call it on the bus's event loop."""
        stamp = self._bus.clock.now_ns() if stamp_ns is None else stamp_ns
        self.seq += 1
        payload = encode(self.schema, data, stamp_ns=stamp, seq=self.seq, period_s=self.period_s,
                         pub=self.pub)
        local = self._bus._local_subscriptions(self.key)
        if local:
            on_loop = threading.get_ident() == self._bus._loop_thread
            for sub in local:
                sub.push(self.key, payload, on_loop=on_loop)
        self._out.put(payload)
        return self.seq, stamp

    def has_subscribers(self) -> bool:
        """Whether a subscriber matching this key is known: on this bus, or to the transport."""
        return bool(self._bus._local_subscriptions(self.key)) or self._out.has_remote_subscribers()

    async def wait_for_subscribers(self, timeout_s: float = 5.0) -> None:
        """Wait until a matching subscriber is known (declarations propagate asynchronously:
        a sample put before that is not delivered to it). Raises TimeoutError."""
        deadline = time.monotonic() + timeout_s
        while not self.has_subscribers():
            if time.monotonic() > deadline:
                raise TimeoutError(f"no subscriber for {self.key} within {timeout_s}s")
            await asyncio.sleep(0.01)

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self._out.undeclare()


class QueryError(UbfError, RuntimeError):
    """A queryable answered with an error instead of a reply (see :meth:`Bus.query`)."""


@dataclass
class QueryStats:
    received: int = 0
    answered: int = 0
    refused: int = 0
    """Queries answered with an error at once because ``max_pending`` were waiting."""
    handler_errors: int = 0


class Queryable:
    """A queryable whose queries are answered on the event loop.

    The transport's callback only takes the query (its payload already copied) and schedules
    the answer on the loop (``call_soon_threadsafe`` from a zenoh thread, ``call_soon`` on the
    loop's own); the handler runs there, so what it reads or changes is never touched by a
    transport thread. Its return value is the reply; a handler that raises is logged and
    counted, and the querier gets an error reply. At most ``max_pending`` queries wait for the
    loop; more are refused with an error reply at once (a flood cannot queue up work).
    """

    def __init__(
        self, loop: asyncio.AbstractEventLoop, key: str, handler: QueryHandler, *,
        max_pending: int = 64, callbacks_on_loop: bool = False,
    ) -> None:
        self.key = key
        self._loop = loop
        self._handler = handler
        self._max_pending = max_pending
        self._on_loop = callbacks_on_loop
        self._pending = 0
        self._lock = threading.Lock()
        self._closed = False
        self._declaration: Declaration | None = None
        self._on_close: Callable[[Queryable], None] | None = None
        self.stats = QueryStats()

    @property
    def pending(self) -> bool:
        """Whether queries wait for the loop."""
        return self._pending > 0

    # transport thread --------------------------------------------------------------------
    def on_query(self, query: IncomingQuery) -> None:
        """The transport's callback: hand the query to the loop, never block."""
        with self._lock:
            self.stats.received += 1
            refuse = "closed" if self._closed else (
                "busy" if self._pending >= self._max_pending else "")
            if refuse:
                self.stats.refused += 1
            else:
                self._pending += 1
        if refuse:
            self._error(query, f"{self.key}: {refuse}, try again")
            return
        if self._on_loop:
            self._loop.call_soon(self._answer, query)
            return
        try:
            self._loop.call_soon_threadsafe(self._answer, query)
        except RuntimeError:  # the loop is closed: nobody will answer
            self._error(query, f"{self.key}: closed")

    @staticmethod
    def _error(query: IncomingQuery, text: str) -> None:
        query.reply_err(text)
        query.drop()

    # event loop --------------------------------------------------------------------------
    def _answer(self, query: IncomingQuery) -> None:
        with self._lock:
            self._pending -= 1
            closed = self._closed
        if closed:
            self._error(query, f"{self.key}: closed")
            return
        try:
            reply = self._handler(query.key, query.payload)
        except Exception as exc:
            self.stats.handler_errors += 1
            log.exception("handler of queryable %s failed", self.key)
            self._error(query, f"{self.key}: internal error: {type(exc).__name__}: {exc}")
            return
        try:
            query.reply(self.key, reply)
            self.stats.answered += 1
        except Exception as exc:  # the transport's error (zenoh.ZError): the querier left
            log.warning("cannot reply to a query on %s: %s", self.key, exc)
        finally:
            query.drop()

    def close(self) -> None:
        """Stop answering (queries still waiting get an error reply); idempotent."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
        if self._on_close is not None:
            self._on_close(self)
        if self._declaration is not None:
            self._declaration.undeclare()


class RawPublisher:
    """Puts payloads on one key as they are (:meth:`Bus.raw_publisher`)."""

    def __init__(self, bus: Bus, key: str) -> None:
        self._bus = bus
        self.key = key
        self._out = bus._connection.declare_publisher(key)

    def put(self, payload: bytes) -> None:
        local = self._bus._local_subscriptions(self.key)
        if local:
            on_loop = threading.get_ident() == self._bus._loop_thread
            for sub in local:
                sub.push(self.key, payload, on_loop=on_loop)
        self._out.put(payload)

    def close(self) -> None:
        self._out.undeclare()


class Bus:
    """One robot's view of the network, used from one event loop.

    The bytes move through a transport (:mod:`ubf_async.net.transport`), as an HTTP client's
    requests go through its transport: ``Bus.open(options)`` opens a zenoh session and is what
    every entry point uses; ``Bus(transport=InProcessTransport(), robot="mini")`` connects to a
    network inside the loop (unit tests: several buses on one transport see each other as
    processes do). The bus adds the same things on either: the hand-off onto the loop, same-bus
    delivery, latest/every modes, bounded queues and counted handler errors.

    Construct it on its event loop. Open with ``async with await Bus.open(options) as bus``
    or ``bus = await Bus.open(...)`` and ``await bus.aclose()`` (idempotent).
    """

    def __init__(
        self, *, transport: Transport, options: ConnectionOptions | None = None,
        robot: str | None = None, clock: Clock | None = None,
    ) -> None:
        """``options`` (their ``robot``) or ``robot`` name the robot (default
        :data:`DEFAULT_ROBOT`); ``clock`` stamps what this bus publishes (default: the wall
        clock). Raises :class:`~ubf_async.errors.ConfigurationError` for a bad robot name or
        ``robot`` contradicting ``options``."""
        if options is None:
            options = ConnectionOptions(robot=robot or DEFAULT_ROBOT)
        elif robot is not None and robot != options.robot:
            raise ConfigurationError(f"Bus: robot={robot!r} but options.robot="
                                     f"{options.robot!r}")
        try:
            self.keys = Keys(options.robot)
        except ProtocolError as exc:
            raise ConfigurationError(f"robot name: {exc}") from None
        self.options = options
        self.clock: Clock = clock or WallClock()
        self.transport = transport
        self._loop = asyncio.get_running_loop()
        self._loop_thread = threading.get_ident()
        self._subscriptions: list[Subscription] = []
        self._queryables: list[Queryable] = []
        self._local: list[tuple[str, Subscription]] = []
        self._local_by_key: dict[str, list[Subscription]] = {}
        """Which local subscriptions each published key reaches; cleared on any change."""
        self._closed = False
        self._connection: Connection = transport.connect(loop=self._loop,
                                                         pending=self._has_pending)
        self._connect_watch: asyncio.Task[None] | None = None

    @classmethod
    async def open(cls, options: ConnectionOptions, *, clock: Clock | None = None,
                   ordered: bool = False) -> Bus:
        """Open a zenoh session (in a worker thread: opening can take a while) and a bus on it.

        ``ordered``: samples of every key are handed to the loop in the order the sending
        session sent them (:class:`~ubf_async.net.transport.ZenohConnection`): for the processes
        of a lockstep run.

        Listen endpoints on port 0 get a free port first (:func:`bind_free_ports`), so
        ``bus.options.listen`` names the ports really listened on. Raises
        :class:`SessionError` with a one-line message (:class:`PortInUseError` for a port
        taken, :class:`NoRobotError` when nothing answers a ``client``,
        :class:`RefusedError` when something there refuses it)."""
        options = dataclasses.replace(options, listen=bind_free_ports(options.listen))
        try:
            config = options.zenoh_config()
        except zenoh.ZError as exc:
            raise ConfigurationError(f"zenoh configuration: {zenoh_message(exc)}") from None
        try:
            session = await asyncio.to_thread(zenoh.open, config)
        except zenoh.ZError as exc:
            error = session_error(options, exc)
            if isinstance(error, NoRobotError):  # or something there refused us
                refused = await asyncio.to_thread(refused_error, options)
                raise (refused or error) from None
            raise error from None
        bus = cls(transport=ZenohTransport(session, ordered=ordered), options=options,
                  clock=clock)
        if options.mode == "peer" and options.connect:
            # A client fails to open when nothing answers; a peer opens all the same and
            # zenoh keeps trying in the background: say so, as a robot should.
            bus._connect_watch = asyncio.get_running_loop().create_task(
                watch_connect_endpoints(bus, options.connect), name="ubf-connect-watch")
        return bus

    @property
    def robot(self) -> str:
        return self.options.robot

    @property
    def session(self) -> zenoh.Session:
        """The zenoh session under a bus made by :meth:`open` (tests and tools reach around
        the bus with it); :class:`~ubf_async.errors.ConfigurationError` on another
        transport."""
        if isinstance(self._connection, ZenohConnection):
            return self._connection.session
        raise ConfigurationError(f"this bus runs on {type(self.transport).__name__}, not on a "
                                 f"zenoh session")

    def _has_pending(self) -> bool:
        """Whether a subscription holds undelivered samples or a queryable unanswered
        queries (what :meth:`InProcessTransport.settle` waits for)."""
        return (any(sub.pending for sub in self._subscriptions)
                or any(q.pending for q in self._queryables))

    def _bridge_callback(self, sub: Subscription) -> Callable[[str, bytes], None]:
        return sub.push_from_loop if self._connection.callbacks_on_loop else sub.push

    def publisher(self, topic: Topic[Any] | str, *parts: str, period_s: float | None = None,
                  **named_parts: str) -> Publisher:
        """A publisher of ``topic`` (:mod:`ubf_async.wire.topics`) on its key for this robot:
        ``bus.publisher(CAMERA, "front", period_s=0.11)``. For a schema not declared there,
        give the key and the schema name instead: ``bus.publisher(key, "my.schema")``."""
        if isinstance(topic, Topic):
            return Publisher(self, topic.key(self.keys, *parts, **named_parts), topic.schema,
                             period_s=period_s)
        if len(parts) != 1 or named_parts:
            raise TypeError("publisher(key, schema): give the key and one schema name")
        return Publisher(self, topic, parts[0], period_s=period_s)

    def raw_publisher(self, key: str) -> RawPublisher:
        """A publisher of payloads exactly as given (no encoding, no checks: a tool replaying
        recorded messages); subscribers of this bus receive them too."""
        return RawPublisher(self, key)

    def subscribe(
        self, key_expr: str, handler: SampleHandler, *, latest: bool = True,
        max_queue: int = 1024, direct: bool = False,
    ) -> Subscription:
        """Deliver samples matching ``key_expr`` to ``handler`` on the event loop.

        ``direct=True``: on a :class:`~ubf_async.runtime.lending.LendingEventLoop` (the one every
        entry point runs on), a sample from another process that finds the loop idle is
        handled at once on the transport's thread, with the loop lent to it, instead of
        waking the loop thread (:mod:`ubf_async.runtime.lending`); for short handlers on a latency
        path."""
        sub = Subscription(self._loop, handler, latest=latest, max_queue=max_queue,
                           name=key_expr, direct=direct)
        # Samples from this bus arrive through Publisher.publish instead (module docstring).
        sub._declaration = self._connection.declare_subscriber(key_expr,
                                                               self._bridge_callback(sub))
        sub._on_close = self._forget
        self._subscriptions.append(sub)
        self._local.append((key_expr, sub))
        self._local_by_key.clear()
        return sub

    def _forget(self, sub: Subscription) -> None:
        """Drop a closed subscription, so a bus that outlives many component restarts does
        not keep every subscription it ever made."""
        if sub in self._subscriptions:
            self._subscriptions.remove(sub)
        if any(s is sub for _, s in self._local):
            self._local = [(expr, s) for expr, s in self._local if s is not sub]
            self._local_by_key.clear()

    def _local_subscriptions(self, key: str) -> list[Subscription]:
        """The open subscriptions of this bus whose key expression matches ``key``."""
        subs = self._local_by_key.get(key)
        if subs is None:
            subs = [sub for sub_expr, sub in self._local if intersects(sub_expr, key)]
            self._local_by_key[key] = subs
        return subs

    def declare_token(self, key: str) -> Declaration:
        """A liveliness token on ``key``; ``token.undeclare()`` (or closing the bus) ends it."""
        return self._connection.declare_token(key)

    def watch_liveliness(
        self, key_expr: str, on_change: Callable[[str, bool], None]
    ) -> Subscription:
        """Call ``on_change(key, alive)`` on the loop for tokens appearing/vanishing,
        starting with those alive now."""

        def handler(key: str, payload: bytes, received_ns: int) -> None:
            on_change(key, payload == b"+")

        sub = Subscription(self._loop, handler, latest=False, name=f"liveliness {key_expr}")
        push = self._bridge_callback(sub)

        def on_token(key: str, alive: bool) -> None:
            # The token's kind travels in the payload slot of the generic bridge.
            push(key, b"+" if alive else b"-")

        sub._declaration = self._connection.declare_liveliness_subscriber(key_expr, on_token)
        sub._on_close = self._forget
        self._subscriptions.append(sub)
        return sub

    async def alive_tokens(self, key_expr: str, *, timeout_s: float = 2.0) -> list[str]:
        """Keys of the liveliness tokens currently alive under ``key_expr``."""
        return await self._connection.liveliness_get(key_expr, timeout_s=timeout_s)

    def declare_queryable(
        self, key: str, handler: QueryHandler, *, max_pending: int = 64
    ) -> Queryable:
        """Answer queries on ``key`` (a concrete key) with ``handler(key, payload) -> reply``,
        called on the event loop; queries from this bus are answered too."""
        queryable = Queryable(self._loop, key, handler, max_pending=max_pending,
                              callbacks_on_loop=self._connection.callbacks_on_loop)
        queryable._declaration = self._connection.declare_queryable(key, queryable.on_query)
        queryable._on_close = self._queryables.remove
        self._queryables.append(queryable)
        return queryable

    async def query(
        self, key: str, payload: bytes | None = None, *, timeout_s: float = 5.0
    ) -> bytes:
        """Send one query on ``key`` and return the first reply's payload.

        Raises :class:`TimeoutError` when nothing answered within ``timeout_s`` (at once when
        no queryable matching ``key`` is known), :class:`QueryError` when the queryable
        answered with an error. The loop is never blocked (zenoh's query runs in a worker
        thread), so a queryable on this same loop can answer it."""
        answer, errors = await self._connection.get(key, payload, timeout_s=timeout_s)
        if answer is not None:
            return answer
        if errors:
            raise QueryError("; ".join(errors))
        raise TimeoutError(f"nothing answered a query on {key} within {timeout_s:g}s")

    def reached_peers(self) -> bool:
        """Whether the transport reaches another node now (see :func:`wait_for_robot`)."""
        return self._connection.reached_peers()

    async def aclose(self) -> None:
        """Undeclare everything and close the connection (the zenoh session); idempotent."""
        if self._closed:
            return
        self._closed = True
        if self._connect_watch is not None:
            self._connect_watch.cancel()
        for sub in list(self._subscriptions):
            sub.close()
        for queryable in list(self._queryables):
            queryable.close()
        await self._connection.close()

    async def __aenter__(self) -> Bus:
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.aclose()


def follow_sim_clock(
    bus: Bus, clock: SimClock, malformed: dict[str, int], *,
    follower: ClockFollower | None = None,
) -> Subscription:
    """Drive ``clock`` from the simulator's samples on ``ubf/<robot>/clock``.

    Malformed samples are counted in ``malformed``. What a valid sample may do is decided by
    ``follower`` (a new :class:`~ubf_async.runtime.timesource.ClockFollower` if not given — pass one
    to pin an epoch or to read its counters): advance the clock, reset it to a new run's time,
    or nothing (refused, counted and logged by the follower). The first sample taken resets
    the clock (``clock.resets``) if nothing had started it yet.
    """
    key = CLOCK.key(bus.keys)
    policy = follower if follower is not None else ClockFollower(name=f"{bus.robot} clock")

    def on_sample(key: str, payload: bytes, received_ns: int) -> None:
        message = decode_or_count(payload, malformed, key, topic=CLOCK)
        if message is None:
            return
        verdict = policy.offer(stamp_ns=message.stamp_ns, epoch=message.data.epoch,
                               wall_ns=received_ns)
        if verdict.action is ClockAction.ADVANCE and clock.started.is_set():
            clock.advance_to(message.stamp_ns)
        elif verdict.action is ClockAction.ADVANCE:
            # The first time heard starts this process's time, as a new run does: joining a
            # run (or a replay) mid-way is not seconds of missed ticks since 0.
            clock.reset_to(message.stamp_ns)
        elif verdict.action is ClockAction.RESET:
            clock.reset_to(message.stamp_ns)

    # Direct, as the state aggregator's samples are: on an ordered bus the clock is then
    # handled in the order it was sent among them, not after samples sent later.
    return bus.subscribe(key, on_sample, direct=True)


def decode_or_count(
    payload: bytes, counter: dict[str, int], key: str, *, schema: str | None = None,
    topic: Topic[Any] | None = None, decoder: Callable[[bytes], Any] | None = None,
    on_error: Callable[[ProtocolError], None] | None = None,
) -> Any | None:
    """Decode ``payload`` (requiring ``schema`` if given, or with a custom ``decoder``); on
    :class:`ProtocolError` count it under ``key``, log it (the first and then every 100th
    per key), pass it to ``on_error`` if given, and return ``None``. ``counter`` keeps at most
    :data:`MAX_COUNTED_KEYS` keys, so junk keys cannot grow it without bound."""
    try:
        if decoder is not None:
            return decoder(payload)
        return decode(payload, topic=topic) if topic is not None else decode(payload,
                                                                             schema=schema)
    except ProtocolError as exc:
        n = counter.get(key, 0) + 1
        counter[key] = n
        if len(counter) > MAX_COUNTED_KEYS:
            del counter[next(iter(counter))]
        if throttle.first_and_every(n):
            log.warning("rejected malformed sample #%d on %s: %s", n, key, exc)
        if on_error is not None:
            on_error(exc)
        return None
