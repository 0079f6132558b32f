"""A secure set-up with its policy: the identities of a robot file or a fleet, the set-up made
and an identity revoked with the grants of :mod:`ubf_async.access.policy`, and what this process
may send.

:mod:`ubf_async.net.secure` keeps the files, certificates and zenoh's configuration; this module
decides who joins (:func:`identities_for`, :func:`fleet_identities`) and hands the transport the
grants wherever the access control is written (:func:`init`, :func:`init_fleet`,
:func:`revoke`) or read (:func:`rights`, which the bus asks when it opens). A set-up's
``rotate``, ``export``, ``override`` and ``settings`` change no grant: they are
:mod:`ubf_async.net.secure`'s alone.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any, Protocol

from ubf_async.access.policy import fleet_grants, grants, grants_of, robot_grants
from ubf_async.errors import ConfigurationError
from ubf_async.net import secure
from ubf_async.net.options import ConnectionOptions
from ubf_async.net.secure import (
    BUILTIN,
    FLEET_BUILTIN,
    INSPECTOR,
    LISTENERS,
    OPEN,
    OPERATOR,
    ROBOT,
    ROS2_BRIDGE,
    ROS2_DRIVER,
    ROS2_READER,
    Identity,
    IdentityRights,
    Rights,
    SecureSetup,
)
from ubf_async.wire.topics import Topic

__all__ = ["SecuredRobot", "fleet_identities", "identities_for", "init", "init_fleet", "revoke",
           "rights"]


class _RemoteSlot(Protocol):
    @property
    def composite(self) -> str: ...
    @property
    def name(self) -> str: ...
    @property
    def key(self) -> str: ...


class _Device(Protocol):
    @property
    def kind(self) -> str: ...
    @property
    def name(self) -> str: ...
    @property
    def requires_simulator(self) -> str | None: ...
    @property
    def further_topics(self) -> Sequence[Topic[Any]]: ...


class _Ros2(Protocol):
    @property
    def enabled(self) -> bool: ...
    @property
    def domain_id(self) -> int: ...
    @property
    def namespace(self) -> str | None: ...
    @property
    def slot(self) -> str: ...


class _RobotSpec(Protocol):
    @property
    def ros2(self) -> _Ros2 | None: ...


class SecuredRobot(Protocol):
    """What a set-up needs to know of a robot: a resolved robot file
    (:class:`ubf_async.assembly.robotfile.Robot`, a room above this one) is one."""

    @property
    def name(self) -> str: ...
    @property
    def source(self) -> str: ...
    @property
    def spec(self) -> _RobotSpec: ...
    @property
    def remotes(self) -> Sequence[_RemoteSlot]: ...
    @property
    def devices(self) -> Sequence[_Device]: ...


def identities_for(robot: SecuredRobot, *, devices: Iterable[str] = ()) -> list[Identity]:
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
    ros2 = robot.spec.ros2
    if ros2 is not None and ros2.enabled:
        ros_at: tuple[int, str] = (ros2.domain_id, ros2.namespace or f"/{robot.name}")
        bridged = tuple(sorted({s.key for s in robot.remotes if s.name == ros2.slot}))
        out += [Identity(name=ROS2_BRIDGE, role=ROS2_BRIDGE, composites=bridged, ros2=ros_at),
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
                            simulated=device.requires_simulator is not None,
                            publishes=tuple(t.name for t in device.further_topics)))
    return out


def fleet_identities(robots: Sequence[str]) -> list[Identity]:
    """The identities of a fleet of ``robots``: :data:`~ubf_async.net.secure.FLEET_BUILTIN` and
    one per robot. Raises :class:`ConfigurationError` for a robot named as a built-in
    identity."""
    clash = sorted(set(robots) & {*FLEET_BUILTIN, ROBOT})
    if clash:
        raise ConfigurationError(f"fleet robot {clash[0]!r}: the name is taken by a built-in "
                                 f"identity ({', '.join((*FLEET_BUILTIN, ROBOT))})")
    return [Identity(name=name, role=name) for name in FLEET_BUILTIN] + [
        Identity(name=robot, role="member") for robot in robots]


def init(directory: Path, *, robot: SecuredRobot, devices: Iterable[str] = (),
         hosts: Sequence[str] = (), force: bool = False,
         days: int | None = None) -> SecureSetup:
    """Generate the certificate authority, identities and ACL of ``robot`` (a resolved robot
    file) into ``directory``; ``hosts``: the robot's host names and addresses (default
    :data:`~ubf_async.net.secure.DEFAULT_HOSTS`). An existing set-up is kept unless ``force``
    (a new CA: every process then needs its new files). Raises :class:`ConfigurationError`."""
    identities = identities_for(robot, devices=devices)
    return secure.create(directory, robot.name, identities,
                         grants=robot_grants(robot.name, identities), source=str(robot.source),
                         hosts=hosts, force=force, days=days)


def init_fleet(directory: Path, *, name: str, robots: Sequence[str], source: str,
               hosts: Sequence[str] = (), force: bool = False,
               days: int | None = None) -> SecureSetup:
    """Generate a fleet's set-up (:func:`fleet_identities`,
    :func:`~ubf_async.access.policy.fleet_grants`): one CA for its router, world, launcher and
    ``robots``; ``hosts``: the router's names."""
    identities = fleet_identities(robots)
    return secure.create(directory, name, identities, grants=fleet_grants(robots, identities),
                         source=source, hosts=hosts, fleet=tuple(robots), force=force,
                         days=days)


def revoke(directory: Path, name: str) -> SecureSetup:
    """Remove identity ``name`` from the set-up at ``directory``: its ACL made again for the
    identities left, its password and its files gone
    (:func:`ubf_async.net.secure.revoke`); a running robot re-opens its session. Raises
    :class:`ConfigurationError`."""
    setup = SecureSetup.load(directory)
    left = [i for i in setup.identities.values() if i.name != name]
    return secure.revoke(directory, name, grants=grants(setup.robot, left, fleet=setup.fleet))


def rights(options: ConnectionOptions) -> Rights:
    """What this process may send (:class:`~ubf_async.net.secure.Rights`): everything in open
    mode, and for the robot or a fleet's router (its own session holds the rules); in secure
    mode its identity's grants, checked before it acts. Raises :class:`ConfigurationError` for
    a bad set-up."""
    if options.secure is None or options.identity is None or options.identity in LISTENERS:
        return OPEN
    setup = SecureSetup.load(options.secure)
    return IdentityRights(setup, options.identity, grants_of(setup))
