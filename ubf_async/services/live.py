"""Live tree changes: another process reads or changes the running behaviour tree.

The robot's :class:`TreeService` component answers queries on ``ubf/<robot>/tree``
(documented in ``docs/protocol.md``, section *Live tree changes*). A request is the usual
msgpack envelope with schema ``"tree.request"``; its ``data`` is one operation:

* ``{"op": "show"}`` — the current tree;
* ``{"op": "set_arbiter", "composite": NAME, "arbiter": "HighestPriority" | {"type": ...,
  "params": {...}}}`` — swap a composite's arbiter;
* ``{"op": "set_child", "composite": NAME, "child": NAME, "priority": int, "weight": float}``
  — change a child's priority and/or weight;
* ``{"op": "load", "tree": "<YAML: a robot-file tree fragment>"}`` — replace the whole tree.

The reply (schema ``"tree.reply"``) is ``{"ok": true, "op": ..., "version": N, "tree": {...}}``
with the tree as it is after the request, or ``{"ok": false, "op": ..., "version": N,
"error": "..."}``. ``version`` counts the changes applied since the service started.

How a change applies: the query is handed to the event loop, where the controller ticks, so a
request is handled between two ticks and the next tick (and its trace) sees the whole change.
Everything is built and validated first — the arbiter by :func:`~ubf_async.assembly.robotfile.
build_arbiter` and then against the composite's children (:meth:`Arbiter.validate
<ubf_async.core.behavior.Arbiter.validate>` through the composite), a new tree by
:func:`~ubf_async.assembly.robotfile.load_tree_fragment` and, if the running tree is set up, the new
tree's ``setup()`` — and only then is anything switched. A refused request gets an error reply
and leaves the running tree exactly as it was; a malformed one is also counted and logged. The
service keeps answering either way.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Iterable, Mapping
from typing import Any

import msgspec

from ubf_async import throttle
from ubf_async.assembly.robotfile import (
    RemoteSlot,
    build_arbiter,
    load_tree_fragment,
)
from ubf_async.core.behavior import Behavior, Composite
from ubf_async.errors import ConfigurationError, ProtocolError, TreeChangeError
from ubf_async.runtime.bus import Bus
from ubf_async.runtime.component import Component
from ubf_async.runtime.controller import Controller
from ubf_async.services.remote import RemoteBehavior, RemoteBehaviors
from ubf_async.wire.protocol import decode, encode
from ubf_async.wire.topics import MAX_TREE_DEPTH as MAX_TREE_DEPTH
from ubf_async.wire.topics import TREE_OPS, TREE_REPLY, TREE_REQUEST, TreeRequest

log = logging.getLogger(__name__)

REQUEST_SCHEMA = TREE_REQUEST.schema
REPLY_SCHEMA = TREE_REPLY.schema
OPS = tuple(TREE_OPS)
MAX_ERROR_CHARS = 2000


def encode_request(data: Mapping[str, Any], *, seq: int = 1, stamp_ns: int = 0) -> bytes:
    """A ``"tree.request"`` payload (raises :class:`ProtocolError` for a malformed one)."""
    return encode(TREE_REQUEST, data, stamp_ns=stamp_ns, seq=seq)


def decode_reply(payload: bytes) -> dict[str, Any]:
    """The data of a ``"tree.reply"`` payload as plain data (raises :class:`ProtocolError`)."""
    data = decode(payload, topic=TREE_REPLY).data
    reply: dict[str, Any] = msgspec.msgpack.decode(msgspec.msgpack.encode(data))
    return reply


async def request(bus: Bus, data: Mapping[str, Any], *, timeout_s: float = 5.0,
                  retry_s: float = 0.05) -> dict[str, Any]:
    """Send one request to the robot's tree service and return the reply's data.

    A query that nothing answers is sent again every ``retry_s`` until ``timeout_s`` has
    passed (a freshly connected session may not know the robot's queryable yet; unanswered,
    nothing was applied). Raises :class:`TimeoutError` if no robot answered,
    :class:`~ubf_async.errors.QueryError` if it answered with an error instead of a reply, and
    :class:`ProtocolError` for a malformed request or reply. A refusal is a reply: check
    ``reply["ok"]``."""
    payload = encode_request(data, stamp_ns=bus.clock.now_ns())
    key = TREE_REQUEST.key(bus.keys)
    deadline = time.monotonic() + timeout_s
    while True:
        remaining = deadline - time.monotonic()
        try:
            answer = await bus.query(key, payload, timeout_s=max(remaining, retry_s))
        except TimeoutError:
            if time.monotonic() + retry_s >= deadline:
                raise TimeoutError(f"no robot answered on {key} within {timeout_s:g}s") from None
            await asyncio.sleep(retry_s)
            continue
        return decode_reply(answer)


# ---------------------------------------------------------------------------------------------
# The tree as data, and back as text


def tree_data(behavior: Behavior, *, priority: int | None = None,
              weight: float | None = None) -> dict[str, Any]:
    """``behavior`` and everything under it as nested plain data (a reply's ``tree``)."""
    if isinstance(behavior, Composite):
        kind = "composite"
    elif isinstance(behavior, RemoteBehavior):
        kind = "remote"
    else:
        kind = "behavior"
    node: dict[str, Any] = {"name": behavior.name, "kind": kind,
                            "type": type(behavior).__name__}
    if priority is not None:
        node["priority"] = priority
        node["weight"] = float(weight if weight is not None else 1.0)
    if isinstance(behavior, Composite):
        node["arbiter"] = behavior.arbiter.describe()
        node["children"] = [tree_data(c.behavior, priority=c.priority, weight=c.weight)
                            for c in behavior.children]
    return node


def render_tree_data(node: Mapping[str, Any], indent: int = 0) -> str:
    """A reply's ``tree`` as indented text, like the robot prints its tree at start."""
    pad = "  " * indent
    if node.get("kind") == "composite":
        head = f"{pad}{node['name']} <{node.get('arbiter', '?')}>"
    elif node.get("kind") == "remote":
        head = f"{pad}{node['name']} (remote)"
    else:
        head = f"{pad}{node['name']} ({node.get('type', 'behaviour')})"
    if "priority" in node:
        head += f" [p={node['priority']} w={node.get('weight', 1.0):g}]"
    lines = [head]
    lines.extend(render_tree_data(child, indent + 1) for child in node.get("children") or ())
    return "\n".join(lines)


# ---------------------------------------------------------------------------------------------
# The robot's side


class TreeService(Component):
    """Answers ``ubf/<robot>/tree``: shows and changes the controller's tree between ticks.

    * ``controller`` — whose ``root`` is the running tree; ``load`` replaces it;
    * ``remotes`` — the robot's :class:`~ubf_async.services.remote.RemoteBehaviors`, if any: on
      ``load`` its ``root`` follows, the remote children of the old tree move to the
      composite of the same name in the new one (or are dropped, with a warning, when it has
      none or refuses them), and the fragment's ``remote:`` slots replace the old tree's in
      its ``config``;
    * ``seed`` — seed of the random choices of the behaviours a ``load`` builds;
    * ``slots`` — the ``remote:`` slots of the tree the robot started with (launch passes
      ``robot.remotes``), so a ``load`` knows which ``config`` entries were the old tree's.

    Hooks: :meth:`run` declares the queryable and waits; :meth:`on_query` runs on the event
    loop for each query. :meth:`show`, :meth:`set_arbiter`, :meth:`set_child` and
    :meth:`load` do the work and can be called directly (on the loop); they raise
    :class:`~ubf_async.errors.TreeChangeError` and leave the tree untouched when they refuse.
    """

    def __init__(
        self,
        *,
        bus: Bus,
        controller: Controller,
        remotes: RemoteBehaviors | None = None,
        seed: int | None = None,
        slots: Iterable[RemoteSlot] = (),
        name: str = "tree",
        **component_options: float,
    ) -> None:
        super().__init__(bus=bus, name=name, **component_options)
        self.controller = controller
        self.remotes = remotes
        self.seed = seed
        self.slots: list[RemoteSlot] = list(slots)
        self.version = 0
        """Changes applied since the service was made."""
        self.malformed: dict[str, int] = {}
        """Requests that failed to decode, per key."""
        self.refused = 0
        """Valid requests refused (unknown composite, arbiter that does not fit, …)."""
        self.changed = asyncio.Event()
        """Set after every applied change (tests and tools clear and await it)."""
        self._replies = 0

    @property
    def key(self) -> str:
        return TREE_REQUEST.key(self.bus.keys)

    @property
    def root(self) -> Behavior:
        return self.controller.root

    async def run(self) -> None:
        queryable = self.bus.declare_queryable(self.key, self.on_query)
        try:
            await asyncio.Event().wait()
        finally:
            queryable.close()

    # -- the queryable (event loop) ----------------------------------------------------------
    def on_query(self, key: str, payload: bytes) -> bytes:
        """Handle one query: decode, apply, reply. Never raises for a bad request. Holds
        the controller's lock: its reflex lane may tick on another thread."""
        with self.controller.lock:
            return self._answer(payload)

    def _answer(self, payload: bytes) -> bytes:
        op = "?"
        try:
            request = decode(payload, topic=TREE_REQUEST).data
        except ProtocolError as exc:
            n = self.malformed.get(self.key, 0) + 1
            self.malformed[self.key] = n
            if throttle.first_and_every(n):
                log.warning("rejected malformed tree request #%d on %s: %s", n, self.key, exc)
            return self._reply({"ok": False, "op": op, "error": f"malformed request: {exc}"})
        op = request.op
        try:
            self.handle(request)
        except TreeChangeError as exc:
            self.refused += 1
            log.warning("refused tree request %s: %s", op, exc)
            return self._reply({"ok": False, "op": op, "error": str(exc)})
        return self._reply({"ok": True, "op": op, "tree": self.show(),
                            "slots": [{"composite": s.composite, "name": s.name,
                                       "priority": s.priority, "weight": float(s.weight)}
                                      for s in self.slots]})

    def _reply(self, data: dict[str, Any]) -> bytes:
        data["version"] = self.version
        if "error" in data and len(data["error"]) > MAX_ERROR_CHARS:
            data["error"] = data["error"][:MAX_ERROR_CHARS - 1] + "…"
        self._replies += 1
        return encode(TREE_REPLY, data, stamp_ns=self.bus.clock.now_ns(), seq=self._replies)

    def handle(self, request: TreeRequest) -> None:
        """Apply one request already checked against ``"tree.request"`` (its ``op`` has the
        fields it needs)."""
        op = request.op
        if op == "set_arbiter":
            spec = request.arbiter
            assert request.composite is not None and spec is not None
            self.set_arbiter(request.composite,
                             spec if isinstance(spec, str) else msgspec.structs.asdict(spec))
        elif op == "set_child":
            assert request.composite is not None and request.child is not None
            self.set_child(request.composite, request.child,
                           priority=request.priority, weight=request.weight)
        elif op == "load":
            fragment = request.tree
            self.load(fragment.decode("utf-8") if isinstance(fragment, bytes) else fragment)

    # -- operations --------------------------------------------------------------------------
    def show(self) -> dict[str, Any]:
        """The running tree as nested data."""
        return tree_data(self.root)

    def set_arbiter(self, composite: str, spec: str | Mapping[str, Any]) -> None:
        """Swap ``composite``'s arbiter for the one ``spec`` describes."""
        target = self._composite(composite)
        what = spec if isinstance(spec, str) else spec.get("type", "?")
        try:
            arbiter = build_arbiter(spec, source="<request>", seed=self.seed)
        except ConfigurationError as exc:
            reason = getattr(exc, "message", str(exc))  # a RobotFileError's, without its place
            raise TreeChangeError(f"cannot build arbiter {what!r}: {reason}") from None
        try:
            target.arbiter = arbiter  # validated against the children, then reset
        except ConfigurationError as exc:
            raise TreeChangeError(str(exc)) from None
        self._applied(f"composite {composite!r} now arbitrates with {arbiter.describe()}")

    def set_child(self, composite: str, child: str, *, priority: int | None = None,
                  weight: float | None = None) -> None:
        """Change the priority and/or weight of ``child`` in ``composite``."""
        if priority is None and weight is None:
            raise TreeChangeError("set_child: give a priority and/or a weight")
        target = self._composite(composite)
        if not any(c.behavior.name == child for c in target.children):
            names = ", ".join(c.behavior.name for c in target.children) or "none"
            raise TreeChangeError(f"composite {composite!r} has no child {child!r} (its "
                                  f"children: {names})")
        try:
            placed = target.set_child(child, priority=priority, weight=weight)
        except (ConfigurationError, KeyError) as exc:
            raise TreeChangeError(f"composite {composite!r}, child {child!r}: {exc}") from None
        self._applied(f"child {child!r} of {composite!r} now has priority {placed.priority} "
                      f"weight {placed.weight:g}")

    def load(self, fragment: str) -> None:
        """Replace the whole tree with the one a robot-file fragment describes."""
        try:
            root, slots = load_tree_fragment(fragment, source="<fragment>", seed=self.seed)
        except ConfigurationError as exc:
            raise TreeChangeError(f"cannot load the tree: {exc}") from None
        old = self.controller.root
        if getattr(old, "live", False):
            # The running tree is set up: so is the new one, before it takes over.
            try:
                root.setup()
            except Exception as exc:
                try:
                    root.shutdown()
                except Exception:
                    log.exception("shutdown of the refused tree %r raised", root.name)
                raise TreeChangeError(f"cannot load the tree: setup of {root.name!r} failed: "
                                      f"{type(exc).__name__}: {exc}") from None
        root.reset()
        self.controller.root = root
        if self.remotes is not None:
            for name in self.remotes.set_root(root, config=self._config_with(slots)):
                log.warning("remote behaviour %s left the tree: the new tree has no place "
                            "for it", name)
        self.slots = list(slots)
        try:
            old.shutdown()
        except Exception:
            log.exception("shutdown of the replaced tree %r raised", old.name)
        self._applied(f"loaded tree {root.name!r}")

    # -- helpers -----------------------------------------------------------------------------
    def _composite(self, name: str) -> Composite:
        root = self.root
        found = root.find(name) if isinstance(root, Composite) else (
            root if root.name == name else None)
        if isinstance(found, Composite):
            return found
        if found is not None:
            raise TreeChangeError(f"{name!r} is a leaf behaviour, not a composite")
        raise TreeChangeError(f"no composite named {name!r} in the tree (composites: "
                              f"{', '.join(_composites(root)) or 'none'})")

    def _applied(self, what: str) -> None:
        self.version += 1
        log.info("tree changed, version %d: %s", self.version, what)
        self.controller.tree_changed(what)
        self.changed.set()

    def _config_with(self, slots: list[RemoteSlot]) -> dict[str, tuple[int, float]]:
        """The remote placements with the old tree's slots replaced by ``slots``."""
        assert self.remotes is not None
        config = dict(self.remotes.config)
        for slot in self.slots:
            if config.get(slot.key) == (slot.priority, slot.weight):
                del config[slot.key]
        for slot in slots:
            config[slot.key] = (slot.priority, float(slot.weight))
        return config


def _composites(node: Behavior) -> list[str]:
    if not isinstance(node, Composite):
        return []
    out = [node.name]
    for child in node.children:
        out.extend(_composites(child.behavior))
    return out


__all__ = [
    "OPS", "REPLY_SCHEMA", "REQUEST_SCHEMA", "TreeService", "decode_reply", "encode_request",
    "render_tree_data", "request", "tree_data",
]
