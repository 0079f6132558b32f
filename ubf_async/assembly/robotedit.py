"""Setting one parameter of a robot file's device in the file's text, the rest byte for byte.

A tool that measures what a robot file holds (the camera's colour range:
``python -m components.camera.calibrate``) writes it back into the user's file, whose
comments, order and layout are the user's. So the edit is a targeted one, found through the
YAML parser's node marks: a value written as a scalar or in flow style
(``{lo: [90, 20, 40], hi: [255, 120, 160]}``) has its text replaced; a block mapping or list
is edited entry by entry; a key its mapping lacks is added in the mapping's style (``, key:
value`` after a flow mapping's last entry, a line at a block mapping's indentation after its
last). The result must read as the file's data with that one value changed, and load as a
robot file: anything else (an alias shared with other places, a layout the edit cannot follow)
is refused with a :class:`~ubf_async.errors.RobotFileError` at the value's line, which says
what to write there by hand.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Any

import yaml

from ubf_async.assembly.robotfile import load_robot_text
from ubf_async.errors import RobotFileError

__all__ = ["flow_yaml", "set_device_param"]

Edit = tuple[int, int, str]
"""Characters ``start:end`` of the text replaced by a string (an insertion when equal)."""


class _Refused(Exception):
    def __init__(self, why: str, node: yaml.Node) -> None:
        super().__init__(why)
        self.why = why
        self.node = node
        """Where in the value the layout stops the edit (the refusal points at its key)."""


def flow_yaml(value: Any) -> str:
    """``value`` in YAML's flow style on one line: ``{lo: [90, 20, 40], hi: [...]}``."""
    text = yaml.safe_dump(value, default_flow_style=True, sort_keys=False, width=1 << 30)
    return text.removesuffix("...\n").strip()


def set_device_param(text: str, *, kind: str, name: str, key: str, value: Any,
                     source: str = "<robot file>") -> str:
    """``text`` with device ``kind``/``name``'s ``params.<key>`` set to ``value`` (written in
    flow style), everything else as it was; a :class:`RobotFileError` when the file's layout
    does not allow that edit, or the device is not in it."""
    root = yaml.compose(text, Loader=yaml.SafeLoader)
    index, device = _device(root, kind, name, source)
    where = f"devices[{index}].params.{key}"
    params = _value(device, "params")
    # Where the value is (its key), or would be: what a refusal points at.
    there = _key(params, key) or _key(device, "params") or device
    edits: list[Edit] = []
    try:
        if params is None:
            _insert(text, device, "params", {key: value}, edits)
        elif not isinstance(params, yaml.MappingNode):
            raise _Refused("its params are not a mapping", params)
        elif (entry := _value(params, key)) is None:
            _insert(text, params, key, value, edits)
        else:
            _replace(entry, value, edits)
    except _Refused as refused:
        raise _refusal(refused.why, there, where, value, source) from None
    edited = _applied(text, edits)
    expected = _plain(yaml.safe_load(text))
    expected["devices"][index].setdefault("params", {})[key] = value
    if _plain(yaml.safe_load(edited)) != _plain(expected):  # an alias, a layout misread
        raise _refusal("the edit would change more than that value", there, where, value,
                       source)
    load_robot_text(edited, source=source)  # never a file that does not load
    return edited


def _plain(data: Any) -> Any:
    """``data`` as plain JSON values, nothing shared (an alias's copies compared apart)."""
    return json.loads(json.dumps(data, default=str))


def _device(root: yaml.Node | None, kind: str, name: str,
            source: str) -> tuple[int, yaml.MappingNode]:
    devices = _value(root, "devices") if isinstance(root, yaml.MappingNode) else None
    if isinstance(devices, yaml.SequenceNode):
        for index, device in enumerate(devices.value):
            if isinstance(device, yaml.MappingNode) and (
                    _scalar(device, "kind"), _scalar(device, "name")) == (kind, name):
                return index, device
    raise RobotFileError(f"no device {kind}/{name} in its devices", path=source)


def _entry(mapping: yaml.Node | None, key: str) -> tuple[yaml.Node, yaml.Node] | None:
    if isinstance(mapping, yaml.MappingNode):
        for key_node, value_node in mapping.value:
            if isinstance(key_node, yaml.ScalarNode) and key_node.value == key:
                return key_node, value_node
    return None


def _key(mapping: yaml.Node | None, key: str) -> yaml.Node | None:
    entry = _entry(mapping, key)
    return entry[0] if entry is not None else None


def _value(mapping: yaml.Node | None, key: str) -> yaml.Node | None:
    entry = _entry(mapping, key)
    return entry[1] if entry is not None else None


def _scalar(mapping: yaml.Node, key: str) -> str | None:
    node = _value(mapping, key)
    return node.value if isinstance(node, yaml.ScalarNode) else None


def _replace(node: yaml.Node, value: Any, edits: list[Edit]) -> None:
    """``node``'s text made to read ``value``: a scalar or flow value as a whole, a block
    mapping or list entry by entry."""
    if isinstance(node, yaml.ScalarNode) and node.style in ("|", ">"):
        raise _Refused("it is a block of text", node)
    if isinstance(node, yaml.ScalarNode) or (isinstance(node, yaml.CollectionNode)
                                             and node.flow_style):
        written = flow_yaml(value)
        start, end = node.start_mark.index, node.end_mark.index
        edits.append((start, end, written if end > start else " " + written))  # `key:` alone
    elif isinstance(node, yaml.MappingNode) and isinstance(value, Mapping):
        extra = [k.value for k, _ in node.value if k.value not in value]
        if extra:
            raise _Refused(f"it also sets {', '.join(extra)}", node)
        for key, item in value.items():
            entry = _value(node, key)
            if entry is None:
                raise _Refused(f"it lacks {key}", node)
            _replace(entry, item, edits)
    elif isinstance(node, yaml.SequenceNode) and isinstance(value, list | tuple) \
            and len(node.value) == len(value):
        for entry, item in zip(node.value, value, strict=True):
            _replace(entry, item, edits)
    else:
        raise _Refused("it is written in block style with another shape", node)


def _insert(text: str, mapping: yaml.MappingNode, key: str, value: Any,
            edits: list[Edit]) -> None:
    """``key: value`` added to ``mapping``, after its last entry, in the mapping's style."""
    entry = f"{key}: {flow_yaml(value)}"
    if mapping.flow_style:
        if mapping.value:
            end = mapping.value[-1][1].end_mark.index
            edits.append((end, end, f", {entry}"))
        else:
            close = mapping.end_mark.index - 1  # its `}`
            edits.append((close, close, entry))
        return
    indent = mapping.value[0][0].start_mark.column
    last = _last_leaf(mapping)
    line_end = text.find("\n", last.end_mark.index)
    at = len(text) if line_end < 0 else line_end
    edits.append((at, at, "\n" + " " * indent + entry))


def _last_leaf(node: yaml.Node) -> yaml.Node:
    """The node written last inside ``node``: its marks end on the block's last line."""
    while isinstance(node, yaml.MappingNode | yaml.SequenceNode) and not node.flow_style \
            and node.value:
        last = node.value[-1]
        node = last[1] if isinstance(last, tuple) else last
    if isinstance(node, yaml.ScalarNode) and node.style in ("|", ">"):
        raise _Refused("the mapping ends in a block of text", node)
    return node


def _applied(text: str, edits: list[Edit]) -> str:
    for start, end, replacement in sorted(edits, reverse=True):
        text = text[:start] + replacement + text[end:]
    return text


def _refusal(why: str, node: yaml.Node, where: str, value: Any,
             source: str) -> RobotFileError:
    return RobotFileError(f"cannot set {where} in the file's text ({why}): write "
                          f"{where.rsplit('.', 1)[1]}: {flow_yaml(value)} there by hand",
                          path=source, line=node.start_mark.line + 1)
