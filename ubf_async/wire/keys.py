"""Key expressions of a robot, ``ubf/<robot>/...``: string builders only.

The lowest rung of the wire contract: :mod:`ubf_async.wire.topics` declares each topic with these
patterns and :mod:`ubf_async.wire.protocol` re-exports :class:`Keys` and :func:`check_segment`
(their old home), so neither of the two needs the other to build a key.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from ubf_async.errors import ProtocolError

__all__ = ["CLOCK_PATTERN", "HEARTBEAT_PATTERN", "ROOT", "STATUS_PATTERN", "TREE_PATTERN", "Keys",
           "check_segment"]

ROOT = "ubf"

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
