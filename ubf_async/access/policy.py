"""What each identity of a secure set-up may do on the robot's network: its grants, named with
the wire's keys.

The policy of ``docs/security.md`` (*Access control*) in executable form. ``secure init`` writes
it for the robot's session to enforce and every other process checks its own rights against it
before it acts (:mod:`ubf_async.access.setup`). It sits above the transport because it is made
of the protocol's keys (:mod:`ubf_async.wire.keys`, :mod:`ubf_async.wire.topics`), each built
by the function the runtime builds it with; :mod:`ubf_async.net.secure` takes the
:class:`~ubf_async.net.secure.Grant` data and turns it into zenoh's ``access_control`` section.
``tests/test_access.py`` holds policy and keys together: every key a component of each identity
publishes or holds, made as the runtime makes it, is granted to that identity.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

from ubf_async.errors import ConfigurationError
from ubf_async.net.secure import (
    ALL_MESSAGES,
    FLEET,
    INSPECTOR,
    OPERATOR,
    READ_MESSAGES,
    ROBOT,
    ROS2_BRIDGE,
    ROS2_DRIVER,
    ROS2_READER,
    ROUTER,
    WORLD,
    Grant,
    Identity,
    Rule,
    SecureSetup,
    zenoh_access_control,
)
from ubf_async.wire.keys import EVERY_ROBOT, Keys, ros2_graph, ros2_names
from ubf_async.wire.topics import SIM_PULSES, TOPICS, VOTE, Topic

__all__ = ["ROS2_BRIDGE_COMPONENT", "ROS2_CLOCK", "ROS2_DRIVEN_TOPIC", "access_control",
           "describe", "fleet_grants", "grants", "grants_of", "robot_grants"]

ROS2_BRIDGE_COMPONENT = "ros2"
"""The ROS 2 bridge's component name (``Ros2Bridge``'s default): its heartbeat and token."""
ROS2_CLOCK = "/clock"
"""The ROS time topic, which the bridge publishes for ``use_sim_time``."""
ROS2_DRIVEN_TOPIC = "cmd_vel_in"
"""The ROS topic, under the robot's ROS namespace, whose Twists drive the robot: the robot
file's default (``ros2: {cmd_vel_in: …}``). An identity records the domain and namespace only,
so a robot file that renames the topic still grants this one (docs/security.md, limits)."""


def grants(robot: str, identities: Sequence[Identity], *, fleet: Sequence[str] = ()
           ) -> tuple[Grant, ...]:
    """The grants of a set-up's ``identities``: a fleet's (:func:`fleet_grants`) when ``fleet``
    names its robots, else robot ``robot``'s (:func:`robot_grants`)."""
    if fleet:
        return fleet_grants(fleet, identities)
    return robot_grants(robot, identities)


def grants_of(setup: SecureSetup) -> tuple[Grant, ...]:
    """The grants of ``setup``'s identities, as ``secure init`` wrote them into its ACL."""
    return grants(setup.robot, list(setup.identities.values()), fleet=setup.fleet)


def robot_grants(robot: str, identities: Sequence[Identity]) -> tuple[Grant, ...]:
    """What each of robot ``robot``'s identities may do (zenoh's default is deny).

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
    keys = Keys(robot)
    everything = (keys.everything,)
    out = [_grant("egress", [Rule("egress", ALL_MESSAGES, everything, flow="egress")],
                  identities),
           _grant("read", [Rule("read", READ_MESSAGES, everything)],
                  [i for i in identities if i.role != ROBOT])]
    ros = [i for i in identities if i.ros2 is not None]
    if ros:  # (one robot file: every ROS identity has its domain and namespace)
        out.append(_grant("ros2-egress",
                          [Rule("ros2-egress", ALL_MESSAGES, _ros_keys(ros[0]), flow="egress")],
                          ros))
    for identity in identities:
        own = _own_rules(keys, identity)
        if own:
            out.append(_grant(f"own-{identity.name}", own, [identity]))
    return tuple(out)


def fleet_grants(robots: Sequence[str], identities: Sequence[Identity]) -> tuple[Grant, ...]:
    """What each identity of a fleet of ``robots`` may do on its router (default deny):
    ``router`` and ``world`` everything under ``ubf/``, each robot everything under its own
    keys, ``operator`` also the tree queries; everyone reads under ``ubf/`` (the fleet's tools
    look at every robot at once: ``ubf/*/alive/controller``). Egress: everything under
    ``ubf/``, to everyone."""
    every = (EVERY_ROBOT,)
    out = [_grant("egress", [Rule("egress", ALL_MESSAGES, every, flow="egress")], identities),
           _grant("read", [Rule("read", READ_MESSAGES, every)], identities),
           _grant("all", [Rule("all", ALL_MESSAGES, every)],
                  [i for i in identities if i.name in (ROUTER, WORLD)]),
           _grant("tree", [Rule("tree", ("query",), tuple(Keys(r).tree for r in robots))],
                  [i for i in identities if i.name == OPERATOR])]
    for identity in identities:
        if identity.role == "member":
            out.append(_grant(f"own-{identity.name}",
                              [Rule(f"{identity.name}-all", ALL_MESSAGES,
                                    (Keys(identity.name).everything,))], [identity]))
    return tuple(out)


def access_control(robot: str, identities: Sequence[Identity]) -> dict[str, Any]:
    """Robot ``robot``'s zenoh ``access_control`` section for ``identities``, as ``acl.json``
    holds it: :func:`robot_grants` in zenoh's words."""
    return zenoh_access_control(robot_grants(robot, identities), identities)


def describe(identity: Identity) -> str:
    """What ``identity`` may do, in a few words (``secure show``)."""
    if identity.role == "remote":
        return f"remote behaviour: votes in {', '.join(identity.composites)}"
    if identity.role == "device" and identity.device is not None:
        return f"device {identity.device[0]}/{identity.device[1]}" + (
            " (simulated: may drive the simulator's wheels)" if identity.simulated else "")
    if identity.ros2 is not None:
        where = f"ROS domain {identity.ros2[0]}, {identity.ros2[1]}"
        return {ROS2_BRIDGE: f"the ROS 2 bridge as its own process ({where}): votes as "
                             f"{', '.join(identity.composites)}",
                ROS2_READER: f"a ROS 2 node that reads the robot's topics ({where})",
                ROS2_DRIVER: f"a ROS 2 node that reads and drives ({ROS2_DRIVEN_TOPIC}; "
                             f"{where})",
                }[identity.role]
    if identity.role == "member":
        return (f"robot {identity.name} of the fleet: every key of "
                f"{Keys(identity.name).prefix}/")
    return {ROBOT: "the robot: every key of the robot",
            INSPECTOR: "read-only: subscribe and liveliness",
            OPERATOR: "read, and the tree service (show and change the tree)",
            ROUTER: "the fleet's router: holds the access control, relays every key",
            WORLD: "the fleet's world: every robot's simulator and devices",
            FLEET: "the fleet's launcher: reads every robot",
            }[identity.role]


def _grant(grant_id: str, rules: Iterable[Rule], identities: Iterable[Identity]) -> Grant:
    return Grant(grant_id, tuple(rules), tuple(i.name for i in identities))


def _ros_keys(identity: Identity) -> tuple[str, ...]:
    """The ROS 2 keys of an identity's domain and namespace: data, ``/clock`` and graph."""
    assert identity.ros2 is not None
    domain, namespace = identity.ros2
    return ros2_names(domain, namespace), ros2_names(domain, ROS2_CLOCK), ros2_graph(domain)


def _own_rules(keys: Keys, identity: Identity) -> list[Rule]:
    """What ``identity`` may do beyond reading: the keys of what its process publishes and
    the tokens it holds, made as that process makes them."""
    name = identity.name
    if identity.ros2 is not None:
        domain, namespace = identity.ros2
        ros = _ros_keys(identity)
        rules = [Rule(f"{name}-read", READ_MESSAGES, ros),
                 Rule(f"{name}-token", ("liveliness_token",), (ros2_graph(domain),))]
        if identity.role == ROS2_DRIVER:
            driven = ros2_names(domain, f"{namespace.rstrip('/')}/{ROS2_DRIVEN_TOPIC}")
            rules.append(Rule(f"{name}-put", ("put",), (driven,)))
        if identity.role == ROS2_BRIDGE:
            # composites: the slots' keys, composite/slot
            slots = [slot.rsplit("/", 1) for slot in identity.composites]
            votes = [VOTE.key(keys, composite=c, behavior=s) for c, s in slots]
            rules += [Rule(f"{name}-put", ("put",), (
                          *ros[:2], *votes, keys.heartbeat(ROS2_BRIDGE_COMPONENT))),
                      Rule(f"{name}-alive", ("liveliness_token",), (
                          *(keys.alive(s) for _, s in slots),
                          keys.alive(ROS2_BRIDGE_COMPONENT)))]
        return rules
    if identity.role == ROBOT:
        return [Rule(f"{name}-all", ALL_MESSAGES, (keys.everything,))]
    if identity.role == OPERATOR:
        return [Rule(f"{name}-tree", ("query",), (keys.tree,))]
    if identity.role == "remote":
        votes = [VOTE.key(keys, composite=c, behavior=name) for c in identity.composites]
        return [Rule(f"{name}-put", ("put",), (*votes, keys.heartbeat(name))),
                Rule(f"{name}-token", ("liveliness_token",), (keys.alive(name),))]
    if identity.role == "device" and identity.device is not None:
        kind, device = identity.device
        component = f"{kind}-{device}"  # (a device component's name: camera-front)
        puts = [keys.sensor(kind, device), keys.heartbeat(component), keys.status(component),
                *(_topic(name, identity).key(keys, device) for name in identity.publishes)]
        if identity.simulated:
            puts.append(SIM_PULSES.key(keys))
        return [Rule(f"{name}-put", ("put",), tuple(puts)),
                Rule(f"{name}-token", ("liveliness_token",), (keys.alive(component),))]
    return []


_BY_NAME = {topic.name: topic for topic in TOPICS}


def _topic(name: str, identity: Identity) -> Topic[Any]:
    """A device identity's further topic by name (``publishes``, from its set-up's file)."""
    topic = _BY_NAME.get(name)
    if topic is None or topic.placeholders != ("name",):
        raise ConfigurationError(f"identity {identity.name!r}: {name!r} is not a topic a "
                                 f"device may publish for its name (make the set-up again "
                                 f"with this version: python -m ubf_async.secure init)")
    return topic
