"""Key expressions of a robot, ``ubf/<robot>/...``, and the ROS 2 keys beside them: string
builders only.

The lowest rung of the wire contract: :mod:`ubf_async.wire.topics` declares each topic with these
patterns and :mod:`ubf_async.wire.protocol` re-exports :class:`Keys` and :func:`check_segment`
(their old home), so neither of the two needs the other to build a key. Every key of the project
is made here or from here: the access policy of a secure set-up (:mod:`ubf_async.access.policy`)
names its keys with these builders, and ``tests/test_access.py`` fails on a key spelled out in
the transport.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from ubf_async.errors import ProtocolError

__all__ = ["CLOCK_PATTERN", "EVERY_ROBOT", "HEARTBEAT_PATTERN", "ROOT", "ROS2_ADMIN_SPACE",
           "STATUS_PATTERN", "TREE_PATTERN", "Keys", "check_segment", "ros2_graph", "ros2_names"]

ROOT = "ubf"
EVERY_ROBOT = f"{ROOT}/**"
"""Every key of every robot: what a fleet's router relays and its identities read, and what a
session's payload limit covers (``ubf_async.net.options.SESSION_LIMITS`` spells it out, a test
holds the two together)."""

# The patterns (under ``ubf/<robot>/``) of the topics :class:`Keys` has a shortcut for; the
# topics of the same name in :mod:`ubf_async.wire.topics` are declared with these very strings.
HEARTBEAT_PATTERN = "heartbeat/{component}"
CLOCK_PATTERN = "clock"
STATUS_PATTERN = "status/{component}"
TREE_PATTERN = "tree"


# ---------------------------------------------------------------------------------------------
# Key expressions


def check_segment(what: str, value: str) -> str:
    if not value or any(c in value for c in "/*$?#") or value != value.strip():
        raise ProtocolError(f"{what} {value!r} must be one non-empty key segment without / * $ ? #")
    return value


@dataclass(frozen=True, slots=True)
class Keys:
    """The key expressions of one robot, ``ubf/<robot>/...``."""

    robot: str
    _sensor_head: str = field(init=False, repr=False, compare=False)
    """``ubf/<robot>/sensor/``, made once: :meth:`source_of` runs for every sensor sample."""

    def __post_init__(self) -> None:
        check_segment("robot name", self.robot)
        object.__setattr__(self, "_sensor_head", f"{ROOT}/{self.robot}/sensor/")

    @property
    def prefix(self) -> str:
        return f"{ROOT}/{self.robot}"

    def sensor(self, kind: str, name: str) -> str:
        """Where a sensor publishes its samples; its state source is ``"<kind>/<name>"``."""
        return f"{self.prefix}/sensor/{check_segment('kind', kind)}/{check_segment('name', name)}"

    def sensors_of_kind(self, kind: str) -> str:
        return f"{self.prefix}/sensor/{check_segment('kind', kind)}/*"

    @property
    def all_sensors(self) -> str:
        return f"{self.prefix}/sensor/*/*"

    def source_of(self, key: str) -> str:
        """``ubf/<robot>/sensor/<kind>/<name>`` → ``"<kind>/<name>"``."""
        head = self._sensor_head
        if not key.startswith(head) or key.count("/", len(head)) != 1:
            raise ProtocolError(f"{key!r} is not a sensor key of robot {self.robot!r}")
        return key[len(head):]

    def cmd(self, target: str) -> str:
        """Commands: ``drive``, ``seek_color``, ``radio``, ``leds``."""
        return f"{self.prefix}/cmd/{check_segment('command target', target)}"

    def alive(self, component: str) -> str:
        """A component's liveliness token."""
        return f"{self.prefix}/alive/{check_segment('component name', component)}"

    @property
    def all_alive(self) -> str:
        return f"{self.prefix}/alive/*"

    def component_of_alive(self, key: str) -> str:
        return key.rsplit("/", 1)[-1]

    def heartbeat(self, component: str) -> str:
        return f"{self.prefix}/" + HEARTBEAT_PATTERN.format(
            component=check_segment("component", component))

    @property
    def all_heartbeats(self) -> str:
        return f"{self.prefix}/" + HEARTBEAT_PATTERN.format(component="*")

    @property
    def clock(self) -> str:
        """Simulation time, published by a simulator (absent in wall-clock runs)."""
        return f"{self.prefix}/{CLOCK_PATTERN}"

    def sim(self, topic: str) -> str:
        """A simulator's own topics, outside ``sensor/`` so behaviours never see them:
        ``truth`` (robot and ball poses), ``world`` (the full snapshot, for sim-backed devices
        in other processes) and ``pulses`` (motor pulses from such a motors process)."""
        return f"{self.prefix}/sim/{check_segment('sim topic', topic)}"

    def status(self, component: str) -> str:
        return f"{self.prefix}/" + STATUS_PATTERN.format(
            component=check_segment("component", component))

    @property
    def tree(self) -> str:
        """The robot's live-tree queryable (:mod:`ubf_async.services.live`)."""
        return f"{self.prefix}/{TREE_PATTERN}"

    @property
    def everything(self) -> str:
        return f"{self.prefix}/**"


# ---------------------------------------------------------------------------------------------
# ROS 2 keys (rmw_zenoh's), beside the robot's

# rmw_zenoh keeps the ROS graph (nodes, publishers, subscriptions) as liveliness tokens under this
# verbatim chunk, outside ``ubf/``: the ROS 2 bridge declares its tokens there
# (ubf_async.services.ros2.keys) and a secure set-up grants them to the ROS 2 identities
# (ubf_async.access.policy) — one spelling for both, so the grant cannot miss the tokens.
ROS2_ADMIN_SPACE = "@ros2_lv"


def ros2_names(domain_id: int, name: str) -> str:
    """Every data key of ROS name ``name`` — a topic, or a namespace and all below it — in ROS
    domain ``domain_id``, as rmw_zenoh writes them (``<domain>/<name, no leading slash>/…``):
    ``(3, "/mini")`` → ``3/mini/**``, the root namespace ``(3, "/")`` → ``3/**``."""
    return "/".join(part for part in (str(domain_id), name.strip("/"), "**") if part)


def ros2_graph(domain_id: int) -> str:
    """Every liveliness token of ROS domain ``domain_id``'s graph: ``@ros2_lv/<domain>/**``."""
    return f"{ROS2_ADMIN_SPACE}/{domain_id}/**"
