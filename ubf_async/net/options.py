"""How a process joins the zenoh network: connection options, the zenoh configuration they
make, and what tells in one line why a session did not open (the session errors themselves
are in :mod:`ubf_async.errors`).

:class:`ConnectionOptions` is what every entry point's connection flags
(:mod:`ubf_async.cli.args`) come to; :meth:`ConnectionOptions.zenoh_config` is the zenoh
configuration a session opens with (:meth:`ubf_async.net.transport.ZenohTransport.open`),
secure mode applied (:mod:`ubf_async.net.secure`).
"""

from __future__ import annotations

import argparse
import json
import re
import socket
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import zenoh

from ubf_async.errors import (
    ConfigurationError,
    NoRobotError,
    PortInUseError,
    RefusedError,
    SessionError,
)

__all__ = ["DEFAULT_LISTEN", "DEFAULT_ROBOT", "INGRESS_LIMIT_BYTES", "MAX_MESSAGE_BYTES",
           "RECONNECT_RETRY", "SESSION_LIMITS", "START_ROBOT_HINT", "ConnectionOptions",
           "bind_free_ports", "config_endpoints", "config_value", "endpoint_locators", "listening",
           "load_zenoh_config", "over_tls", "refused_error", "session_error", "zenoh_message"]

DEFAULT_ROBOT = "mini"
DEFAULT_LISTEN = "tcp/127.0.0.1:7447"

INGRESS_LIMIT_BYTES = 256 * 1024 + 1024
"""The largest message on ``ubf/**`` a session takes in (zenoh's ``low_pass_filter``): the
protocol's ``MAX_PAYLOAD_BYTES`` (256 KiB, :mod:`ubf_async.wire.protocol`) and 1 KiB for an
attachment. The protocol refuses anything larger; zenoh drops it before it costs a copy."""
MAX_MESSAGE_BYTES = 1 << 20
"""The largest message a link reassembles, on any key (zenoh's default is 1 GiB a link)."""

SESSION_LIMITS: dict[str, Any] = {
    # zenoh's implicit shared-memory optimisation maps each same-host peer's 16 MiB pool into
    # the receiver for messages of 3 KiB and more — and keeps it mapped after the peer
    # leaves: ≈ 19 MiB of RSS kept per visiting session (docs/resources.md). It also lets a
    # message past max_message_size. ubf_async's messages are small: the copy costs little.
    "transport/shared_memory/enabled": False,
    "transport/link/rx/max_message_size": MAX_MESSAGE_BYTES,
    "low_pass_filter": [{
        "id": "ubf-max-payload",
        "flows": ["ingress"],
        "messages": ["put", "delete", "query", "reply"],
        # The one key this room spells out: every session of every process sets it, from
        # defaults no layer above hands down; tests/test_access.py holds it to the wire's own
        # (ubf_async.wire.keys.EVERY_ROBOT).
        "key_exprs": ["ubf/**"],
        "size_limit": INGRESS_LIMIT_BYTES,
    }],
}
"""What every session of ubf_async sets over zenoh's defaults, to bound what others can make
it hold; a ``--config`` file that sets one of these keys keeps its own value."""


def over_tls(endpoint: str) -> str:
    """``endpoint`` over TLS, as a default endpoint is in secure mode: ``tcp/X`` as ``tls/X``,
    any other as it is."""
    return f"tls/{endpoint.removeprefix('tcp/')}" if endpoint.startswith("tcp/") else endpoint


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
        """The zenoh configuration: zenoh's defaults with :data:`SESSION_LIMITS`, the ``config``
        file, then these options over it; in secure mode the identity's credentials (and for
        ``robot`` the password dictionary and the ACL), and client mode for every identity
        but ``robot`` (see :mod:`ubf_async.net.secure`).
        Raises :class:`~ubf_async.errors.ConfigurationError` for a bad secure set-up, and for
        an endpoint or value zenoh refuses (``zenoh configuration: ...``)."""
        try:
            return self._zenoh_config()
        except zenoh.ZError as exc:
            raise ConfigurationError(f"zenoh configuration: {zenoh_message(exc)}") from None

    def _zenoh_config(self) -> zenoh.Config:
        conf = zenoh.Config.from_file(str(self.config)) if self.config else zenoh.Config()
        for key, value in SESSION_LIMITS.items():
            if self.config is None or config_value(conf, key) is None:
                conf.insert_json5(key, json.dumps(value))
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
            from ubf_async.net import secure  # only secure mode needs it

            secure.apply(conf, directory=self.secure, identity=self.identity, robot=self.robot,
                         listen=self.listen, connect=self.connect)
        elif self.identity is not None:
            raise ConfigurationError(f"--identity {self.identity} needs --secure DIR")
        return conf


def load_zenoh_config(path: Path) -> zenoh.Config:
    """Read a zenoh JSON5 configuration file; :class:`ConfigurationError` if it cannot be."""
    if not path.is_file():
        raise ConfigurationError(f"--config {path}: no such file")
    try:
        return zenoh.Config.from_file(str(path))
    except zenoh.ZError as exc:
        raise ConfigurationError(f"--config {path}: {zenoh_message(exc)}") from None


def config_value(conf: zenoh.Config | None, key: str) -> Any:
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


def config_endpoints(conf: zenoh.Config | None, section: str, mode: str) -> list[str] | None:
    """``<section>/endpoints`` set by a configuration file (a list, or one list per mode:
    this ``mode``'s); ``None`` if the file sets none."""
    value = config_value(conf, f"{section}/endpoints")
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
    """For a session that reached nothing: a :class:`RefusedError` saying why if something
    listens at one of its ``connect`` endpoints (:func:`listening`) — over TLS, which
    certificate or name was refused and what to run (:func:`ubf_async.net.secure.diagnose`)
    — else ``None``. Blocking: run it in a thread."""
    from ubf_async.net.secure import diagnose

    open_at = [e for e in options.connect if listening(e, timeout_s=timeout_s)]
    if not open_at:
        return None
    for endpoint in open_at:
        reason = diagnose(endpoint, directory=options.secure, identity=options.identity)
        if reason is not None:
            return RefusedError(reason)
    if options.secure is None:
        credentials = ("this process gave none: pass the robot's set-up with --secure DIR "
                       "--identity NAME")
    else:
        credentials = (f"this process gave identity {options.identity!r} of {options.secure}, "
                       f"which the robot's set-up does not have with that password (another "
                       f"set-up, or one made again with `python -m ubf_async.secure init "
                       f"--force`)")
    return RefusedError(
        f"the robot at {' '.join(open_at)} refused the connection: something listens there but "
        f"did not let this process's zenoh session in, as a robot in secure mode does without "
        f"valid credentials (docs/security.md); {credentials}")


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
