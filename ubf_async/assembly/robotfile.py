"""Robot files: one YAML file describes one robot — devices, controller, behaviour tree.

The format is documented in ``docs/robot-file.md``; its JSON Schema
(``ubf_async/robot-file.schema.json``, generated from the types below by
``python -m ubf_async.robotfile schema``) lets editors complete and check robot files.

Loading happens in two steps, and every mistake is reported as a
:class:`~ubf_async.errors.RobotFileError` reading ``FILE:LINE: message`` before anything runs:

1. :func:`decode_robot_file` composes the YAML (:meth:`Locator.parse`: syntax errors at their
   own line, a key given twice), then decodes it into typed :class:`RobotFile` objects with
   msgspec (types, ranges, unknown keys, listed with the valid ones). msgspec names the place
   of a mistake as a path such as ``$.tree.children[1].priority``; :class:`Locator` maps that
   path to the file's line through the YAML parser's node marks.
2. :func:`resolve` looks every name up in the plug-in registries
(:mod:`ubf_async.assembly.registry`),
   validates each behaviour's, arbiter's, device's and backend's parameters against the
   factory's own signature, and builds the behaviour tree. What needs a running bus (devices)
   is resolved and validated here, and built by launch.
"""

from __future__ import annotations

import datetime
import difflib
import inspect
import json
import random
import re
import types
import typing
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Annotated, Any, ClassVar, Final, Literal

import msgspec
import yaml

from ubf_async.assembly.body import (
    MOUNT_FIELDS,
    BodyPart,
    BodySpec,
    body_problems,
    mount_problems,
)
from ubf_async.assembly.context import DeviceContext
from ubf_async.assembly.devices import (
    BACKEND_INJECTED,
    DEVICE_INJECTED,
    backend_label,
    build_device,
    device_label,
    further_topics,
    requires_simulator,
)
from ubf_async.assembly.registry import (
    ARBITERS,
    BEHAVIORS,
    DEVICES,
    accepts,
    checked_params,
    get_backend,
    is_reference,
    validation_parts,
)
from ubf_async.core.behavior import Behavior, Child, Composite
from ubf_async.core.fusion import CameraFusion
from ubf_async.errors import MissingExtraError, ParameterError, PluginError, RobotFileError
from ubf_async.runtime.component import Component
from ubf_async.wire.topics import Topic

FORMAT_VERSION: Final = 1
DEFAULT_ROBOT_FILE = "mini-whegs"
"""The robot file ``python -m ubf_async.launch`` runs without arguments (package data)."""
SCHEMA_RESOURCE = "robot-file.schema.json"
PRIORITY_LIMIT = 1_000_000
MAX_WEIGHT = 1e6
MAX_DEPTH = 32

Name = Annotated[str, msgspec.Meta(pattern=r"^[A-Za-z0-9_][A-Za-z0-9_.-]{0,63}$",
                                   description="letters, digits, '_', '.', '-' (≤ 64)")]
Reference = Annotated[str, msgspec.Meta(min_length=1, max_length=200,
                                        description="a registered name or 'module:factory'")]
Priority = Annotated[int, msgspec.Meta(ge=-PRIORITY_LIMIT, le=PRIORITY_LIMIT,
                                       description="higher wins")]
Weight = Annotated[float, msgspec.Meta(ge=0.0, le=MAX_WEIGHT)]
Params = Annotated[dict[str, Any], msgspec.Meta(
    description="keyword parameters of the factory (checked against its signature)")]

# Behaviour and arbiter factories get these from the loader, never from the file.
INJECTED_TREE = frozenset({"name", "rng"})


class Spec(msgspec.Struct, kw_only=True, forbid_unknown_fields=True, omit_defaults=True):
    """Base of the robot file's types: keyword-only, unknown keys refused."""

    what: ClassVar[str] = "it"
    """What an error message calls an object of this type (``a tree node takes: …``)."""
    lists: ClassVar[Mapping[str, str]] = {}
    """What the lists of its fields hold (a field of lists: each of its lists), so that a
    single value written where one belongs is told how to write it as a list
    (``overrides["tree.arbiter"] must be a list of values to try: write [X]``)."""


class ArbiterSpec(Spec):
    """An arbiter with parameters: ``{type: MonteCarlo, params: {seed: 3}}``."""

    what: ClassVar[str] = "an arbiter"

    type: Reference
    params: Params = {}


class NodeSpec(Spec):
    """A node of the behaviour tree: a composite, a behaviour, or a remote slot.

    * composite: ``name``, ``arbiter`` and ``children``;
    * behaviour: ``behavior`` (registered name or ``module:factory``) and its ``params``;
    * remote slot: ``remote`` — the name a behaviour in another process votes under
      (docs/protocol.md, "Remote behaviours"); it is placed here when it attaches.

    ``priority`` and ``weight`` are the node's place in its parent composite.
    """

    what: ClassVar[str] = "a tree node"

    name: Name | None = None
    behavior: Reference | None = None
    arbiter: Reference | ArbiterSpec | None = None
    children: list[NodeSpec] | None = None
    remote: Name | None = None
    priority: Priority = 0
    weight: Weight = 1.0
    params: Params = {}

    def __post_init__(self) -> None:
        kinds = [k for k, v in (("behavior", self.behavior), ("arbiter", self.arbiter),
                                ("remote", self.remote)) if v is not None]
        if len(kinds) != 1:
            raise ValueError("a tree node needs exactly one of `behavior` (a leaf), `arbiter` "
                             "with `children` (a composite) or `remote` (a remote slot); got "
                             + (", ".join(f"`{k}`" for k in kinds) or "none"))
        if self.arbiter is not None:
            if self.children is None:
                raise ValueError("a composite (a node with `arbiter`) needs `children`")
            if self.name is None:
                raise ValueError("a composite needs a `name`")
            if self.params:
                raise ValueError("a composite takes no `params`; give the arbiter's as "
                                 "`arbiter: {type: NAME, params: {...}}`")
        elif self.children is not None:
            raise ValueError("only a composite (a node with `arbiter`) has `children`")
        if self.remote is not None and self.params:
            raise ValueError("a remote slot takes no `params`")

    @property
    def kind(self) -> Literal["composite", "behavior", "remote"]:
        if self.arbiter is not None:
            return "composite"
        return "behavior" if self.behavior is not None else "remote"


class DeviceSpec(Spec):
    """One device: its kind, instance name, backend and their parameters."""

    what: ClassVar[str] = "a device"

    kind: Reference
    name: Name
    backend: Reference
    params: Params = {}
    """The device's own parameters (mounting pose, period, …)."""
    backend_params: Params = {}
    """The backend's parameters (pins, a video source, …)."""


class ControllerSpec(Spec):
    """When the tree ticks (see :mod:`ubf_async.runtime.controller`)."""

    what: ClassVar[str] = "`controller`"

    mode: Literal["periodic", "sync", "event"] = "periodic"
    rate_hz: Annotated[float, msgspec.Meta(gt=0.0, le=10_000.0)] = 50.0
    reflex: list[Annotated[str, msgspec.Meta(max_length=128)]] = msgspec.field(
        default_factory=lambda: ["range/"])
    """Periodic mode also ticks at once on samples of sources starting with these."""
    sync_source: Annotated[str, msgspec.Meta(min_length=1, max_length=128)] = "camera/front"
    """Sync mode waits for a new sample of this source before each tick."""
    trigger: Annotated[str, msgspec.Meta(min_length=1, max_length=128)] | None = None
    """Event mode ticks on each sample of this source."""
    stale_after_s: dict[str, Annotated[float, msgspec.Meta(gt=0.0)]] = {}
    """Per source: stale when no sample has arrived for this long (default: 1.5× the period its
    samples declare, :data:`ubf_async.runtime.aggregator.STALE_PERIODS`)."""
    default_stale_after_s: Annotated[float, msgspec.Meta(gt=0.0)] | None = None
    """For sources that declare no period (events): stale after this long (default: never)."""
    lane: bool = True
    """Run a tick triggered by a sample on the thread that brought it (the reflex lane,
    wall-clock robots only); ``false`` keeps every tick on the event loop's thread, for
    behaviours that need it (:mod:`ubf_async.runtime.controller`)."""
    fuse: dict[Annotated[str, msgspec.Meta(min_length=1, max_length=128)],
               list[Annotated[str, msgspec.Meta(min_length=1, max_length=128)]]] = {}
    """Per fused source (``camera/both``): the robot's cameras it joins, left to right, into
    one wide camera's five bins, which the state holds beside theirs
    (:mod:`ubf_async.core.fusion`; docs/bodies.md, "The rodent")."""

    def fusions(self) -> tuple[CameraFusion, ...]:
        """The fused sources the state derives (``fuse``), checked when the file loads."""
        return tuple(CameraFusion(name, tuple(sources)) for name, sources in self.fuse.items())

    def __post_init__(self) -> None:
        if self.mode == "event" and self.trigger is None:
            raise ValueError("`mode: event` needs a `trigger` source, e.g. range/front")


class RemotesSpec(Spec):
    """How behaviours of other processes may join the tree."""

    what: ClassVar[str] = "`remotes`"

    only_declared: bool = False
    """Refuse remote behaviours without a `remote:` slot in the tree."""
    default_ttl_s: Annotated[float, msgspec.Meta(gt=0.0, le=60.0)] = 0.5
    max_ttl_s: Annotated[float, msgspec.Meta(gt=0.0, le=60.0)] = 5.0
    max_remotes: Annotated[int, msgspec.Meta(ge=0, le=4096)] = 64


ROS_NAMESPACE = r"^/([A-Za-z_][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*)*)?$"
ROS_TOPIC = r"^/?[A-Za-z_][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*)*$"


class Ros2Spec(Spec):
    """The ROS 2 bridge launch runs in-process (``ubf_async.ros2``, docs/ros2.md)."""

    what: ClassVar[str] = "`ros2`"

    enabled: bool = True
    domain_id: Annotated[int, msgspec.Meta(ge=0, le=232)] = 0
    distro: Literal["humble", "jazzy", "kilted"] = "jazzy"
    namespace: Annotated[str, msgspec.Meta(pattern=ROS_NAMESPACE)] | None = None
    """The node's namespace (default ``/<robot>``)."""
    node: Annotated[str, msgspec.Meta(pattern=r"^[A-Za-z_][A-Za-z0-9_]*$")] = "ubf_bridge"
    cmd_vel_in: Annotated[str, msgspec.Meta(pattern=ROS_TOPIC, max_length=128)] = "cmd_vel_in"
    slot: Name = "teleop"
    """The `remote:` slot the inbound Twists vote in (its composite: the one holding it)."""
    ttl_s: Annotated[float, msgspec.Meta(ge=0.001, le=60.0)] = 0.5
    max_linear_m_s: Annotated[float, msgspec.Meta(gt=0.0, le=100.0)] = 0.34
    """Calibration: the robot's forward speed at ``speed`` 100 (m/s)."""
    max_angular_rad_s: Annotated[float, msgspec.Meta(gt=0.0, le=100.0)] = 1.62
    """Calibration: its turn rate at ``turn`` 100, to the left (rad/s)."""


class RobotFile(Spec):
    """A robot: its name, devices, controller and behaviour tree."""

    what: ClassVar[str] = "a robot file"

    name: Name
    """The robot's name: its keys live under ``ubf/<name>/``."""
    tree: NodeSpec
    format: Literal[1] = FORMAT_VERSION
    description: str = ""
    seed: int | None = None
    """Seed of the behaviours' random choices (a simulated run's seed overrides it)."""
    devices: list[DeviceSpec] = []
    controller: ControllerSpec = msgspec.field(default_factory=ControllerSpec)
    remotes: RemotesSpec = msgspec.field(default_factory=RemotesSpec)
    ros2: Ros2Spec | None = None
    """The ROS 2 bridge (absent: none)."""
    body: BodySpec = msgspec.field(default_factory=BodySpec)
    """The robot's body (absent: the thesis's Mini-WHEGS; docs/bodies.md)."""


# -- file positions ---------------------------------------------------------------------------

Path_ = tuple[str | int, ...]
_PATH_PART = re.compile(r"\.([A-Za-z_][A-Za-z0-9_]*)|\[(\d+)\]|\[\"?([^\]\"]*)\"?\]")
_UNKNOWN_FIELD = re.compile(r"unknown field `([^`]+)`")


def parse_error_path(text: str) -> Path_:
    """``$.tree.children[1].priority`` → ``("tree", "children", 1, "priority")``."""
    out: list[str | int] = []
    for match in _PATH_PART.finditer(text.removeprefix("$")):
        name, index, key = match.groups()
        out.append(int(index) if index is not None else (name if name is not None else key))
    return tuple(out)


class Locator:
    """Maps a path into the decoded data to a line of the YAML text (1-based)."""

    def __init__(self, root: yaml.Node | None, *, source: str) -> None:
        self.source = source
        self._root = root

    @classmethod
    def parse(cls, text: str, *, source: str) -> Locator:
        """Compose ``text``'s YAML, refusing what decoding would not report: a syntax error
        (at its own line) and a key given twice in one mapping (YAML keeps the last one)."""
        try:
            root = yaml.compose(text, Loader=YAML_LOADER)
        except yaml.MarkedYAMLError as exc:
            raise yaml_syntax_error(exc, text, source) from None
        except yaml.YAMLError as exc:
            raise RobotFileError(f"not valid YAML: {exc}", path=source) from None
        duplicate = first_duplicate_key(root)
        if duplicate is not None:
            first, again = duplicate
            raise RobotFileError(
                f"duplicate key `{again.value}` (also on line {first.start_mark.line + 1}): "
                f"a key may appear once in a mapping; YAML would silently keep the last",
                path=source, line=again.start_mark.line + 1) from None
        return cls(root, source=source)

    def node(self, path: Path_) -> yaml.Node | None:
        node = self._root
        for part in path:
            if isinstance(node, yaml.MappingNode) and isinstance(part, str):
                found = None
                for key, value in node.value:
                    if isinstance(key, yaml.ScalarNode) and key.value == part:
                        found = value
                        break
                if found is None:
                    return node
                node = found
            elif isinstance(node, yaml.SequenceNode) and isinstance(part, int):
                if not 0 <= part < len(node.value):
                    return node
                node = node.value[part]
            else:
                return node
        return node

    def key_line(self, path: Path_, key: str) -> int | None:
        """The line of ``key`` inside the mapping at ``path`` (for unknown keys)."""
        node = self.node(path)
        if isinstance(node, yaml.MappingNode):
            for k, _ in node.value:
                if isinstance(k, yaml.ScalarNode) and k.value == key:
                    return int(k.start_mark.line) + 1
        return self.line(path)

    def line(self, path: Path_) -> int | None:
        node = self.node(path)
        return None if node is None else int(node.start_mark.line) + 1

    def error(self, message: str, path: Path_, *, key: str | None = None) -> RobotFileError:
        line = self.key_line(path, key) if key is not None else self.line(path)
        return RobotFileError(message, path=self.source, line=line)

    def from_validation(self, exc: msgspec.ValidationError, base: Path_ = (), *,
                        root: type[Spec | BodyPart] | None = RobotFile) -> RobotFileError:
        """A msgspec error (relative to ``base``) as a :class:`RobotFileError` at its line.

        ``root`` is the type decoded at ``base``: an unknown field is told the fields of the
        object it was found in (``None``: the caller lists them itself)."""
        message, where = validation_parts(exc)
        relative = parse_error_path(where) if where else ()
        path = base + relative
        unknown = _UNKNOWN_FIELD.search(message)
        text = f"{message} (at {format_path(path)})" if path else message
        if unknown:
            spec = struct_at(root, relative) if root is not None else None
            if spec is not None:
                text += f"; {spec.what} takes: {', '.join(spec.__struct_fields__)}"
        return self.error(text, path, key=unknown.group(1) if unknown else None)

    def problems(self, data: Any, root: type[Spec]) -> list[RobotFileError]:
        """Every mistake in ``data`` (a file's YAML, loaded) decoded as ``root``, each at its
        line — not only msgspec's first: each field of an object, each item of a list and each
        value of a map is checked on its own. Where every part is right but the whole is not
        (a list too short, a union none of whose members fits), the whole's mistake is told."""
        return self._problems(data, root, (), root)

    def _problems(self, data: Any, kind: Any, path: Path_,
                  root: type[Spec]) -> list[RobotFileError]:
        try:
            msgspec.convert(data, kind, strict=True, builtin_types=YAML_BUILTIN_TYPES)
            return []
        except msgspec.ValidationError as exc:
            whole = exc
        return self._parts(data, kind, path, root) or [self._told(whole, data, path, root)]

    def _parts(self, data: Any, kind: Any, path: Path_,
               root: type[Spec]) -> list[RobotFileError]:
        """The mistakes of ``data``'s parts, each checked alone (none: not a shape whose parts
        can be)."""
        shape, kind = _shape_for(kind, data)
        if isinstance(shape, type) and issubclass(shape, msgspec.Struct):
            fields = {f.encode_name: f for f in msgspec.structs.fields(shape)}
            missing = [name for name, f in fields.items() if f.required and name not in data]
            found, meant = [], set()
            for key in data:
                if key in fields:
                    continue
                # A misspelt required field is one mistake, told with the name it means.
                near = difflib.get_close_matches(str(key), missing, n=1)
                meant.update(near)
                found.append(self.error(
                    f"Object contains unknown field `{key}`"
                    f"{f' (at {format_path(path)})' if path else ''}; "
                    + (f"did you mean `{near[0]}`? " if near else "")
                    + f"{getattr(shape, 'what', 'it')} takes: {', '.join(fields)}",
                    path, key=str(key)))
            for name, field_ in fields.items():
                if name in data:
                    found += self._problems(data[name], field_.type, (*path, name), root)
                elif field_.required and name not in meant:
                    found.append(self.error(
                        f"Object missing required field `{name}`"
                        f"{f' (at {format_path(path)})' if path else ''}", path))
            return found
        if shape is list:
            [item] = typing.get_args(kind) or (Any,)
            return [p for i, value in enumerate(data)
                    for p in self._problems(value, item, (*path, i), root)]
        if shape is dict:
            _, value_kind = typing.get_args(kind) or (Any, Any)
            return [p for key, value in data.items()
                    for p in self._problems(value, value_kind, (*path, str(key)), root)]
        return []

    def _told(self, whole: msgspec.ValidationError, data: Any, path: Path_,
              root: type[Spec]) -> RobotFileError:
        """``whole``, a mistake of the value at ``path``, as a refusal at its line: a single
        value where a list belongs is told how to write it as one."""
        message, where = validation_parts(whole)
        holds = _list_holds(root, path)
        if (holds and (not where or where == "$") and message.startswith("Expected `array`")
                and not isinstance(data, list | dict)):
            written = yaml.safe_dump([data], default_flow_style=True).strip()
            return self.error(f"{format_path(path)} must be a list of {holds}: write {written}",
                              path)
        return self.from_validation(whole, path, root=struct_at(root, path))

    def from_refusal(self, refusal: ParameterError, base: Path_) -> RobotFileError:
        """Parameters refused (:func:`~ubf_async.assembly.registry.checked_params`, of the
        mapping at ``base``) as the same refusal at its line, its field named by its place in
        the file (``devices[0].params.yaw_deg``)."""
        path = base + (parse_error_path(refusal.at) if refusal.at else ())
        unknown = _UNKNOWN_FIELD.search(refusal.problem)
        return self.error(refusal.told_at(format_path(path)), path,
                          key=unknown.group(1) if unknown else None)


YAML_LOADER: Final = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
"""libyaml when PyYAML has it, as msgspec.yaml uses: the same parser, the same messages."""
YAML_BUILTIN_TYPES: Final = (datetime.datetime, datetime.date)
"""What YAML's loader makes that msgspec.yaml.decode takes as it is."""

# Where the parser notices a mistake is often past it: a key without its ':' is noticed on the
# next line, an unclosed quote or bracket at the next token or the end of the file. For these
# the context mark (where the unfinished key, string or collection began) is the mistake's own
# line; for the others (a block that breaks off, a tab) the problem mark is.
_UNFINISHED = ("simple key", "quoted scalar", "flow mapping", "flow sequence")


def yaml_syntax_error(exc: yaml.MarkedYAMLError, text: str, source: str) -> RobotFileError:
    """A YAML parser's error as ``FILE:LINE: not valid YAML: …`` at the mistake's line."""

    def line(mark: yaml.Mark) -> int:
        if not text[mark.index:].strip():
            # Ran out of text: the mistake is on the last line that has any.
            return text[:mark.index].rstrip().count("\n") + 1
        return int(mark.line) + 1

    problem = exc.problem or str(exc)
    context, at, noticed = exc.context, exc.context_mark, exc.problem_mark
    mark: yaml.Mark | None
    if context is not None and at is not None and noticed is not None \
            and context.endswith(_UNFINISHED):
        mark, note = at, (f" ({context}; noticed on line {line(noticed)})"
                          if line(noticed) != line(at) else f" ({context})")
    elif context is not None and at is not None and noticed is not None \
            and line(at) != line(noticed):
        mark, note = noticed, f" ({context} begun on line {line(at)})"
    else:
        mark, note = noticed or at, ""
    return RobotFileError(f"not valid YAML: {problem}{note}", path=source,
                          line=None if mark is None else line(mark))


def first_duplicate_key(root: yaml.Node | None) -> tuple[yaml.ScalarNode, yaml.ScalarNode] | None:
    """The first key (in the text) given twice in one mapping: ``(first, again)``."""
    found: list[tuple[yaml.ScalarNode, yaml.ScalarNode]] = []
    seen: set[int] = set()  # an alias is the node it names: visit each once
    stack = [root] if root is not None else []
    while stack:
        node = stack.pop()
        if id(node) in seen:
            continue
        seen.add(id(node))
        if isinstance(node, yaml.MappingNode):
            keys: dict[tuple[str, str], yaml.ScalarNode] = {}
            for key, value in node.value:
                # A merge key (<<) brings keys that the mapping's own may override.
                if isinstance(key, yaml.ScalarNode) and key.tag != MERGE_TAG:
                    first = keys.setdefault((key.tag, key.value), key)
                    if first is not key:
                        found.append((first, key))
                stack += (key, value)
        elif isinstance(node, yaml.SequenceNode):
            stack += node.value
    return min(found, key=lambda pair: pair[1].start_mark.index, default=None)


MERGE_TAG: Final = "tag:yaml.org,2002:merge"


def struct_at(root: type[Spec | BodyPart], path: Path_) -> type[Spec | BodyPart] | None:
    """The robot-file type of the object at ``path`` in a ``root`` (``None``: not one)."""
    info: msgspec.inspect.Type = msgspec.inspect.type_info(root)
    for part in path:
        step = _step(info, part)
        if step is None:
            return None
        info = step
    found = _struct(info)
    # The body's types (ubf_async.assembly.body) are told alike without deriving from Spec.
    return found if found is not None and (issubclass(found, Spec) or issubclass(
        found, BodyPart)) else None


def _members(info: msgspec.inspect.Type) -> list[msgspec.inspect.Type]:
    while isinstance(info, msgspec.inspect.Metadata):
        info = info.type
    if isinstance(info, msgspec.inspect.UnionType):
        return [m for t in info.types for m in _members(t)]
    return [info]


def _struct(info: msgspec.inspect.Type) -> type[Any] | None:
    return next((m.cls for m in _members(info) if isinstance(m, msgspec.inspect.StructType)),
                None)


def _step(info: msgspec.inspect.Type, part: str | int) -> msgspec.inspect.Type | None:
    for member in _members(info):
        if isinstance(member, msgspec.inspect.StructType) and isinstance(part, str):
            field_ = next((f for f in member.fields if f.encode_name == part), None)
            if field_ is not None:
                return field_.type
        elif isinstance(member, msgspec.inspect.ListType) and isinstance(part, int):
            return member.item_type
        elif isinstance(member, msgspec.inspect.DictType) and isinstance(part, str):
            return member.value_type
    return None


def format_path(path: Path_) -> str:
    """``("tree", "children", 1, "priority")`` → ``tree.children[1].priority``; a map's key
    that is no name is quoted: ``overrides["tree.arbiter"]``."""
    out = ""
    for part in path:
        if isinstance(part, int):
            out += f"[{part}]"
        elif not part.isidentifier():
            out += f"[{json.dumps(part)}]"
        else:
            out += f".{part}" if out else part
    return out


def _list_holds(root: type[Spec], path: Path_) -> str:
    """What the list at ``path`` holds, as the object whose field it is (or whose field's map
    holds it) says in its :attr:`Spec.lists` ("": no such list)."""
    for i in range(len(path) - 1, -1, -1):
        holder = struct_at(root, path[:i])
        if holder is not None:
            return holder.lists.get(str(path[i]), "")
    return ""


def _bare(kind: Any) -> Any:
    """``kind`` without its ``Annotated`` constraints."""
    while typing.get_origin(kind) is Annotated:
        kind = typing.get_args(kind)[0]
    return kind


def _shape_for(kind: Any, data: Any) -> tuple[Any, Any]:
    """What ``data`` is checked as, part by part — a struct class, ``list`` or ``dict``, or
    ``None`` — and the type that says so: the member of a union (``list[int] | SeedRange``)
    that has ``data``'s shape."""
    kind = _bare(kind)
    members = typing.get_args(kind) if isinstance(kind, types.UnionType) \
        or typing.get_origin(kind) is typing.Union else (kind,)
    for member in map(_bare, members):
        origin = typing.get_origin(member) or member
        if isinstance(data, dict) and (origin is dict or (
                isinstance(origin, type) and issubclass(origin, msgspec.Struct))):
            return origin, member
        if isinstance(data, list) and origin is list:
            return list, member
    return None, None


# -- loading ----------------------------------------------------------------------------------


def decode_robot_file(text: str, *, source: str = "<robot file>") -> tuple[RobotFile, Locator]:
    """Decode and type-check a robot file's text (step 1). Raises :class:`RobotFileError`."""
    locator = Locator.parse(text, source=source)
    try:
        spec = msgspec.yaml.decode(text, type=RobotFile)
    except msgspec.ValidationError as exc:
        raise locator.from_validation(exc) from None
    except msgspec.DecodeError as exc:  # what the composer took, the constructor refused
        raise _decode_error(exc, text, source) from None
    _check_depth(spec.tree, locator, ("tree",), 1)
    return spec, locator


def decode_robot_data(data: Any, locator: Locator) -> RobotFile:
    """Step 1 on a robot file's data already read and changed (values replaced at paths:
    :mod:`ubf_async.runs.overrides`): typed and checked as :func:`decode_robot_file` does, a
    mistake reported at the line of ``locator``'s text it came from. Raises
    :class:`RobotFileError`."""
    try:
        # As msgspec.yaml.decode converts what it read: the same checks, the same messages.
        spec = msgspec.convert(data, RobotFile, str_keys=True)
    except msgspec.ValidationError as exc:
        raise locator.from_validation(exc) from None
    _check_depth(spec.tree, locator, ("tree",), 1)
    return spec


def _decode_error(exc: msgspec.DecodeError, text: str, source: str) -> RobotFileError:
    cause = exc.__cause__ or exc.__context__
    if isinstance(cause, yaml.MarkedYAMLError):
        return yaml_syntax_error(cause, text, source)
    return RobotFileError(f"not valid YAML: {cause or exc}", path=source)


def _check_depth(node: NodeSpec, locator: Locator, path: Path_, depth: int) -> None:
    if depth > MAX_DEPTH:
        raise locator.error(f"the tree is nested deeper than {MAX_DEPTH} levels", path)
    for i, child in enumerate(node.children or ()):
        _check_depth(child, locator, (*path, "children", i), depth + 1)


def builtin_robot_files() -> list[str]:
    """Names of the robot files shipped with the package (``mini-whegs`` …)."""
    folder = resources.files("ubf_async") / "robots"
    return sorted(p.name.removesuffix(".yaml") for p in folder.iterdir()
                  if p.name.endswith(".yaml"))


def read_robot_file(name_or_path: str | Path) -> tuple[str, str]:
    """``(text, source)`` of a robot file: a path, or the name of a shipped one."""
    path = Path(name_or_path)
    if path.suffix in (".yaml", ".yml") or path.exists():
        try:
            return path.read_text(encoding="utf-8"), str(path)
        except FileNotFoundError:
            raise RobotFileError("no such file", path=str(path)) from None
        except (OSError, UnicodeDecodeError) as exc:
            raise RobotFileError(f"cannot read it: {exc}", path=str(path)) from None
    name = str(name_or_path)
    if name not in builtin_robot_files():
        raise RobotFileError(f"no such file, nor a shipped robot file (shipped: "
                             f"{', '.join(builtin_robot_files())})", path=name)
    resource = resources.files("ubf_async") / "robots" / f"{name}.yaml"
    return resource.read_text(encoding="utf-8"), f"{name}.yaml"


# -- resolving: names → factories, parameters → typed values, the tree -----------------------


@dataclass(frozen=True, slots=True)
class RemoteSlot:
    """A ``remote:`` node: where a behaviour of another process joins the tree."""

    composite: str
    name: str
    priority: int
    weight: float

    @property
    def key(self) -> str:
        return f"{self.composite}/{self.name}"


@dataclass(frozen=True, slots=True)
class ResolvedDevice:
    """A device of the robot file with its factories found and parameters validated."""

    kind: str
    name: str
    backend: str
    factory: Callable[..., Any]
    params: dict[str, Any]
    backend_factory: Callable[..., Any]
    backend_params: dict[str, Any]

    @property
    def requires_simulator(self) -> str | None:
        return requires_simulator(self.backend_factory)

    @property
    def further_topics(self) -> tuple[Topic[Any], ...]:
        """What its component publishes for its name besides its sensor key
        (:func:`~ubf_async.assembly.devices.further_topics`)."""
        return further_topics(self.factory)

    def build(self, *, context: DeviceContext) -> Component:
        """Build the backend and the device component (launch calls this). A device that
        refuses its backend closes it (:func:`~ubf_async.assembly.devices.build_device`)."""
        backend = self.backend_factory(context=context, **self.backend_params)
        return build_device(self.factory, kind=self.kind, name=self.name, backend=backend,
                            params=self.params, context=context)


@dataclass(slots=True)
class Robot:
    """A robot file, resolved: the tree is built, devices are ready to build."""

    spec: RobotFile
    source: str
    root: Composite
    devices: list[ResolvedDevice]
    locator: Locator
    remotes: list[RemoteSlot] = field(default_factory=list)

    @property
    def name(self) -> str:
        return self.spec.name

    @property
    def body(self) -> BodySpec:
        return self.spec.body

    def mount_x_m(self, kind: str) -> float | None:
        """How far ahead of the centre the first device of ``kind`` is mounted (its ``x_m``,
        given or its factory's default); ``None``: no such device, or it has no mount."""
        for device in self.devices:
            if device.kind == kind:
                given = device.params.get("x_m")
                if given is None:
                    found = _default_of(device.factory, "x_m")
                    given = found if isinstance(found, int | float) else None
                return None if given is None else float(given)
        return None

    def reseeded(self, seed: int | None) -> Robot:
        """The same robot file resolved again with the behaviours drawing from ``seed`` (a
        simulated run's), without reading the file again."""
        return resolve(self.spec, self.locator, seed=seed)

    def remote_config(self) -> dict[str, tuple[int, float]]:
        """``RemoteBehaviors(config=…)``: each declared slot's place."""
        return {slot.key: (slot.priority, slot.weight) for slot in self.remotes}

    def simulators(self) -> list[str]:
        """Simulators the devices' backends need (none for a robot of real devices)."""
        return sorted({d.requires_simulator for d in self.devices if d.requires_simulator})


def _checked_params(factory: Callable[..., Any], params: Mapping[str, Any], *,
                    injected: frozenset[str], locator: Locator, path: Path_,
                    what: str) -> dict[str, Any]:
    """:func:`~ubf_async.assembly.registry.checked_params`, its refusal at the file's line."""
    try:
        return checked_params(factory, params, injected=injected, what=what)
    except ParameterError as refusal:
        raise locator.from_refusal(refusal, path) from None
    except PluginError as exc:  # parameters that cannot be described
        raise locator.error(str(exc), path) from None


def _default_of(factory: Callable[..., Any], parameter: str) -> Any:
    """``factory``'s default for ``parameter`` (``None``: none, or no signature to read)."""
    try:
        found = inspect.signature(factory).parameters.get(parameter)
    except (TypeError, ValueError):
        return None
    return None if found is None or found.default is inspect.Parameter.empty else found.default


def _requires(factory: Callable[..., Any], parameter: str) -> bool:
    """Whether ``factory`` has a keyword parameter ``parameter`` without a default."""
    try:
        found = inspect.signature(factory).parameters.get(parameter)
    except (TypeError, ValueError):  # no signature to read (a builtin): it cannot be told
        return False
    return found is not None and found.default is inspect.Parameter.empty \
        and found.kind in (inspect.Parameter.KEYWORD_ONLY, inspect.Parameter.POSITIONAL_OR_KEYWORD)


def _lookup(registry_get: Callable[[], Any], locator: Locator, path: Path_, key: str) -> Any:
    try:
        return registry_get()
    except MissingExtraError as exc:  # the install's fault, not the file's: its own type
        raise exc.asked_at(locator.error("", path, key=key).where) from None
    except PluginError as exc:
        raise locator.error(str(exc), path, key=key) from None


class TreeBuilder:
    """Builds behaviours and composites from :class:`NodeSpec` nodes."""

    def __init__(self, *, locator: Locator, seed: int | None) -> None:
        self.locator = locator
        self.seed = seed
        self.remotes: list[RemoteSlot] = []

    def _rng(self) -> random.Random:
        # Each consumer gets its own stream, seeded with the run's seed: repeatable runs.
        return random.Random(self.seed)

    def _inject(self, factory: Callable[..., Any]) -> dict[str, Any]:
        return {"rng": self._rng()} if accepts(factory, "rng") else {}

    def arbiter(self, spec: str | ArbiterSpec, path: Path_) -> Any:
        kind, params = (spec, {}) if isinstance(spec, str) else (spec.type, spec.params)
        at = path if isinstance(spec, str) else (*path, "type")
        factory = _lookup(lambda: ARBITERS.get(kind), self.locator, at, "arbiter")
        values = _checked_params(factory, params, injected=INJECTED_TREE, locator=self.locator,
                                 path=(*path, "params"), what=f"arbiter {kind!r}")
        try:
            return factory(**self._inject(factory), **values)
        except (ValueError, TypeError, LookupError) as exc:  # at its parameters' line
            raise self.locator.error(f"arbiter {kind!r}: {exc}",
                                     (*path, "params") if params else path) from None

    def behavior(self, node: NodeSpec, path: Path_) -> Behavior:
        assert node.behavior is not None
        ref = node.behavior
        factory = _lookup(lambda: BEHAVIORS.get(ref), self.locator, path, "behavior")
        values = _checked_params(factory, node.params, injected=INJECTED_TREE,
                                 locator=self.locator, path=(*path, "params"),
                                 what=f"behaviour {ref!r}")
        # The file's name if it gives one, else the factory's own (its `name` default, or
        # whatever it names the behaviour); only a factory that requires a name gets the one
        # it is referenced by.
        extra = self._inject(factory)
        if node.name is not None and accepts(factory, "name"):
            extra["name"] = node.name
        elif node.name is None and _requires(factory, "name"):
            extra["name"] = (ref.rpartition(":")[2].rpartition(".")[2] if is_reference(ref)
                             else ref)
        try:
            made = factory(**extra, **values)
        except (ValueError, TypeError, LookupError) as exc:  # at its parameters' line
            raise self.locator.error(f"behaviour {ref!r}: {exc}",
                                     (*path, "params") if node.params else path) from None
        if not isinstance(made, Behavior):
            raise self.locator.error(
                f"behaviour {ref!r} made a {type(made).__name__}, not a "
                f"ubf_async.core.behavior.Behavior", path, key="behavior")
        if node.name is not None and "name" not in extra:
            made.name = node.name  # a factory that takes no name still gets the file's
        return made

    def composite(self, node: NodeSpec, path: Path_) -> Composite:
        assert node.arbiter is not None and node.name is not None
        arbiter = self.arbiter(node.arbiter, (*path, "arbiter"))
        children: list[Child] = []
        seen: dict[str, int] = {}
        for i, child_spec in enumerate(node.children or ()):
            at = (*path, "children", i)
            if child_spec.kind == "remote":
                assert child_spec.remote is not None
                label = child_spec.remote
                self._unique(label, seen, at, i)
                self.remotes.append(RemoteSlot(node.name, label, child_spec.priority,
                                               child_spec.weight))
                continue
            behavior = self.node(child_spec, at)
            self._unique(behavior.name, seen, at, i)
            children.append(Child(behavior, child_spec.priority, child_spec.weight))
        try:
            return Composite(name=node.name, arbiter=arbiter, children=children)
        except (ValueError, TypeError) as exc:
            raise self.locator.error(f"composite {node.name!r}: {exc}", path) from None

    def _unique(self, name: str, seen: dict[str, int], path: Path_, index: int) -> None:
        if name in seen:
            raise self.locator.error(
                f"duplicate child name {name!r} (also child {seen[name]}); names must be "
                f"unique within a composite: give one a `name`", path)
        seen[name] = index

    def node(self, node: NodeSpec, path: Path_) -> Behavior:
        if node.kind == "composite":
            return self.composite(node, path)
        if node.kind == "behavior":
            return self.behavior(node, path)
        raise self.locator.error("a remote slot must be the child of a composite", path)


def _resolve_device(spec: DeviceSpec, locator: Locator, path: Path_) -> ResolvedDevice:
    factory = _lookup(lambda: DEVICES.get(spec.kind), locator, path, "kind")
    params = _checked_params(factory, spec.params, injected=DEVICE_INJECTED, locator=locator,
                             path=(*path, "params"), what=device_label(spec.kind, spec.name))
    if is_reference(spec.kind) and not is_reference(spec.backend):
        raise locator.error(f"a device kind given as a reference ({spec.kind!r}) needs its "
                            f"backend as a 'module:factory' reference too", path, key="backend")
    backend = _lookup(lambda: get_backend(spec.kind, spec.backend), locator, path, "backend")
    backend_params = _checked_params(backend, spec.backend_params, injected=BACKEND_INJECTED,
                                     locator=locator, path=(*path, "backend_params"),
                                     what=backend_label(spec.kind, spec.backend))
    return ResolvedDevice(kind=spec.kind, name=spec.name, backend=spec.backend, factory=factory,
                          params=params, backend_factory=backend, backend_params=backend_params)


def _check_body(spec: RobotFile, locator: Locator) -> None:
    """The body as a whole, at the line of the field it names."""
    for where, message in body_problems(spec.body):
        raise locator.error(f"body: {message}", ("body", *where))


def _check_mount(device: ResolvedDevice, body: BodySpec, locator: Locator,
                 path: Path_) -> None:
    """A mounted device (its factory takes ``x_m`` and ``y_m``) placed on the body's
    footprint: the values the file gives, else the factory's defaults."""
    if not all(accepts(device.factory, name) for name in MOUNT_FIELDS):
        return
    mount = {name: device.params.get(name, _default_of(device.factory, name))
             for name in MOUNT_FIELDS}
    if any(not isinstance(value, int | float) for value in mount.values()):
        return
    for name, message in mount_problems(mount, body):
        given = name in device.params
        raise locator.error(f"{device_label(device.kind, device.name)}: {message}",
                            (*path, "params", name) if given else path)


def _check_fusions(spec: RobotFile, locator: Locator) -> None:
    """Each fused source a ``camera/`` name no device has, of two or more of the file's
    cameras, at the line of the name or camera at fault."""
    cameras = {f"camera/{d.name}" for d in spec.devices if d.kind == "camera"}
    devices = {f"{d.kind}/{d.name}" for d in spec.devices}
    for name, sources in spec.controller.fuse.items():
        path: Path_ = ("controller", "fuse")
        if not name.startswith("camera/") or name in devices:
            why = "a device's own" if name in devices else "not a camera/NAME source"
            raise locator.error(f"controller.fuse: {name!r} is {why}: name the fused source "
                                f"camera/NAME after no device (camera/both)", path, key=name)
        for i, source in enumerate(sources):
            if source not in cameras:
                raise locator.error(f"controller.fuse[{name!r}]: {source!r} is not a camera of "
                                    f"this file (cameras: {', '.join(sorted(cameras)) or 'none'})",
                                    (*path, name, i))
        try:
            CameraFusion(name, tuple(sources))
        except ValueError as exc:
            raise locator.error(f"controller.fuse: {exc}", (*path, name)) from None
    for field_name in ("sync_source", "trigger"):
        waits_on = getattr(spec.controller, field_name)
        if waits_on in spec.controller.fuse:
            raise locator.error(f"controller.{field_name}: {waits_on!r} is fused in the state, "
                                f"no sample of it arrives to wait on: name one of its cameras",
                                ("controller", field_name))


def resolve(spec: RobotFile, locator: Locator, *, seed: int | None = None) -> Robot:
    """Step 2: look every name up, validate every parameter, build the tree."""
    _check_body(spec, locator)
    devices: list[ResolvedDevice] = []
    seen: dict[tuple[str, str], int] = {}
    for i, device in enumerate(spec.devices):
        path: Path_ = ("devices", i)
        if (device.kind, device.name) in seen:
            raise locator.error(f"duplicate device {device.kind}/{device.name} (also "
                                f"devices[{seen[device.kind, device.name]}])", path)
        seen[device.kind, device.name] = i
        devices.append(_resolve_device(device, locator, path))
        _check_mount(devices[-1], spec.body, locator, path)
    _check_fusions(spec, locator)
    if spec.tree.kind != "composite":
        raise locator.error("the tree's root must be a composite (`name`, `arbiter`, "
                            "`children`)", ("tree",))
    builder = TreeBuilder(locator=locator, seed=spec.seed if seed is None else seed)
    root = builder.composite(spec.tree, ("tree",))
    if spec.ros2 is not None and not any(s.name == spec.ros2.slot for s in builder.remotes):
        raise locator.error(f"ros2: slot {spec.ros2.slot!r} is not a `remote:` slot of the tree "
                            f"(its Twists vote there; docs/ros2.md)", ("ros2",), key="slot")
    return Robot(spec=spec, source=locator.source, root=root, devices=devices,
                 locator=locator, remotes=builder.remotes)


def load_robot(name_or_path: str | Path = DEFAULT_ROBOT_FILE, *,
               seed: int | None = None) -> Robot:
    """Read, decode and resolve a robot file (a path or a shipped name).

    ``seed`` overrides the file's (a simulated run passes its own). Raises
    :class:`RobotFileError` (a :class:`~ubf_async.errors.ConfigurationError`).
    """
    text, source = read_robot_file(name_or_path)
    return load_robot_text(text, source=source, seed=seed)


def load_robot_text(text: str, *, source: str = "<robot file>",
                    seed: int | None = None) -> Robot:
    spec, locator = decode_robot_file(text, source=source)
    return resolve(spec, locator, seed=seed)


def load_tree_fragment(text: str, *, source: str = "<tree>",
                       seed: int | None = None) -> tuple[Composite, list[RemoteSlot]]:
    """A tree from a robot-file fragment: the ``tree:`` node alone, or ``{tree: …}``.

    Used to replace a running robot's tree (``inspector tree load``). Raises
    :class:`RobotFileError`.
    """
    locator = Locator.parse(text, source=source)
    try:
        data = msgspec.yaml.decode(text)
    except msgspec.DecodeError as exc:
        raise _decode_error(exc, text, source) from None
    base: Path_ = ("tree",) if isinstance(data, dict) and "tree" in data else ()
    if base:
        data = data["tree"]
    try:
        node = msgspec.convert(data, NodeSpec)
    except msgspec.ValidationError as exc:
        raise locator.from_validation(exc, base, root=NodeSpec) from None
    if node.kind != "composite":
        raise locator.error("a tree's root must be a composite (`name`, `arbiter`, "
                            "`children`)", base)
    _check_depth(node, locator, base, 1)
    builder = TreeBuilder(locator=locator, seed=seed)
    return builder.composite(node, base), builder.remotes


def build_arbiter(spec: str | Mapping[str, Any], *, source: str = "<arbiter>",
                  seed: int | None = None) -> Any:
    """An arbiter from a name or ``{type, params}`` (live changes use this); an arbiter that
    takes ``rng`` draws from ``seed``, as in a robot file."""
    text = json.dumps(spec)
    locator = Locator.parse(text, source=source)
    try:
        typed = msgspec.convert(spec, str | ArbiterSpec)
    except msgspec.ValidationError as exc:
        raise locator.from_validation(exc, root=ArbiterSpec) from None
    return TreeBuilder(locator=locator, seed=seed).arbiter(typed, ())


# -- the JSON Schema --------------------------------------------------------------------------


def robot_file_schema() -> dict[str, Any]:
    """The JSON Schema of robot files, generated from :class:`RobotFile`."""
    schema: dict[str, Any] = _clean_descriptions(msgspec.json.schema(RobotFile))
    schema["$schema"] = "https://json-schema.org/draft/2020-12/schema"
    schema["title"] = "ubf_async robot file"
    schema["description"] = ("One robot: devices, controller and behaviour tree "
                             "(docs/robot-file.md).")
    return schema


def _clean_descriptions(node: Any) -> Any:
    """Every ``description`` in ``node`` as :func:`inspect.cleandoc` gives it: msgspec copies
    a class's docstring raw up to 0.22 and dedents it from 0.23 (and Python 3.13 dedents
    docstrings itself), so the schema is made the same whichever built it."""
    if isinstance(node, dict):
        return {key: inspect.cleandoc(value) if key == "description" and isinstance(value, str)
                else _clean_descriptions(value) for key, value in node.items()}
    if isinstance(node, list):
        return [_clean_descriptions(value) for value in node]
    return node


def schema_text() -> str:
    return json.dumps(robot_file_schema(), indent=2, sort_keys=True) + "\n"


def shipped_schema_text() -> str:
    return (resources.files("ubf_async") / SCHEMA_RESOURCE).read_text(encoding="utf-8")


__all__ = [
    "ArbiterSpec", "BodySpec", "ControllerSpec", "DeviceSpec", "Locator", "NodeSpec", "RemoteSlot",
    "RemotesSpec", "ResolvedDevice", "Robot", "RobotFile", "RobotFileError",
    "build_arbiter", "decode_robot_data", "decode_robot_file", "load_robot", "load_robot_text",
    "load_tree_fragment", "resolve", "robot_file_schema",
]

