"""A robot file with values replaced at paths::

    load_robot_with("mini-whegs", {"tree.children[0].params.period_s": 6,
                                   "tree.arbiter": "UtilityFusion"})

A path names a place in the robot file as its error messages do: keys joined by ``.``, list
items by ``[i]``, a key that is not a plain name in quotes (``controller.stale_after_s
["camera/front"]``). Every container on the way must be in the file. The last key may be new
where the file could have it: a field of the robot-file type at that place (the ``priority`` of
a tree node that gives none, ``controller.rate_hz``), or any key of a ``params`` or
``backend_params`` map — then the factory's signature decides, as for a parameter written in
the file.

The changed robot is checked exactly as the file itself is (decoded, every name looked up,
every parameter validated against its factory's signature), so a value outside a parameter's
range is refused as the file would be: a :class:`~ubf_async.errors.RobotFileError` at the line
of the value replaced, naming the overrides.
"""

from __future__ import annotations

import copy
import json
import re
from collections import Counter
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import yaml

from ubf_async.assembly.robotfile import (
    YAML_LOADER,
    Locator,
    Path_,
    Robot,
    RobotFile,
    decode_robot_data,
    format_path,
    parse_error_path,
    read_robot_file,
    resolve,
    struct_at,
)
from ubf_async.errors import OverridePathError, RobotFileError

PATH_SYNTAX = re.compile(
    r'[A-Za-z_][A-Za-z0-9_]*(?:\.[A-Za-z_][A-Za-z0-9_]*|\[\d+\]|\["[^"\]]*"\])*')
"""``tree.children[1].params.period_s``, ``controller.stale_after_s["camera/front"]``."""
OPEN_MAPS = frozenset({"params", "backend_params"})
"""Maps whose keys a factory's signature checks: an override may add a key to them."""


def parse_path(text: str) -> Path_:
    """``tree.children[1].params.period_s`` → ``("tree", "children", 1, "params",
    "period_s")``. Raises :class:`ValueError` for anything else (parse_error_path, which reads
    msgspec's paths, would skip what it does not understand)."""
    if not PATH_SYNTAX.fullmatch(text):
        raise ValueError(f"not a path into a robot file: {text!r} (expected names joined by "
                         f"'.' and list items as [i], e.g. tree.children[1].params.period_s)")
    return parse_error_path("$." + text)


def readable_name(data: Any, path: str) -> str:
    """``tree.children[0].params.period_s`` → ``search.period_s``: the path from the last
    named object it passes through in the robot file's ``data`` (a tree node by its ``name``,
    ``behavior`` or ``remote``, a device as ``KIND/NAME``), without ``params``; the path
    itself where none is named."""
    node, named, rest = data, "", list[str | int]()
    for part in parse_path(path):
        if isinstance(part, int):
            node = node[part] if isinstance(node, list) and 0 <= part < len(node) else None
        else:
            node = node.get(part) if isinstance(node, dict) else None
        name = next((node[k] for k in ("name", "behavior", "remote")
                     if isinstance(node.get(k), str)), None) if isinstance(node, dict) else None
        if name is not None and isinstance(node, dict):
            kind = node.get("kind")
            named, rest = (f"{kind}/{name}" if isinstance(kind, str) else name), []
        elif part != "params":
            rest.append(part)
    if not named:
        return path
    tail = format_path(tuple(rest))
    return named + ("" if not tail else tail if tail.startswith("[") else f".{tail}")


def readable_names(data: Any, paths: Sequence[str]) -> dict[str, str]:
    """:func:`readable_name` of each of ``paths``; a path whose name another path's name is
    too keeps its path."""
    names = {path: readable_name(data, path) for path in paths}
    taken = Counter(names.values())
    return {path: name if taken[name] == 1 else path for path, name in names.items()}


def describe(overrides: Mapping[str, Any]) -> str:
    """``tree.arbiter = "UtilityFusion", …`` (values as JSON, long ones cut)."""
    def short(value: Any) -> str:
        text = json.dumps(value, default=str, ensure_ascii=False)
        return text if len(text) <= 60 else text[:57] + "..."
    return ", ".join(f"{path} = {short(value)}" for path, value in overrides.items())


def _may_add(path: Path_) -> bool:
    """Whether the last key of ``path`` may be new: a parameter, or a field the robot-file
    type has there."""
    parent, key = path[:-1], path[-1]
    if parent and parent[-1] in OPEN_MAPS:
        return True
    spec = struct_at(RobotFile, parent)
    return spec is not None and key in spec.__struct_fields__


def _missing(node: dict[str, Any], at: Path_, key: str) -> str:
    spec = struct_at(RobotFile, at)
    where = format_path(at) or "the file"
    if spec is not None and key in spec.__struct_fields__:  # a place on the way, not given
        return (f"no `{key}` in {where}: give it in the file, or override "
                f"{format_path((*at, key))} as a whole")
    if spec is not None:
        return f"no `{key}` in {where} ({spec.what} takes: {', '.join(spec.__struct_fields__)})"
    return f"no `{key}` in {where}" + (f" (it has: {', '.join(map(str, node))})" if node else "")


def apply_override(data: Any, text: str, value: Any, *, locator: Locator) -> None:
    """Replace the value at path ``text`` of ``data`` (a robot file's data) with ``value``,
    in place. Raises :class:`OverridePathError` at the line of the deepest place found."""
    try:
        path = parse_path(text)
    except ValueError as exc:
        raise OverridePathError(f"override: {exc}", path=locator.source) from None
    node = data
    for depth, part in enumerate(path):
        at, last = path[:depth], depth == len(path) - 1
        problem = None
        if isinstance(part, int):
            if not isinstance(node, list):
                problem = f"{format_path(at) or 'the file'} is not a list"
            elif not 0 <= part < len(node):
                problem = f"{format_path(at)} has {len(node)} item(s), [0] to [{len(node) - 1}]"
        elif not isinstance(node, dict):
            problem = f"{format_path(at) or 'the file'} is not a mapping"
        elif part not in node and not (last and _may_add(path)):
            problem = _missing(node, at, part)
        if problem is not None:
            found = locator.error(f"override {text}: {problem}", at)
            raise OverridePathError(found.message, path=found.path, line=found.line)
        if last:
            node[part] = copy.deepcopy(value)
        else:
            node = node[part]


def robot_data_with(text: str, overrides: Mapping[str, Any], *,
                    source: str = "<robot file>") -> tuple[Any, Locator]:
    """A robot file's ``text`` as data with ``overrides`` (path → value, applied in order),
    not decoded yet, and the :class:`Locator` of its lines. Raises :class:`RobotFileError`:
    :class:`OverridePathError` for a path that leads nowhere in the file."""
    locator = Locator.parse(text, source=source)
    try:
        data = yaml.load(text, Loader=YAML_LOADER)
    except yaml.YAMLError as exc:  # what composing took, constructing refused (a bad tag)
        raise RobotFileError(f"not valid YAML: {exc}", path=source) from None
    for path, value in overrides.items():
        apply_override(data, path, value, locator=locator)
    return data, locator


def load_robot_text_with(text: str, overrides: Mapping[str, Any], *,
                         source: str = "<robot file>", seed: int | None = None) -> Robot:
    """A robot file's ``text`` with ``overrides`` (path → value, applied in order), decoded and
    resolved as :func:`~ubf_async.assembly.robotfile.load_robot_text` does. Raises
    :class:`RobotFileError` (``SOURCE:LINE: …``): :class:`OverridePathError` for a path that
    leads nowhere in the file."""
    data, locator = robot_data_with(text, overrides, source=source)
    try:
        return resolve(decode_robot_data(data, locator), locator, seed=seed)
    except RobotFileError as exc:
        if not overrides:
            raise
        raise RobotFileError(f"with {describe(overrides)}: {exc.message}", path=exc.path,
                             line=exc.line) from None


def load_robot_with(robot_file: str | Path, overrides: Mapping[str, Any], *,
                    seed: int | None = None) -> Robot:
    """The robot file ``robot_file`` (a path or a shipped robot's name) with ``overrides``;
    ``seed`` overrides the file's, as :func:`~ubf_async.assembly.robotfile.load_robot`'s
    does. Raises :class:`RobotFileError`."""
    text, source = read_robot_file(robot_file)
    return load_robot_text_with(text, overrides, source=source, seed=seed)


__all__ = ["OverridePathError", "apply_override", "describe", "load_robot_text_with",
           "load_robot_with", "parse_path", "robot_data_with"]
