"""Secure mode: who may say what on a robot's zenoh network, over mutual TLS, with zenoh's own
mechanisms.

The mechanism (set-up files, :func:`apply`, :class:`Rights`, :func:`diagnose`); the policy —
which identities a robot file has and what each may do — is :mod:`ubf_async.access` (a room
above this one: it builds the rules from the wire's keys, which a transport does not know, and
hands them here as :class:`Grant` data); the command line is :mod:`ubf_async.tools.secure`.
Split so the connection options (:mod:`ubf_async.net.options`) can apply a set-up without
importing either.

``python -m ubf_async.secure init DIR --robot-file FILE [--host NAME_OR_IP ...]`` generates,
for the robot the file describes:

* a **certificate authority** (``DIR/ca.pem``; its key ``DIR/private/ca.key`` never leaves
  the set-up's host);
* one **identity** per process that may join — ``robot`` (the launch process: controller,
  simulator and devices in one session), one per configured remote behaviour (the name of
  each ``remote:`` slot), ``inspector`` (read-only), ``operator`` (read, and the tree service),
  with a ``ros2:`` section the ROS 2 identities and, with ``--device KIND/NAME``,
  ``device-KIND-NAME`` — each with a **certificate** whose common name is the identity
  (the robot's also carries the ``--host`` names its clients dial) and a random
  **password** (zenoh ``transport/auth/usrpwd``: a second factor);
* the robot's **access control** (zenoh ``access_control``, default deny; subjects matched on
  the certificate's common name *and* the username): what each identity may put, declare and
  query on the robot's keys (the grants of :mod:`ubf_async.access.policy`, turned into zenoh's
  section by :func:`zenoh_access_control`).

Every process then passes ``--secure DIR --identity NAME`` (the shared connection flags) and
``tls/`` endpoints: :func:`apply` sets zenoh's TLS link (mutual TLS, the robot's name checked
against the name dialled) and the identity's credentials; the ``robot`` identity also gets the
password dictionary its listener checks and the ACL its session enforces. Other identities
connect in **client** mode, so all their traffic crosses the robot's session — zenoh applies
ACL rules only on the node that holds them, and a denied message is dropped there without any
error to the sender; so :class:`Rights` refuses, in this process and before anything is sent,
what the identity's rules do not allow. ``docs/security.md`` has the threat model, the set-up
and the limits.

Files: ``DIR/secure.json`` (what was generated, for whom), ``DIR/ca.pem``,
``DIR/private/ca.key``, ``DIR/passwords.txt`` and ``DIR/acl.json`` (the robot's side),
``DIR/identities/NAME.{json,pem,key}`` (one set per identity). ``secure export NAME`` packs
what one host needs. Secret files are 0600, folders 0700.
"""

from __future__ import annotations

import io
import json
import os
import secrets
import stat
import tarfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import zenoh

from ubf_async.errors import ConfigurationError, NotAllowedError
from ubf_async.net import tlsprobe

if TYPE_CHECKING:
    from ubf_async.net import pki

__all__ = ["ACL", "ALL_MESSAGES", "BUILTIN", "CA_CERT", "CA_KEY", "DEFAULT_HOSTS", "FLEET_BUILTIN",
           "FORMAT", "IDENTITIES", "INIT_HINT", "INSPECTOR", "LISTENERS", "MANIFEST", "OPEN",
           "OPERATOR", "PASSWORDS", "PRIVATE", "READ_MESSAGES", "REISSUE", "ROBOT",
           "ROS2_IDENTITIES", "WATCHED", "Grant", "Identity", "IdentityRights", "Rights", "Rule",
           "SecureSetup", "apply", "changes", "create", "diagnose", "export", "fingerprint",
           "identity_file", "override", "passwords_of", "revoke", "rotate", "settings",
           "zenoh_access_control"]

FORMAT = 2
ROBOT = "robot"
INSPECTOR = "inspector"
OPERATOR = "operator"
BUILTIN = (ROBOT, INSPECTOR, OPERATOR)
ROUTER, WORLD, FLEET = "router", "world", "fleet"
FLEET_BUILTIN = (ROUTER, WORLD, FLEET, INSPECTOR, OPERATOR)
"""A fleet's set-up (``init --fleet-file``): its router, its world, the launcher's own
session, and one identity per robot, named as the robot (role ``member``)."""
ROS2_BRIDGE, ROS2_READER, ROS2_DRIVER = "ros2-bridge", "ros2-reader", "ros2-driver"
ROS2_IDENTITIES = (ROS2_BRIDGE, ROS2_READER, ROS2_DRIVER)
"""With a robot file's ``ros2:`` section (docs/ros2.md)."""
MANIFEST = "secure.json"
PASSWORDS = "passwords.txt"
ACL = "acl.json"
IDENTITIES = "identities"

ALL_MESSAGES = ("put", "delete", "declare_subscriber", "query", "reply", "declare_queryable",
                "liveliness_token", "liveliness_query", "declare_liveliness_subscriber")
READ_MESSAGES = ("declare_subscriber", "declare_liveliness_subscriber", "liveliness_query")


@dataclass(frozen=True, slots=True, kw_only=True)
class Identity:
    """One process's name on the robot's network (its zenoh username) and what it is."""

    name: str
    role: str
    """``robot``, ``remote``, ``inspector``, ``operator`` or ``device``."""
    composites: tuple[str, ...] = ()
    """A remote behaviour: the composites it has a slot in (where it may vote)."""
    device: tuple[str, str] | None = None
    """A device: ``(kind, name)``."""
    simulated: bool = False
    """A device whose backend drives the simulator (it may put ``sim/pulses``)."""
    publishes: tuple[str, ...] = ()
    """A device: the topics (by name) its component publishes for its own name besides its
    ``sensor/<kind>/<name>`` (the camera's view, the encoders' odometry)."""
    ros2: tuple[int, str] | None = None
    """A ROS 2 identity (``ros2-bridge``, ``ros2-reader``, ``ros2-driver``): the robot file's
    ROS domain id and namespace (docs/ros2.md)."""

    def as_data(self) -> dict[str, Any]:
        data: dict[str, Any] = {"name": self.name, "role": self.role}
        if self.composites:
            data["composites"] = list(self.composites)
        if self.device is not None:
            data["device"] = list(self.device)
            data["simulated"] = self.simulated
            if self.publishes:
                data["publishes"] = list(self.publishes)
        if self.ros2 is not None:
            data["ros2"] = list(self.ros2)
        return data

    @classmethod
    def of_data(cls, data: Mapping[str, Any]) -> Identity:
        device, ros2 = data.get("device"), data.get("ros2")
        return cls(name=str(data["name"]), role=str(data["role"]),
                   composites=tuple(data.get("composites", ())),
                   device=(str(device[0]), str(device[1])) if device else None,
                   simulated=bool(data.get("simulated", False)),
                   publishes=tuple(str(t) for t in data.get("publishes", ())),
                   ros2=(int(ros2[0]), str(ros2[1])) if ros2 else None)


# ---------------------------------------------------------------------------------------------
# The access control, as data from the policy and as zenoh's section


@dataclass(frozen=True, slots=True)
class Rule:
    """``messages`` (of :data:`ALL_MESSAGES`) allowed on ``key_exprs`` in one ``flow``:
    ``ingress`` (what a process sends into the session) or ``egress`` (what the session sends
    it)."""

    id: str
    messages: tuple[str, ...]
    key_exprs: tuple[str, ...]
    flow: str = "ingress"


@dataclass(frozen=True, slots=True)
class Grant:
    """``rules`` for the identities named in ``subjects``: one entry of a set-up's access
    control, as :mod:`ubf_async.access.policy` decides it (this room knows no key of its
    own)."""

    id: str
    rules: tuple[Rule, ...]
    subjects: tuple[str, ...]


def zenoh_access_control(grants: Sequence[Grant], identities: Sequence[Identity]
                         ) -> dict[str, Any]:
    """zenoh's ``access_control`` section for ``grants``: default deny, one subject per
    identity, the rules in the order the grants bring them. What ``acl.json`` holds and the
    robot's session enforces."""
    # A grant left to no one (its identities revoked) gives nothing, and zenoh refuses a
    # policy without subjects: the robot would not start.
    grants = [grant for grant in grants if grant.subjects]
    rules = dict.fromkeys(rule for grant in grants for rule in grant.rules)
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": [{"id": r.id, "messages": list(r.messages), "flows": [r.flow],
                   "permission": "allow", "key_exprs": list(r.key_exprs)} for r in rules],
        # Both must match: the certificate's common name (mTLS) and the username (the
        # identity's password, a second factor).
        "subjects": [{"id": _subject_id(i.name), "cert_common_names": [i.name],
                      "usernames": [i.name]} for i in identities],
        "policies": [{"id": g.id, "rules": [r.id for r in g.rules],
                      "subjects": [_subject_id(name) for name in g.subjects]} for g in grants],
    }


def _subject_id(name: str) -> str:
    return f"user-{name}"


# ---------------------------------------------------------------------------------------------
# Generating and loading a secure set-up

CA_CERT = "ca.pem"
PRIVATE = "private"
CA_KEY = "ca.key"
LISTENERS = (ROBOT, ROUTER)
"""Identities that listen (their certificates carry the ``--host`` names) and hold the
access control: the robot, a fleet's router."""
DEFAULT_HOSTS = ("localhost", "127.0.0.1")
"""The robot's names when ``init`` is given no ``--host``: this host only."""
INIT_HINT = "python -m ubf_async.secure init {dir} --robot-file FILE --host NAME_OR_IP"


@dataclass(slots=True, kw_only=True)
class SecureSetup:
    """A generated set-up directory (see the module docstring), or a host's export of it."""

    directory: Path
    robot: str
    identities: dict[str, Identity] = field(default_factory=dict)
    source: str = ""
    hosts: tuple[str, ...] = DEFAULT_HOSTS
    """The names and addresses the robot's (or the router's) certificate carries."""
    revoked: tuple[str, ...] = ()
    fleet: tuple[str, ...] = ()
    """A fleet's set-up: its robots (``robot`` is then the fleet file's name)."""

    @classmethod
    def load(cls, directory: Path) -> SecureSetup:
        """Read ``DIR/secure.json``. Raises :class:`ConfigurationError`."""
        if not (directory / MANIFEST).is_file():
            raise ConfigurationError(
                f"--secure {directory}: no secure set-up there (no {MANIFEST}): make one with "
                f"`{INIT_HINT.format(dir=directory)}`, or unpack this host's "
                f"`python -m ubf_async.secure export NAME` into it")
        data = _read_json(directory / MANIFEST, what="the secure set-up")
        if data.get("format") != FORMAT:
            raise ConfigurationError(
                f"{directory / MANIFEST}: a set-up of format {data.get('format')!r}, this "
                f"version needs {FORMAT} (certificates for TLS): make it again with "
                f"`{INIT_HINT.format(dir=directory)} --force`")
        try:
            identities = [Identity.of_data(i) for i in data["identities"]]
            return cls(directory=directory, robot=str(data["robot"]),
                       identities={i.name: i for i in identities},
                       source=str(data.get("source", "")),
                       hosts=tuple(str(h) for h in data.get("hosts", DEFAULT_HOSTS)),
                       revoked=tuple(str(r) for r in data.get("revoked", ())),
                       fleet=tuple(str(r) for r in data.get("fleet", ())))
        except (KeyError, TypeError, IndexError, ValueError) as exc:
            raise ConfigurationError(f"{directory / MANIFEST}: malformed ({exc})") from None

    def identity_file(self, name: str, suffix: str = ".json") -> Path:
        return identity_file(self.directory, name, suffix)

    def check_robot(self, identity: Identity, robot: str) -> None:
        """:class:`ConfigurationError` unless ``identity`` may run as robot ``robot``
        (``--robot``)."""
        if self.fleet:
            ok = robot == identity.name if identity.role == "member" else (
                identity.role == ROUTER or robot in self.fleet)
            where = (f"the fleet's robot {identity.name!r}" if identity.role == "member"
                     else f"the fleet of {', '.join(self.fleet)}")
        else:
            ok, where = robot == self.robot, f"robot {self.robot!r}"
        if not ok:
            raise ConfigurationError(f"identity {identity.name!r} of {self.directory} is for "
                                     f"{where}, not {robot!r} (--robot)")

    def identity(self, name: str) -> Identity:
        """Identity ``name``; :class:`ConfigurationError` saying what to do if it has none."""
        if name in self.revoked:
            raise ConfigurationError(
                f"identity {name!r} was revoked from the set-up in {self.directory}: the robot "
                f"lets it in no more (`python -m ubf_async.secure show {self.directory}` lists "
                f"the others)")
        if name not in self.identities:
            raise ConfigurationError(
                f"--identity {name}: the set-up in {self.directory} has no such identity (its "
                f"identities: {', '.join(self.identities)})")
        return self.identities[name]

    def save(self) -> None:
        """Write ``DIR/secure.json`` (the access control is :meth:`save_access_control`'s)."""
        _write_secret(self.directory / MANIFEST, json.dumps({
            "format": FORMAT, "robot": self.robot, "source": self.source,
            "hosts": list(self.hosts), "revoked": list(self.revoked), "fleet": list(self.fleet),
            "identities": [i.as_data() for i in self.identities.values()],
        }, indent=2) + "\n")

    def save_access_control(self, grants: Sequence[Grant]) -> None:
        """Write ``DIR/acl.json``: ``grants`` (for this set-up's identities) as zenoh's section,
        what the robot (a fleet's router) loads when it starts."""
        _write_secret(self.directory / ACL, json.dumps(
            {"robot": self.robot,
             "access_control": zenoh_access_control(grants, list(self.identities.values()))},
            indent=2) + "\n")


def identity_file(directory: Path, name: str, suffix: str = ".json") -> Path:
    """Where identity ``name``'s credentials (``.json``), certificate (``.pem``) and private
    key (``.key``) live in a set-up directory."""
    return directory / IDENTITIES / f"{name}{suffix}"


def create(directory: Path, robot: str, identities: Sequence[Identity], *,
           grants: Sequence[Grant], source: str, hosts: Sequence[str] = (),
           fleet: tuple[str, ...] = (), force: bool = False,
           days: int | None = None) -> SecureSetup:
    """Generate a set-up into ``directory``: a certificate authority, ``identities`` (each its
    certificate, key and password) and the access control ``grants`` give them (made by
    :mod:`ubf_async.access.setup`, whose ``init`` is what to call); ``robot``: the robot's
    name (a fleet's: the fleet file's, and ``fleet`` its robots); ``hosts``: the listener's
    host names and addresses (default :data:`DEFAULT_HOSTS`). An existing set-up is kept
    unless ``force`` (a new CA: every process then needs its new files). Raises
    :class:`ConfigurationError`."""
    from ubf_async.net import pki  # (cryptography: imported where certificates are made)

    setup = SecureSetup(directory=directory, robot=robot,
                        identities={i.name: i for i in identities}, source=source,
                        hosts=tuple(pki.check_host(h) for h in hosts) or DEFAULT_HOSTS,
                        fleet=fleet)
    if (directory / MANIFEST).exists() and not force:
        raise ConfigurationError(f"{directory} already holds a secure set-up (--force makes "
                                 "a new CA and new credentials for every identity)")
    try:
        for folder in (directory, directory / IDENTITIES, directory / PRIVATE):
            folder.mkdir(parents=True, exist_ok=True)
            os.chmod(folder, 0o700)
        for old in (directory / IDENTITIES).iterdir():
            old.unlink()  # --force: nothing of the old set-up's identities stays
        # A name of its own: two set-ups' CAs never pass for each other by name.
        ca = pki.make_ca(f"ubf {setup.robot} CA {secrets.token_hex(4)}")
        pki.write_private(directory / PRIVATE / CA_KEY, ca.key_pem)
        _write_secret(directory / CA_CERT, ca.cert_pem.decode())
        _write_passwords(setup, {name: _issue(setup, ca, name, days=days)
                                 for name in setup.identities})
        setup.save()
        setup.save_access_control(grants)
    except OSError as exc:
        raise ConfigurationError(f"cannot write the secure set-up into {directory}: {exc}") \
            from None
    return setup


def _issue(setup: SecureSetup, ca: pki.Issued, name: str, *, days: int | None) -> str:
    """Write identity ``name``'s certificate, key and credentials (a new password), valid for
    ``days`` (``None``: :data:`~ubf_async.net.pki.IDENTITY_DAYS`); return the password."""
    from ubf_async.net import pki

    if days is None:
        days = pki.IDENTITY_DAYS
    password = secrets.token_urlsafe(24)
    issued = pki.issue(ca, name, hosts=setup.hosts if name in LISTENERS else (), days=days)
    _write_secret(setup.identity_file(name, ".pem"), issued.cert_pem.decode())
    pki.write_private(setup.identity_file(name, ".key"), issued.key_pem)
    _write_secret(setup.identity_file(name), json.dumps({
        "format": FORMAT, "robot": setup.robot, "identity": name, "user": name,
        "password": password}, indent=2) + "\n")
    return password


def _the_ca(setup: SecureSetup) -> pki.Issued:
    from ubf_async.net import pki

    key = setup.directory / PRIVATE / CA_KEY
    if not key.is_file():
        raise ConfigurationError(
            f"{key}: no such file: the CA's private key is only on the host where the set-up "
            f"was made (`secure init`); rotate and revoke there")
    return pki.Issued(key.read_bytes(), (setup.directory / CA_CERT).read_bytes())


def _passwords(setup: SecureSetup) -> dict[str, str]:
    lines = (setup.directory / PASSWORDS).read_text().splitlines()
    return dict(line.split(":", 1) for line in lines if ":" in line)


def _write_passwords(setup: SecureSetup, passwords: Mapping[str, str]) -> None:
    _write_secret(setup.directory / PASSWORDS,
                  "".join(f"{name}:{pw}\n" for name, pw in passwords.items()))


def rotate(directory: Path, name: str, *, hosts: Sequence[str] = (),
           days: int | None = None) -> SecureSetup:
    """Issue identity ``name`` a new key, certificate and password, leaving every other
    identity as it is (and the access control: the identities are the same); for a listener
    ``hosts`` replace the names its certificate carries. The robot reads its password
    dictionary when its session opens: a running robot re-opens it when the files change
    (:class:`ubf_async.services.setupwatch.SetupWatch`). Raises :class:`ConfigurationError`."""
    from ubf_async.net import pki

    setup = SecureSetup.load(directory)
    setup.identity(name)
    ca = _the_ca(setup)
    if hosts:
        if name not in LISTENERS:
            raise ConfigurationError(f"--host: identity {name!r} does not listen; only "
                                     f"{', '.join(LISTENERS)} carries host names")
        setup.hosts = tuple(pki.check_host(h) for h in hosts)
    passwords = _passwords(setup)
    passwords[name] = _issue(setup, ca, name, days=days)
    _write_passwords(setup, passwords)
    setup.save()
    return setup


def revoke(directory: Path, name: str, *, grants: Sequence[Grant]) -> SecureSetup:
    """Remove identity ``name``: from the ACL (now ``grants``, those of the identities left:
    :func:`ubf_async.access.setup.revoke` makes them, and is what to call), from the password
    dictionary (so the robot refuses its session even with its still-valid certificate), and
    its files. The robot reads both when its session opens: a running robot re-opens it when
    the files change (:class:`ubf_async.services.setupwatch.SetupWatch`). Raises
    :class:`ConfigurationError`."""
    setup = SecureSetup.load(directory)
    setup.identity(name)
    if name == ROBOT:
        raise ConfigurationError("the robot's own identity cannot be revoked: rotate it "
                                 "(`secure rotate robot`), or make a new set-up")
    del setup.identities[name]
    setup.revoked = (*setup.revoked, name)
    passwords = _passwords(setup)
    passwords.pop(name, None)
    _write_passwords(setup, passwords)
    setup.save()
    setup.save_access_control(grants)
    for suffix in (".json", ".pem", ".key"):
        setup.identity_file(name, suffix).unlink(missing_ok=True)
    return setup


WATCHED = (MANIFEST, PASSWORDS, ACL, CA_CERT)
"""The set-up's files a running robot reads again when they change (with its own identity's):
what ``rotate`` and ``revoke`` write."""


def fingerprint(directory: Path, identity: str = ROBOT) -> bytes:
    """What the robot's session is opened from, as bytes that change when any of it changes
    (:data:`WATCHED`, and ``identity``'s certificate and key): a robot compares it to know
    when to re-open its session (``launch`` in secure mode, docs/security.md)."""
    parts = []
    for path in [*(directory / name for name in WATCHED),
                 *(directory / IDENTITIES / f"{identity}{suffix}" for suffix in (".pem", ".key"))]:
        try:
            parts.append(path.read_bytes())
        except OSError:  # gone (mid-rewrite): changed
            parts.append(b"\0missing")
    return b"\0\0".join(parts)


def changes(before: Mapping[str, str], after: Mapping[str, str]) -> str:
    """What happened between two password dictionaries (:func:`passwords_of`), in a user's
    words: ``revoked avoid_obstacles; rotated teleop``."""
    revoked = sorted(set(before) - set(after))
    rotated = sorted(n for n in set(before) & set(after) if before[n] != after[n])
    added = sorted(set(after) - set(before))
    said = [f"{what} {', '.join(names)}" for what, names in
            (("revoked", revoked), ("rotated", rotated), ("added", added)) if names]
    return "; ".join(said) or "the files changed"


def passwords_of(directory: Path) -> dict[str, str]:
    """The set-up's password dictionary (identity → password); empty where it cannot be read."""
    try:
        return _passwords(SecureSetup(directory=directory, robot=""))
    except OSError:
        return {}


def export(directory: Path, names: Sequence[str], output: Path) -> list[str]:
    """Pack into ``output`` (a ``.tar.gz``) exactly what a host running ``names`` needs: the
    set-up's description and CA certificate, those identities' certificates, keys and
    credentials, and for the robot its password dictionary and ACL — never the CA's key.
    Returns the packed paths. Raises :class:`ConfigurationError`."""
    setup = SecureSetup.load(directory)
    members = [MANIFEST, CA_CERT]
    for name in names:
        setup.identity(name)
        members += [f"{IDENTITIES}/{name}{suffix}" for suffix in (".json", ".pem", ".key")]
        if name in LISTENERS:
            members += [PASSWORDS, ACL]
    try:
        with tarfile.open(output, "w:gz") as tar:
            folder = tarfile.TarInfo(IDENTITIES)
            folder.type, folder.mode = tarfile.DIRTYPE, 0o700
            tar.addfile(folder)
            for member in dict.fromkeys(members):
                data = (directory / member).read_bytes()
                info = tarfile.TarInfo(member)
                info.size, info.mode = len(data), 0o600
                tar.addfile(info, io.BytesIO(data))
        os.chmod(output, 0o600)
    except OSError as exc:
        raise ConfigurationError(f"cannot write {output}: {exc}") from None
    return members


def _write_secret(path: Path, text: str) -> None:
    from ubf_async.net import pki

    pki.write_private(path, text.encode())


def _private(path: Path) -> None:
    if path.stat().st_mode & (stat.S_IRWXG | stat.S_IRWXO):
        raise ConfigurationError(f"{path}: readable by others (chmod 600 {path})")


def _read_json(path: Path, *, what: str, secret: bool = False) -> dict[str, Any]:
    try:
        if secret:
            _private(path)
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise ConfigurationError(f"{path}: no such file: {what}") from None
    except (OSError, ValueError) as exc:
        raise ConfigurationError(f"{path}: cannot read {what}: {exc}") from None
    if not isinstance(data, dict):
        raise ConfigurationError(f"{path}: not a JSON object")
    return data


# ---------------------------------------------------------------------------------------------
# Applying a set-up to a zenoh configuration


def _tls_only(endpoints: Sequence[str], flag: str) -> None:
    plain = [e for e in endpoints if not e.startswith("tls/")]
    if plain:
        suggestion = " ".join("tls/" + e.split("/", 1)[-1] for e in plain)
        raise ConfigurationError(
            f"{flag} {' '.join(plain)}: secure mode speaks TLS only (nothing in clear on the "
            f"network): use {suggestion}")


def settings(*, directory: Path, identity: str | None, robot: str,
             listen: Sequence[str] = (), connect: Sequence[str] = ()) -> dict[str, Any]:
    """The zenoh configuration keys (path → value) that put identity ``identity`` of set-up
    ``directory`` in secure mode: its TLS link (mutual TLS, the robot's name checked against
    the endpoint dialled), its credentials; for ``robot`` also its listening certificate, the
    password dictionary and the ACL; client mode for any other identity, which may not listen.
    Every endpoint must be ``tls/``. What :func:`apply` sets, and what a ROS 2 node's
    ``ZENOH_CONFIG_OVERRIDE`` carries (:func:`override`). Raises :class:`ConfigurationError`."""
    from ubf_async.net import pki

    if not identity:
        raise ConfigurationError(f"--secure {directory} needs --identity NAME (the file names "
                                 f"in {directory / IDENTITIES})")
    setup = SecureSetup.load(directory)
    setup.check_robot(setup.identity(identity), robot)
    if not identity_file(directory, identity).exists():
        present = sorted(p.stem for p in (directory / IDENTITIES).glob("*.json"))
        raise ConfigurationError(
            f"--identity {identity}: {identity_file(directory, identity)}: no such file: this "
            f"host has the files of {', '.join(present) if present else 'no identity'} only; "
            f"on the set-up's host, `python -m ubf_async.secure export DIR {identity}` packs "
            f"{identity}'s for this one (docs/security.md)")
    creds = _read_json(identity_file(directory, identity), secret=True,
                       what=f"the credentials of identity {identity!r}")
    user, password = creds.get("user"), creds.get("password")
    if not isinstance(user, str) or not isinstance(password, str):
        raise ConfigurationError(f"{identity_file(directory, identity)}: no user/password")
    cert, key = identity_file(directory, identity, ".pem"), identity_file(directory, identity,
                                                                          ".key")
    if key.exists():
        _private(key)
    problem = pki.own_certificate_problem(cert_path=cert, key_path=key,
                                          ca_path=directory / CA_CERT, identity=identity)
    if problem is not None:
        raise ConfigurationError(f"{problem}: {REISSUE.format(name=identity)}")
    _tls_only(listen, "--listen")
    _tls_only(connect, "--connect")
    tls = "transport/link/tls"
    out: dict[str, Any] = {
        f"{tls}/root_ca_certificate": str(directory.resolve() / CA_CERT),
        f"{tls}/enable_mtls": True, f"{tls}/verify_name_on_connect": True,
        f"{tls}/close_link_on_expiration": True,
        f"{tls}/connect_certificate": str(cert.resolve()),
        f"{tls}/connect_private_key": str(key.resolve()),
        "transport/auth/usrpwd/user": user, "transport/auth/usrpwd/password": password,
    }
    if identity not in LISTENERS:
        if listen:
            raise ConfigurationError(f"identity {identity!r} may not --listen in secure mode: "
                                     "only the robot (a fleet's router) listens, the others "
                                     "connect to it")
        return out | {"mode": "client"}
    out |= {f"{tls}/listen_certificate": str(cert.resolve()),
            f"{tls}/listen_private_key": str(key.resolve())}
    dictionary = directory / PASSWORDS
    if not dictionary.is_file():
        raise ConfigurationError(f"{dictionary}: no such file: the robot's password dictionary")
    _private(dictionary)
    acl = _read_json(directory / ACL, what="the robot's access control", secret=True)
    if acl.get("robot") != setup.robot or not isinstance(acl.get("access_control"), dict):
        raise ConfigurationError(f"{directory / ACL}: not the access control of "
                                 f"{setup.robot!r}")
    return out | {"transport/auth/usrpwd/dictionary_file": str(dictionary.resolve()),
                  "access_control": acl["access_control"]}


def apply(conf: Any, *, directory: Path, identity: str | None, robot: str,
          listen: Sequence[str] = (), connect: Sequence[str] = ()) -> None:
    """Put ``conf`` (a ``zenoh.Config``) in secure mode: the :func:`settings` of identity
    ``identity`` of set-up ``directory``. Raises :class:`ConfigurationError`."""
    for path, value in settings(directory=directory, identity=identity, robot=robot,
                                listen=listen, connect=connect).items():
        conf.insert_json5(path, json.dumps(value))


def override(directory: Path, identity: str, *, connect: Sequence[str]) -> str:
    """A ``ZENOH_CONFIG_OVERRIDE`` value (``path=value;…``, as rmw_zenoh reads it) that
    joins a client-mode zenoh node — a ROS 2 node with identity ``identity`` — to the robot at
    ``connect``, in secure mode. Raises :class:`ConfigurationError`."""
    setup = SecureSetup.load(directory)
    pairs = settings(directory=directory, identity=identity, robot=setup.robot,
                     connect=connect) | {"connect/endpoints": list(connect),
                                         "listen/endpoints": []}
    return ";".join(f"{path}={json.dumps(value)}" for path, value in pairs.items())


REISSUE = ("on the set-up's host run `python -m ubf_async.secure rotate DIR {name}` and bring "
           "this host the new `python -m ubf_async.secure export DIR {name}`")


# ---------------------------------------------------------------------------------------------
# What an identity may do, told before it acts

_VERBS = {"put": "publish on", "delete": "delete", "query": "query",
          "declare_queryable": "answer queries on", "liveliness_token": "announce itself on",
          "reply": "reply on"}


class Rights:
    """What this process may send into the robot's session. Open mode (and the robot itself,
    whose own session holds the rules): everything. :meth:`check` before acting."""

    def allows(self, message: str, key: str) -> bool:
        return True

    def check(self, message: str, key: str) -> None:
        """:class:`NotAllowedError` (one line: who may, and the flag to use) unless
        :meth:`allows`."""


OPEN = Rights()


class IdentityRights(Rights):
    """An identity's ingress rights in the set-up's access control (what the robot enforces):
    its ``grants``, which :func:`ubf_async.access.setup.rights` makes from the set-up."""

    def __init__(self, setup: SecureSetup, name: str, grants: Sequence[Grant]) -> None:
        self.setup, self.name = setup, name
        self._granted: dict[str, list[tuple[str, zenoh.KeyExpr]]] = {}
        for grant in grants:
            ingress = [(m, zenoh.KeyExpr(k)) for rule in grant.rules if rule.flow == "ingress"
                       for m in rule.messages for k in rule.key_exprs]
            for who in grant.subjects:
                self._granted.setdefault(who, []).extend(ingress)

    def _may(self, who: str, message: str, key: str) -> bool:
        target = zenoh.KeyExpr(key)
        return any(m == message and k.includes(target) for m, k in self._granted.get(who, ()))

    def allows(self, message: str, key: str) -> bool:
        return self._may(self.name, message, key)

    def check(self, message: str, key: str) -> None:
        if self.allows(message, key):
            return
        who = [name for name in self.setup.identities if self._may(name, message, key)]
        others = [name for name in who if name != ROBOT]
        if others:
            hint = (f"{', '.join(others)} may{' (and the robot)' * (ROBOT in who)}: run it with "
                    f"--identity {others[0]}")
        elif who:
            hint = "only the robot itself may (its launch process)"
        else:
            hint = "no identity of this set-up may"
        raise NotAllowedError(
            f"identity {self.name!r} may not {_VERBS.get(message, message)} {key}: the "
            f"robot's access control would drop it without a word; {hint} (docs/security.md)")


# ---------------------------------------------------------------------------------------------
# Why the robot did not let this process in


def diagnose(endpoint: str, *, directory: Path | None, identity: str | None) -> str | None:
    """For a session that could not reach ``endpoint`` although something accepts TCP there:
    why, in one line that says what to do, from a TLS handshake of this process's own
    (:func:`~ubf_async.net.tlsprobe.probe`); ``None`` when TLS is not the reason as far as
    can be told. Blocking: run it in a worker thread."""
    parts = tlsprobe.split_endpoint(endpoint)
    if parts is None:
        return None
    proto, host, port = parts
    export = "`python -m ubf_async.secure export DIR NAME` on the set-up's host"
    if directory is None or identity is None:
        found = tlsprobe.probe(host, port, ca=None)
        if found is None or found.kind != "tls-speaks":
            return None
        if proto == "tcp":
            return (f"the robot at {endpoint} speaks TLS (secure mode), not plain tcp/: "
                    f"connect to tls/{host}:{port} with --secure DIR --identity NAME ({export})")
        return (f"the robot at {endpoint} is in secure mode and asks for a certificate: this "
                f"process gave none: pass --secure DIR --identity NAME ({export})")
    cert, key = identity_file(directory, identity, ".pem"), identity_file(directory, identity,
                                                                          ".key")
    found = tlsprobe.probe(host, port, ca=directory / CA_CERT, cert=cert, key=key)
    if found is None:
        return None
    rotate_robot = ("on the set-up's host run `python -m ubf_async.secure rotate DIR robot{hosts}` "
                    "and restart the robot with the new `secure export DIR robot`")
    reissue = REISSUE.format(name=identity)
    if found.kind == "no-tls":
        return (f"the robot at {endpoint} does not speak TLS: it is not in secure mode (launch "
                f"it with --secure DIR --listen tls/HOST:PORT), or this is not its endpoint")
    if found.kind == "server-name":
        carried = tlsprobe.peer_names(host, port)
        return (f"the robot's certificate at {endpoint} does not carry the name dialled, "
                f"{host!r} (it carries: {', '.join(carried) or 'no names'}): dial one of those, "
                f"or {rotate_robot.format(hosts=f' --host {host} …')}")
    if found.kind == "server-unknown-ca":
        return (f"the robot at {endpoint} has a certificate not signed by this set-up's CA "
                f"({directory / CA_CERT}): this host's files come from another set-up (or one "
                f"made again with `secure init --force`): bring this host the robot set-up's "
                f"`python -m ubf_async.secure export DIR {identity}`")
    if found.kind == "server-expired":
        return (f"the robot's certificate at {endpoint} has expired, or is not valid yet (is "
                f"this host's clock right? {found.detail}): "
                f"{rotate_robot.format(hosts='')}")
    if found.kind == "server-other":
        return f"this process does not trust the robot's certificate at {endpoint}: {found.detail}"
    if found.kind in ("client-unknown-ca", "client-required", "client-bad"):
        return (f"the robot at {endpoint} refused this process's certificate ({cert}: "
                f"{found.detail}): it is not of the robot's set-up; {reissue}")
    if found.kind == "client-expired":
        return (f"the robot at {endpoint} refused this process's certificate as expired "
                f"({cert}; is this host's clock right?): {reissue}")
    return (f"the robot at {endpoint} accepted this process's certificate but not identity "
            f"{identity!r}'s password: it was rotated or revoked since this host's files were "
            f"made, or the robot runs on an older copy of the set-up (restart it with the "
            f"latest); {reissue}")
