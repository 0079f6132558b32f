"""Secure mode: who may say what on a robot's zenoh network, with zenoh's own mechanisms.

The library (set-up and :func:`apply`); its command line is :mod:`ubf_async.tools.secure`, which
re-exports these names. Split so the connection options (:mod:`ubf_async.runtime.bus`) can apply a
set-up without importing the command line, which reads robot files (a module far above).

``python -m ubf_async.secure init DIR --robot-file FILE`` generates, for the robot the file
describes:

* one **identity** per process that may join — ``robot`` (the launch process: controller,
  simulator and devices in one session), one per configured remote behaviour (the name of
  each ``remote:`` slot), ``inspector`` (read-only), ``operator`` (read, and the tree service)
  and, with ``--device KIND/NAME``, ``device-KIND-NAME`` for a device process attached from
  outside — each with a random password (zenoh ``transport/auth/usrpwd``);
* the robot's **access control** (zenoh ``access_control``, default deny): what each identity
  may put, declare and query under ``ubf/<robot>/`` (see :func:`access_control`).

Every process then passes ``--secure DIR --identity NAME`` (the shared connection flags):
:func:`apply` adds that identity's credentials to the zenoh configuration; the ``robot``
identity also gets the password dictionary its listener checks and the ACL its session
enforces. Other identities connect in **client** mode, so all their traffic crosses the
robot's session — zenoh applies ACL rules only on the node that holds them, and a denied
message is dropped there without any error to the sender. ``docs/security.md`` has the
threat model, the set-up and the limits.

Files: ``DIR/secure.json`` (what was generated, for whom), ``DIR/passwords.txt`` and
``DIR/acl.json`` (the robot's side), ``DIR/identities/NAME.json`` (one per identity: copy
just that file to the machine that runs it). Secret files are 0600, folders 0700.
"""

from __future__ import annotations

import json
import os
import secrets
import stat
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ubf_async.errors import ConfigurationError

FORMAT = 1
ROBOT = "robot"
INSPECTOR = "inspector"
OPERATOR = "operator"
BUILTIN = (ROBOT, INSPECTOR, OPERATOR)
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
                   ros2=(int(ros2[0]), str(ros2[1])) if ros2 else None)

    def describe(self) -> str:
        if self.role == "remote":
            return f"remote behaviour: votes in {', '.join(self.composites)}"
        if self.role == "device" and self.device is not None:
            return f"device {self.device[0]}/{self.device[1]}" + (
                " (simulated: may drive the simulator's wheels)" if self.simulated else "")
        if self.ros2 is not None:
            where = f"ROS domain {self.ros2[0]}, {self.ros2[1]}"
            return {ROS2_BRIDGE: f"the ROS 2 bridge as its own process ({where}): votes as "
                                 f"{', '.join(self.composites)}",
                    ROS2_READER: f"a ROS 2 node that reads the robot's topics ({where})",
                    ROS2_DRIVER: f"a ROS 2 node that reads and drives (cmd_vel_in; {where})",
                    }[self.role]
        return {ROBOT: "the robot: every key of the robot",
                INSPECTOR: "read-only: subscribe and liveliness",
                OPERATOR: "read, and the tree service (show and change the tree)"}[self.role]


def identities_for(robot: Any, *, devices: Iterable[str] = ()) -> list[Identity]:
    """The identities of ``robot`` (a :class:`~ubf_async.assembly.robotfile.Robot`): the built-in
    ones, one per remote slot name, one per ``devices`` entry (``KIND/NAME`` of a device of
    the robot file). Raises :class:`ConfigurationError`."""
    out = [Identity(name=ROBOT, role=ROBOT), Identity(name=INSPECTOR, role=INSPECTOR),
           Identity(name=OPERATOR, role=OPERATOR)]
    composites: dict[str, list[str]] = {}
    for slot in robot.remotes:
        composites.setdefault(slot.name, []).append(slot.composite)
    for name, where in composites.items():
        if name in BUILTIN or name.startswith(("device-", "ros2-")):
            raise ConfigurationError(f"remote slot {name!r}: the name is taken by a built-in "
                                     f"identity ({', '.join(BUILTIN)}, device-*, ros2-*)")
        out.append(Identity(name=name, role="remote", composites=tuple(sorted(set(where)))))
    ros2 = getattr(getattr(robot, "spec", None), "ros2", None)
    if ros2 is not None and ros2.enabled:
        ros_at: tuple[int, str] = (ros2.domain_id, ros2.namespace or f"/{robot.name}")
        slot = tuple(sorted({s.key for s in robot.remotes if s.name == ros2.slot}))
        out += [Identity(name=ROS2_BRIDGE, role=ROS2_BRIDGE, composites=slot, ros2=ros_at),
                Identity(name=ROS2_READER, role=ROS2_READER, ros2=ros_at),
                Identity(name=ROS2_DRIVER, role=ROS2_DRIVER, ros2=ros_at)]
    known = {f"{d.kind}/{d.name}": d for d in robot.devices}
    for wanted in devices:
        device = known.get(wanted)
        if device is None:
            raise ConfigurationError(f"--device {wanted}: not a device of the robot file "
                                     f"(its devices: {', '.join(sorted(known)) or 'none'})")
        out.append(Identity(name=f"device-{device.kind}-{device.name}", role="device",
                            device=(device.kind, device.name),
                            simulated=device.requires_simulator is not None))
    return out


def access_control(robot: str, identities: Sequence[Identity]) -> dict[str, Any]:
    """The robot's zenoh ``access_control`` section (default deny).

    Ingress (what a connected process may send into the robot's session):

    * ``robot``: everything under ``ubf/<robot>/``;
    * everyone else: subscribe, liveliness-subscribe and liveliness-query under
      ``ubf/<robot>/`` (they can read every key: sensors, commands, status);
    * a remote behaviour ``N``: also put its votes ``vote/<composite>/N`` (only the
      composites it has a slot in), its ``heartbeat/N``, and hold the token ``alive/N``;
    * ``operator``: also query ``tree`` (show *and* change the tree: one key serves both);
    * ``device-K-N``: also put ``sensor/K/N``, ``heartbeat/K-N`` and ``status/K-N``, hold
      ``alive/K-N`` and, for a simulated backend, put ``sim/pulses``;
    * with a ``ros2:`` section, the ROS 2 keys of its domain ``D`` and namespace ``NS``
      (``D/NS/**``, ``D/clock/**``, and the graph ``@ros2_lv/D/**``): ``ros2-reader`` and
      ``ros2-driver`` may subscribe to them, hold their own graph tokens and query the graph;
      ``ros2-driver`` also put ``D/NS/cmd_vel_in/**``; ``ros2-bridge`` (the bridge in a
      process of its own) put the ROS keys and vote in its slot (``vote/<composite>/<slot>``,
      ``alive/<slot>``, ``alive/ros2``, ``heartbeat/ros2``). ROS keys go out (egress) to the
      ROS identities only.

    Nobody but ``robot`` may put ``cmd/*`` (drive, seek_color, radio, leds), ``clock`` or
    other ``sim/*`` keys, declare a queryable, reply, or delete. Egress (what the session
    sends to connected processes): everything under ``ubf/<robot>/``, to every identity."""
    prefix = f"ubf/{robot}"
    rules: list[dict[str, Any]] = [
        _rule("egress", ALL_MESSAGES, [f"{prefix}/**"], flow="egress"),
        _rule("read", READ_MESSAGES, [f"{prefix}/**"]),
    ]
    policies: list[dict[str, Any]] = [
        {"id": "egress", "rules": ["egress"], "subjects": [_subject_id(i) for i in identities]},
        {"id": "read", "rules": ["read"],
         "subjects": [_subject_id(i) for i in identities if i.role != ROBOT]},
    ]
    ros = [i for i in identities if i.ros2 is not None]
    if ros:
        rules.append(_rule("ros2-egress", ALL_MESSAGES, _ros_keys(ros[0]), flow="egress"))
        policies.append({"id": "ros2-egress", "rules": ["ros2-egress"],
                         "subjects": [_subject_id(i) for i in ros]})
    for identity in identities:
        own = _own_rules(prefix, identity)
        rules += own
        if own:
            policies.append({"id": f"own-{identity.name}", "rules": [r["id"] for r in own],
                             "subjects": [_subject_id(identity)]})
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": [{"id": _subject_id(i), "usernames": [i.name]} for i in identities],
        "policies": policies,
    }


def _rule(rule_id: str, messages: Sequence[str], key_exprs: Sequence[str], *,
          flow: str = "ingress") -> dict[str, Any]:
    return {"id": rule_id, "messages": list(messages), "flows": [flow], "permission": "allow",
            "key_exprs": list(key_exprs)}


def _subject_id(identity: Identity) -> str:
    return f"user-{identity.name}"


def _ros_keys(identity: Identity, topic: str = "**") -> list[str]:
    """The ROS 2 keys of an identity's domain and namespace: data, ``/clock`` and graph."""
    assert identity.ros2 is not None
    domain, namespace = identity.ros2
    data = f"{domain}/{namespace.strip('/')}/{topic}".replace("//", "/")
    return [data] if topic != "**" else [data, f"{domain}/clock/**", f"@ros2_lv/{domain}/**"]


def _own_rules(prefix: str, identity: Identity) -> list[dict[str, Any]]:
    name = identity.name
    if identity.ros2 is not None:
        keys = _ros_keys(identity)
        graph = [k for k in keys if k.startswith("@")]
        rules = [_rule(f"{name}-read", ("declare_subscriber", "declare_liveliness_subscriber",
                                        "liveliness_query"), keys),
                 _rule(f"{name}-token", ("liveliness_token",), graph)]
        if identity.role == ROS2_DRIVER:
            rules.append(_rule(f"{name}-put", ("put",), _ros_keys(identity, "cmd_vel_in/**")))
        if identity.role == ROS2_BRIDGE:
            # composites: the slot's key, composite/slot
            votes = [f"{prefix}/vote/{slot}" for slot in identity.composites]
            alive = [f"{prefix}/alive/{slot.rsplit('/', 1)[1]}" for slot in identity.composites]
            rules += [_rule(f"{name}-put", ("put",), [*keys[:2], *votes,
                                                      f"{prefix}/heartbeat/ros2"]),
                      _rule(f"{name}-alive", ("liveliness_token",),
                            [*alive, f"{prefix}/alive/ros2"])]
        return rules
    if identity.role == ROBOT:
        return [_rule(f"{name}-all", ALL_MESSAGES, [f"{prefix}/**"])]
    if identity.role == OPERATOR:
        return [_rule(f"{name}-tree", ("query",), [f"{prefix}/tree"])]
    if identity.role == "remote":
        puts = [f"{prefix}/vote/{c}/{name}" for c in identity.composites]
        return [_rule(f"{name}-put", ("put",), [*puts, f"{prefix}/heartbeat/{name}"]),
                _rule(f"{name}-token", ("liveliness_token",), [f"{prefix}/alive/{name}"])]
    if identity.role == "device" and identity.device is not None:
        kind, device = identity.device
        component = f"{kind}-{device}"
        puts = [f"{prefix}/sensor/{kind}/{device}", f"{prefix}/heartbeat/{component}",
                f"{prefix}/status/{component}"]
        if identity.simulated:
            puts.append(f"{prefix}/sim/pulses")
        return [_rule(f"{name}-put", ("put",), puts),
                _rule(f"{name}-token", ("liveliness_token",), [f"{prefix}/alive/{component}"])]
    return []


# ---------------------------------------------------------------------------------------------
# Generating and loading a secure set-up


@dataclass(slots=True, kw_only=True)
class SecureSetup:
    """A generated set-up directory (see the module docstring)."""

    directory: Path
    robot: str
    identities: dict[str, Identity] = field(default_factory=dict)
    source: str = ""

    @classmethod
    def load(cls, directory: Path) -> SecureSetup:
        """Read ``DIR/secure.json``. Raises :class:`ConfigurationError`."""
        data = _read_json(directory / MANIFEST, what="the secure set-up (run `python -m "
                          f"ubf_async.tools.secure init {directory} --robot-file FILE` first)")
        if data.get("format") != FORMAT:
            raise ConfigurationError(f"{directory / MANIFEST}: unknown format "
                                     f"{data.get('format')!r} (expected {FORMAT})")
        try:
            identities = [Identity.of_data(i) for i in data["identities"]]
            return cls(directory=directory, robot=str(data["robot"]),
                       identities={i.name: i for i in identities},
                       source=str(data.get("source", "")))
        except (KeyError, TypeError, IndexError) as exc:
            raise ConfigurationError(f"{directory / MANIFEST}: malformed ({exc})") from None

    def identity_file(self, name: str) -> Path:
        return identity_file(self.directory, name)


def identity_file(directory: Path, name: str) -> Path:
    """Where identity ``name``'s credentials live in a set-up directory."""
    return directory / IDENTITIES / f"{name}.json"


def init(directory: Path, *, robot: Any, devices: Iterable[str] = (),
         force: bool = False) -> SecureSetup:
    """Generate the identities and ACL of ``robot`` (a resolved robot file) into
    ``directory``. An existing set-up is kept unless ``force`` (new passwords: every process
    then needs its new identity file). Raises :class:`ConfigurationError`."""
    identities = identities_for(robot, devices=devices)
    if (directory / MANIFEST).exists() and not force:
        raise ConfigurationError(f"{directory} already holds a secure set-up (--force makes "
                                 "new passwords for every identity)")
    try:
        (directory / IDENTITIES).mkdir(parents=True, exist_ok=True)
        os.chmod(directory, 0o700)
        os.chmod(directory / IDENTITIES, 0o700)
        passwords = {i.name: secrets.token_urlsafe(24) for i in identities}
        for identity in identities:
            _write_secret(identity_file(directory, identity.name), json.dumps({
                "format": FORMAT, "robot": robot.name, "identity": identity.name,
                "user": identity.name, "password": passwords[identity.name],
            }, indent=2) + "\n")
        _write_secret(directory / PASSWORDS,
                      "".join(f"{name}:{pw}\n" for name, pw in passwords.items()))
        _write_secret(directory / ACL, json.dumps(
            {"robot": robot.name, "access_control": access_control(robot.name, identities)},
            indent=2) + "\n")
        _write_secret(directory / MANIFEST, json.dumps({
            "format": FORMAT, "robot": robot.name, "source": str(robot.source),
            "identities": [i.as_data() for i in identities],
        }, indent=2) + "\n")
    except OSError as exc:
        raise ConfigurationError(f"cannot write the secure set-up into {directory}: {exc}") \
            from None
    return SecureSetup(directory=directory, robot=robot.name,
                       identities={i.name: i for i in identities}, source=str(robot.source))


def _write_secret(path: Path, text: str) -> None:
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w") as out:
        out.write(text)
    os.chmod(path, 0o600)  # O_CREAT's mode does not apply to a file that already existed


def _read_json(path: Path, *, what: str, secret: bool = False) -> dict[str, Any]:
    try:
        if secret and path.stat().st_mode & (stat.S_IRWXG | stat.S_IRWXO):
            raise ConfigurationError(f"{path}: readable by others (chmod 600 {path})")
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise ConfigurationError(f"{path}: no such file: {what}") from None
    except (OSError, ValueError) as exc:
        raise ConfigurationError(f"{path}: cannot read {what}: {exc}") from None
    if not isinstance(data, dict):
        raise ConfigurationError(f"{path}: not a JSON object")
    return data


def apply(conf: Any, *, directory: Path, identity: str | None, robot: str,
          listen: Sequence[str] = ()) -> None:
    """Add identity ``identity``'s credentials from set-up ``directory`` to ``conf`` (a
    ``zenoh.Config``); for ``robot`` also the password dictionary and the ACL. Any other
    identity is put in client mode (all its traffic then crosses the robot's session, where
    the ACL is) and may not listen. Raises :class:`ConfigurationError`."""
    if not identity:
        raise ConfigurationError(f"--secure {directory} needs --identity NAME (the file names "
                                 f"in {directory / IDENTITIES})")
    creds = _read_json(identity_file(directory, identity), secret=True,
                       what=f"the credentials of identity {identity!r}")
    if creds.get("robot") != robot:
        raise ConfigurationError(f"identity {identity!r} of {directory} is for robot "
                                 f"{creds.get('robot')!r}, not {robot!r} (--robot)")
    user, password = creds.get("user"), creds.get("password")
    if not isinstance(user, str) or not isinstance(password, str):
        raise ConfigurationError(f"{identity_file(directory, identity)}: no user/password")
    conf.insert_json5("transport/auth/usrpwd/user", json.dumps(user))
    conf.insert_json5("transport/auth/usrpwd/password", json.dumps(password))
    if identity != ROBOT:
        if listen:
            raise ConfigurationError(f"identity {identity!r} may not --listen in secure mode: "
                                     "only the robot listens, the others connect to it")
        conf.insert_json5("mode", json.dumps("client"))
        return
    dictionary = directory / PASSWORDS
    if not dictionary.is_file():
        raise ConfigurationError(f"{dictionary}: no such file: the robot's password dictionary")
    if dictionary.stat().st_mode & (stat.S_IRWXG | stat.S_IRWXO):
        raise ConfigurationError(f"{dictionary}: readable by others (chmod 600 {dictionary})")
    acl = _read_json(directory / ACL, what="the robot's access control", secret=True)
    if acl.get("robot") != robot or not isinstance(acl.get("access_control"), dict):
        raise ConfigurationError(f"{directory / ACL}: not the access control of robot "
                                 f"{robot!r}")
    conf.insert_json5("transport/auth/usrpwd/dictionary_file", json.dumps(str(dictionary)))
    conf.insert_json5("access_control", json.dumps(acl["access_control"]))
