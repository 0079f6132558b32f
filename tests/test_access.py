"""The access policy and the wire's keys cannot drift apart, and neither the transport nor the
policy spells a key out.

:mod:`ubf_async.access.policy` names every key it grants with the wire's builders; these tests
hold it to what the processes of each identity really send: every key the robot file's own
device components publish or hold (run on a bus that records what it is asked to allow), and
every key a remote behaviour, the operator, a fleet's robots, the ROS 2 bridge and ROS 2 nodes
send (made with the functions their code makes them with), is granted to that identity — and
what is the robot's alone to none of them; a grant left to no one is left out of zenoh's
section, which zenoh would refuse. A scan of ``ubf_async/net/`` and
``ubf_async/access/`` finds no key literal but the one the session's payload limit spells out,
held equal to the wire's.
"""

from __future__ import annotations

import ast
import asyncio
import inspect
import json
from pathlib import Path

import pytest
import zenoh

from components.sim.world.config import WorldConfig
from components.sim.world.physics import World
from tests.conftest import eventually
from ubf_async.access.policy import ROS2_DRIVEN_TOPIC, fleet_grants, grants_of, robot_grants
from ubf_async.access.setup import fleet_identities, identities_for
from ubf_async.assembly.context import DeviceContext
from ubf_async.assembly.robotfile import ResolvedDevice, Robot, load_robot
from ubf_async.net.inprocess import InProcessTransport
from ubf_async.net.options import SESSION_LIMITS
from ubf_async.net.secure import (
    ALL_MESSAGES,
    IdentityRights,
    Rights,
    SecureSetup,
    zenoh_access_control,
)
from ubf_async.runtime.bus import Bus
from ubf_async.services.remote import vote_key
from ubf_async.services.ros2 import keys as rk
from ubf_async.services.ros2.bridge import Ros2Bridge, Ros2Settings
from ubf_async.wire.keys import EVERY_ROBOT, Keys
from ubf_async.wire.topics import SIM_PULSES, TOPICS, TREE_REQUEST

ROOT = Path(__file__).resolve().parents[1]
MINI = (ROOT / "ubf_async" / "robots" / "mini-whegs.yaml").read_text()
DOMAIN, NAMESPACE = 3, "/sec/ns"
HASH = "RIHS01_" + "0" * 64  # (a type hash's shape: the keys, not the types, are tested)


def robot(tmp_path: Path) -> Robot:
    """mini-whegs named ``sec``, with a ``ros2:`` section in a namespace of its own."""
    text = MINI.replace("\nname: mini\n", "\nname: sec\n")
    path = tmp_path / "robot.yaml"
    path.write_text(f"{text}\nros2: {{domain_id: {DOMAIN}, namespace: {NAMESPACE}}}\n")
    return load_robot(path)


def set_up(tmp_path: Path) -> tuple[Robot, SecureSetup]:
    """The set-up ``secure init --device KIND/NAME …`` makes for every device of the robot
    file (in memory: the grants need no certificate)."""
    sec = robot(tmp_path)
    identities = identities_for(sec, devices=[f"{d.kind}/{d.name}" for d in sec.devices])
    return sec, SecureSetup(directory=tmp_path, robot=sec.name,
                            identities={i.name: i for i in identities})


def rights_of(setup: SecureSetup) -> dict[str, IdentityRights]:
    grants = grants_of(setup)
    return {name: IdentityRights(setup, name, grants) for name in setup.identities}


def refused(rights: Rights, sent: set[tuple[str, str]]) -> set[tuple[str, str]]:
    return {(message, key) for message, key in sent if not rights.allows(message, key)}


THE_ROBOTS_ALONE = [("put", "cmd/drive"), ("put", "clock"), ("put", "sim/truth"),
                    ("declare_queryable", "tree"), ("reply", "tree"), ("delete", "status/x")]


# ---------------------------------------------------------------------------------------------
# The robot's device components, run: what each publishes and holds


class Recording(Rights):
    """Allows everything and remembers what it was asked: the bus asks its rights before
    each publisher, token, queryable and query, and a component before announcing itself."""

    def __init__(self) -> None:
        self.asked: set[tuple[str, str]] = set()

    def allows(self, message: str, key: str) -> bool:
        self.asked.add((message, key))
        return True

    def check(self, message: str, key: str) -> None:
        self.asked.add((message, key))




async def sent_by(device: ResolvedDevice, bus: Bus, world: World) -> set[tuple[str, str]]:
    """What ``device``'s component, run on ``bus``, asks to publish and hold; with a
    simulated backend, in a process of its own, its mirror of the world also drives the
    simulator's wheels (``components.sim.mirror``)."""
    recording = Recording()
    bus.rights = recording
    component = device.build(context=DeviceContext(bus=bus, clock=bus.clock,
                                                   simulation=world.robot(0)))
    await component.start()
    try:
        # Its publishers are declared as its run starts, its heartbeat's with its token.
        started = {("put", bus.keys.sensor(device.kind, device.name)),
                   ("put", bus.keys.heartbeat(component.name))}
        await eventually(lambda: started <= recording.asked, timeout_s=10,
                         what=f"{component.name}'s publishers")
        await asyncio.sleep(0.2)  # (and what it declares a moment later)
    finally:
        await component.aclose()
    assert component.last_error is None, (device.kind, component.last_error)
    assert ("liveliness_token", bus.keys.alive(component.name)) in recording.asked
    pulses = {("put", SIM_PULSES.key(bus.keys))} if device.requires_simulator else set()
    return recording.asked | pulses


@pytest.mark.asyncio
async def test_every_key_a_device_component_publishes_or_holds_is_granted_to_it(
        tmp_path: Path) -> None:
    sec, setup = set_up(tmp_path)
    rights, keys = rights_of(setup), Keys(sec.name)
    bus = Bus(transport=InProcessTransport(), robot=sec.name)
    world = World(WorldConfig())
    gaps: dict[str, set[tuple[str, str]]] = {}
    try:
        for device in sec.devices:
            identity = rights[f"device-{device.kind}-{device.name}"]
            missing = refused(identity, await sent_by(device, bus, world))
            if missing:
                gaps[device.kind] = {(m, k.removeprefix(keys.prefix + "/")) for m, k in missing}
            for message, key in THE_ROBOTS_ALONE:
                assert not identity.allows(message, f"{keys.prefix}/{key}"), (device, key)
    finally:
        await bus.aclose()
    assert gaps == {}  # (the camera's view and the encoders' odometry: publishes_also)


# ---------------------------------------------------------------------------------------------
# Remote behaviours, the operator, the inspector, the robot


def test_every_key_a_remote_behaviour_sends_is_granted_to_its_slot_alone(tmp_path: Path
                                                                        ) -> None:
    sec, setup = set_up(tmp_path)
    rights, keys = rights_of(setup), Keys(sec.name)
    slots = {slot.name: slot.composite for slot in sec.remotes}
    assert {"teleop", "avoid_obstacles"} <= set(slots) and sec.spec.ros2 is not None
    bridge_slot = sec.spec.ros2.slot  # (the ros2: section's: the bridge votes as it)
    for name, composite in slots.items():
        # As tools/remote_host.py checks and RemoteBehaviorHost sends them.
        vote = ("put", vote_key(keys, composite, name))
        sent = {vote, ("put", keys.heartbeat(name)), ("liveliness_token", keys.alive(name))}
        assert refused(rights[name], sent) == set(), name
        bridged = ["ros2-bridge"] if name == bridge_slot else []
        assert [n for n, r in rights.items() if r.allows(*vote)] == ["robot", name, *bridged]
        for message, key in THE_ROBOTS_ALONE:
            assert not rights[name].allows(message, f"{keys.prefix}/{key}")


def test_reading_is_everyones_the_tree_the_operators_everything_the_robots(tmp_path: Path
                                                                          ) -> None:
    sec, setup = set_up(tmp_path)
    rights, keys = rights_of(setup), Keys(sec.name)
    every_topic = {t.key_expr(keys) for t in TOPICS} | {keys.all_alive}
    for name, identity in rights.items():
        if name == "robot":
            continue
        reads = {(m, k) for k in every_topic for m in ("declare_subscriber", "liveliness_query",
                                                       "declare_liveliness_subscriber")}
        assert refused(identity, reads) == set(), name
    query = ("query", TREE_REQUEST.key(keys))  # as the tree service's clients ask
    assert [n for n, r in rights.items() if r.allows(*query)] == ["robot", "operator"]
    everything = {(m, t.key(keys, *("x",) * len(t.placeholders))) for t in TOPICS
                  for m in ALL_MESSAGES}
    assert refused(rights["robot"], everything) == set()


# ---------------------------------------------------------------------------------------------
# ROS 2: the bridge in its own process, a ROS node that reads, one that drives


def test_every_key_the_ros2_bridge_and_ros2_nodes_send_is_granted_to_them(tmp_path: Path
                                                                         ) -> None:
    sec, setup = set_up(tmp_path)
    rights, keys = rights_of(setup), Keys(sec.name)
    spec = sec.spec.ros2
    assert spec is not None
    settings = Ros2Settings(domain_id=DOMAIN, namespace=NAMESPACE, slot=spec.slot)
    namespace = settings.namespace_for(sec.name)

    def data(topic: str, ros_type: str = "std_msgs/msg/String") -> str:
        return rk.data_key(DOMAIN, rk.qualify(namespace, topic), ros_type, HASH)

    node = rk.Node(DOMAIN, "0123456789abcdef", 0, namespace, settings.node)
    ros_node = rk.Node(DOMAIN, "fedcba9876543210", 0, "/", "teleop_twist_keyboard")
    component = inspect.signature(Ros2Bridge).parameters["name"].default
    composite = next(s.composite for s in sec.remotes if s.name == spec.slot)
    # What Ros2Bridge declares: its ROS publishers (data keys and MP tokens), its node, its
    # vote in the slot and its component's heartbeat and token.
    bridge = {("put", data(topic)) for topic in ("cmd_vel", "odom", "/clock", "ubf/trace",
                                                 "range/front", "camera/front/compressed")}
    bridge |= {("liveliness_token", node.token()),
               ("liveliness_token", node.endpoint_token(rk.PUBLISHER, 1,
                                                        rk.qualify(namespace, "odom"),
                                                        "nav_msgs/msg/Odometry", HASH)),
               ("put", vote_key(keys, composite, spec.slot)),
               ("put", keys.heartbeat(component)), ("liveliness_token", keys.alive(component)),
               ("liveliness_token", keys.alive(spec.slot))}
    assert refused(rights["ros2-bridge"], bridge) == set()
    # A ROS node reads the bridge's topics, announces itself and its subscriptions, and
    # asks for the graph.
    reader = {("declare_subscriber", data(topic)) for topic in ("odom", "/clock")}
    reader |= {("liveliness_token", ros_node.token()),
               ("liveliness_token", ros_node.endpoint_token(
                   rk.SUBSCRIPTION, 1, rk.qualify(namespace, "odom"), "nav_msgs/msg/Odometry",
                   HASH)),
               ("liveliness_query", rk.endpoints_of(DOMAIN, rk.PUBLISHER,
                                                    rk.qualify(namespace, "odom"),
                                                    "nav_msgs/msg/Odometry"))}
    drive = ("put", data(settings.cmd_vel_in, "geometry_msgs/msg/Twist"))
    assert settings.cmd_vel_in == ROS2_DRIVEN_TOPIC  # (the default the policy grants)
    for name in ("ros2-reader", "ros2-driver"):
        assert refused(rights[name], reader) == set(), name
    assert rights["ros2-driver"].allows(*drive) and not rights["ros2-reader"].allows(*drive)
    for name in ("ros2-reader", "ros2-driver"):
        assert not rights[name].allows("put", vote_key(keys, composite, spec.slot))
        assert not rights[name].allows("put", data("odom"))


# ---------------------------------------------------------------------------------------------
# A fleet


def test_each_robot_of_a_fleet_has_every_key_of_its_own_and_none_of_the_others(
        tmp_path: Path) -> None:
    robots = ("r1", "r2")
    setup = SecureSetup(directory=tmp_path, robot="fleet", fleet=robots,
                        identities={i.name: i for i in fleet_identities(robots)})
    rights = rights_of(setup)
    for name in robots:
        keys, other = Keys(name), Keys(next(r for r in robots if r != name))
        own = {(m, t.key(keys, *("x",) * len(t.placeholders))) for t in TOPICS
               for m in ALL_MESSAGES}
        assert refused(rights[name], own) == set()
        assert refused(rights["world"], own) == set() == refused(rights["router"], own)
        assert not rights[name].allows("put", other.cmd("drive"))
        assert rights["operator"].allows("query", keys.tree)
        assert not rights["fleet"].allows("query", keys.tree)
    assert rights["inspector"].allows("declare_subscriber", EVERY_ROBOT)


def test_an_access_control_whose_grants_lost_their_identities_still_opens(tmp_path: Path
                                                                          ) -> None:
    """Revoking the fleet's operator, or every identity of a robot but its own, leaves grants
    to no one: zenoh refuses a policy without subjects, so they are left out."""
    fleet = [i for i in fleet_identities(("r1",)) if i.name != "operator"]
    _, setup = set_up(tmp_path)
    alone = [setup.identities["robot"]]
    for acl in (zenoh_access_control(fleet_grants(("r1",), fleet), fleet),
                zenoh_access_control(robot_grants("sec", alone), alone)):
        assert all(policy["subjects"] for policy in acl["policies"])
        conf = zenoh.Config()
        for path, value in (("access_control", acl), ("listen/endpoints", ["tcp/127.0.0.1:0"]),
                            ("scouting/multicast/enabled", False)):
            conf.insert_json5(path, json.dumps(value))
        zenoh.open(conf).close()


# ---------------------------------------------------------------------------------------------
# No key spelled out in the transport or the policy


KEY_CHUNKS = sorted({t.pattern.split("/", 1)[0] for t in TOPICS} | {"alive"})
"""The first chunks of the robot's keys under ``ubf/<robot>/`` (``vote``, ``sensor`` …)."""
SPELLED_OUT_ON_PURPOSE = {("net/options.py", "ubf/**")}
"""The session's payload limit (``SESSION_LIMITS``), which every session of every process sets
from defaults no layer above hands down: held equal to the wire's own
(:data:`~ubf_async.wire.keys.EVERY_ROBOT`) below."""


def key_literals(source: str) -> list[str]:
    """The strings of ``source`` that spell out a key: with ``ubf/``, ``@ros2`` or one of
    :data:`KEY_CHUNKS` between slashes (``f"{prefix}/vote/{c}"`` too); docstrings and other
    bare strings, which say rather than make, are not code."""
    tree = ast.parse(source)
    said = {id(node.value) for node in ast.walk(tree) if isinstance(node, ast.Expr)}
    chunks = [f"/{c}/" for c in KEY_CHUNKS] + [f"{c}/" for c in KEY_CHUNKS]
    return [node.value for node in ast.walk(tree)
            if isinstance(node, ast.Constant) and isinstance(node.value, str)
            and id(node) not in said
            and ("ubf/" in node.value or "@ros2" in node.value
                 or any(c in node.value if c[0] == "/" else node.value.startswith(c)
                        for c in chunks))]


def test_the_scan_finds_a_key_spelled_out() -> None:
    planted = '''
"""The module's docstring may say ubf/<robot>/vote/."""
prefix = f"ubf/{robot}"
vote = f"{prefix}/vote/{composite}/{name}"
graph = f"@ros2_lv/{domain}/**"
pulses = prefix + "/sim/pulses"
alive = "alive/" + name
KEY = "x"
"""ubf/<robot>/tree: a docstring of KEY."""
fine = ("transport/link/tls", "connect/endpoints", "tls/", "python -m ubf_async.secure")
'''
    assert key_literals(planted) == ["ubf/", "/vote/", "@ros2_lv/", "/sim/pulses", "alive/"]


@pytest.mark.parametrize("room", ["net", "access"])
def test_no_key_is_spelled_out_in_the_transport_or_the_policy(room: str) -> None:
    found = {(str(path.relative_to(ROOT / "ubf_async")), literal)
             for path in sorted((ROOT / "ubf_async" / room).glob("*.py"))
             for literal in key_literals(path.read_text(encoding="utf-8"))}
    assert found - SPELLED_OUT_ON_PURPOSE == set()


def test_the_one_key_the_transport_spells_out_is_the_wires() -> None:
    (limit,) = SESSION_LIMITS["low_pass_filter"]
    assert limit["key_exprs"] == [EVERY_ROBOT]
