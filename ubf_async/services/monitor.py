"""The behaviour tree, live in a browser: ``launch --monitor [PORT]`` or ``python -m
ubf_async.monitor``.

A monitor watches one robot's keys — each tick's trace (``ubf/<robot>/trace``), the drive
command, the controller's status and the newest sample of every sensor — and serves a page
(HTTP and a WebSocket on one port, through aiohttp) that draws the running tree as a tree: each
node's last vote and the winners of the drive command, each source's age, a strip of the last
:data:`HISTORY_S` seconds of winners to scrub back through, and the state snapshot. The page
is the package's own static files (``monitor_page/``: plain JavaScript and SVG, no library,
nothing fetched at run time). docs/monitor.md describes it.

What crosses the WebSocket (JSON):

* server → page: a ``hello`` (robot, whether changes are allowed, the history length), then
  ``frame`` messages — the newest tick's trace, drive command, status and state, and every
  tick's winners since the page's previous frame — at most :data:`MAX_FRAME_HZ` a second per
  page, latest wins (a slow browser skips frames, never falls behind); a ``tree`` message when
  the tree's shape is new; a ``reply`` to each of the page's requests;
* page → server: ``{"id": N, "request": {...}}`` with a tree request of
  :mod:`ubf_async.services.live` (``set_arbiter``, ``set_child``, ``load``, ``show``), sent to
  the robot's tree service as ``inspector tree`` sends them, through this process's bus — so in
  secure mode its identity's rights decide, and a refusal comes back with its reason.

Changes from a page are refused by a monitor made with ``allow_changes=False`` (a secure
robot's own monitor: a browser must not get more rights than an identity).

It serves on loopback by default and has no authentication: bind it wider only on a network
you trust.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field
from importlib import resources
from typing import TYPE_CHECKING, Any

import msgspec

from ubf_async import extras
from ubf_async.assembly.registry import ARBITERS
from ubf_async.errors import ConfigurationError, ProtocolError, QueryError, UbfError
from ubf_async.runtime.bus import Bus
from ubf_async.runtime.component import Component
from ubf_async.services import live
from ubf_async.wire.protocol import Message, decode
from ubf_async.wire.topics import DRIVE, TRACE

if TYPE_CHECKING:
    from aiohttp import web

__all__ = ["DEFAULT_HOST", "DEFAULT_PORT", "HISTORY_S", "MAX_FRAME_HZ", "MonitorModel",
           "MonitorServer", "plain"]

log = logging.getLogger(__name__)

DEFAULT_PORT = 8770
DEFAULT_HOST = "127.0.0.1"
HISTORY_S = 30.0
"""Robot seconds of winners the strip keeps (and the page can scrub back through)."""
MAX_FRAME_HZ = 20.0
"""Frames a second per page at most: more than a person reads, little for a browser."""
MAX_TICKS_PER_FRAME = 2000
"""A frame's winners since the previous one, bounded (a page that stalled gets the newest)."""
MAX_VALUE_CHARS = 200
"""A state value longer than this as JSON (an image's bytes, a long list) is shown shortened."""
PAGE_FILES = {"index.html": "text/html", "monitor.js": "text/javascript",
              "monitor.css": "text/css"}


def plain(value: Any) -> Any:
    """A decoded message's data as JSON-ready plain data: bytes as ``"<N bytes>"`` (an image
    is not for this page), non-finite floats as ``None`` (JSON has none)."""
    return _json_ready(msgspec.to_builtins(value, builtin_types=(bytes, bytearray, memoryview)))


def _json_ready(value: Any) -> Any:
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, bytes | bytearray | memoryview):
        return f"<{len(value)} bytes>"
    if isinstance(value, dict):
        return {str(k): _json_ready(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_json_ready(v) for v in value]
    return value


def _short(value: Any) -> Any:
    text = msgspec.json.encode(value)
    return value if len(text) <= MAX_VALUE_CHARS else text[:MAX_VALUE_CHARS].decode(
        "utf-8", "replace") + "…"


@dataclass
class MonitorModel:
    """What the page shows, kept from the robot's messages (plain logic: no bus, no server).

    ``on_*`` take decoded messages; :meth:`frame` is what one page is sent next, given the
    newest tick it already has. ``version`` counts changes, so a page's sender knows when there
    is something new."""

    history_s: float = HISTORY_S
    version: int = 0
    trace: dict[str, Any] | None = None
    drive: dict[str, Any] | None = None
    status: dict[str, Any] | None = None
    state: dict[str, dict[str, Any]] = field(default_factory=dict)
    tree: dict[str, Any] | None = None
    tree_version: int = 0
    """Counts the tree shapes seen (a page asks for the tree when it has an older one)."""
    ticks: deque[tuple[int, float, int, list[str]]] = field(default_factory=deque)
    """``(n, robot seconds, tick, winners)`` per tick, ``n`` counting every tick seen."""
    _n: int = 0

    def on_trace(self, message: Message[Any]) -> None:
        nodes = [plain(node) for node in message.data.nodes]
        t = message.stamp_ns / 1e9
        winners = winning_leaves(nodes)
        self._n += 1
        self.ticks.append((self._n, t, int(message.data.tick), winners))
        while self.ticks and (t - self.ticks[0][1] > self.history_s
                              or len(self.ticks) > MAX_TICKS_PER_FRAME * 10):
            self.ticks.popleft()
        self.trace = {"t": t, "tick": int(message.data.tick), "nodes": nodes}
        self.version += 1

    def on_drive(self, message: Message[Any]) -> None:
        self.drive = {"t": message.stamp_ns / 1e9, **plain(message.data)}
        self.version += 1

    def on_status(self, message: Message[Any]) -> None:
        self.status = plain(message.data)
        self.version += 1

    def on_sample(self, source: str, message: Message[Any]) -> None:
        data = plain(message.data)
        self.state[source] = {
            "schema": message.schema, "t": message.stamp_ns / 1e9,
            "data": {k: _short(v) for k, v in data.items()} if isinstance(data, dict)
            else _short(data)}
        self.version += 1

    def on_tree(self, reply: Mapping[str, Any]) -> None:
        """A tree service's reply to ``show`` (or to a change: it carries the tree after it)."""
        if reply.get("ok") and reply.get("tree") is not None:
            tree = {"tree": plain(reply["tree"]), "slots": plain(reply.get("slots", [])),
                    "version": reply.get("version")}
            if tree != self.tree:
                self.tree = tree
                self.tree_version += 1
                self.version += 1

    def traced_names(self) -> frozenset[str]:
        """The behaviours of the newest trace."""
        return frozenset(n["name"] for n in self.trace["nodes"]) if self.trace else frozenset()

    def shape_differs(self) -> bool:
        """Whether the newest trace names behaviours the known tree does not have (a change
        made elsewhere: ask the robot for its tree again)."""
        if self.trace is None:
            return False
        return self.tree is None or not self.traced_names() <= set(tree_names(self.tree["tree"]))

    def frame(self, after_tick: int) -> dict[str, Any]:
        """The next frame for a page whose newest tick is ``after_tick`` (``n`` of
        :attr:`ticks`): the newest of everything, and the ticks since."""
        new = [t for t in self.ticks if t[0] > after_tick][-MAX_TICKS_PER_FRAME:]
        return {"type": "frame", "trace": self.trace, "drive": self.drive,
                "status": self.status, "state": self.state, "tree_version": self.tree_version,
                "ticks": [[n, t, tick, winners] for n, t, tick, winners in new]}


def winning_leaves(nodes: list[dict[str, Any]]) -> list[str]:
    """The behaviours whose votes made the command: winners whose children did not (or who
    have none), from a depth-first trace."""
    out = []
    for i, node in enumerate(nodes):
        if not node.get("won"):
            continue
        following = nodes[i + 1] if i + 1 < len(nodes) else None
        is_parent = following is not None and following["depth"] > node["depth"]
        if not is_parent or not any(
                n.get("won") for n in _children(nodes, i)):
            out.append(node["name"])
    return out


def _children(nodes: list[dict[str, Any]], i: int) -> list[dict[str, Any]]:
    depth, out = nodes[i]["depth"], []
    for node in nodes[i + 1:]:
        if node["depth"] <= depth:
            break
        if node["depth"] == depth + 1:
            out.append(node)
    return out


def tree_names(node: Mapping[str, Any]) -> list[str]:
    """Every name in a tree reply's ``tree``, depth first."""
    out, stack = [], [node]
    while stack:
        current = stack.pop()
        out.append(current["name"])
        stack.extend(reversed(current.get("children") or []))
    return out


class MonitorServer(Component):
    """Serves one robot's tree live to browsers (module docstring) on ``host``:``port``
    (``port`` 0: any free port; :attr:`url` says which once started).

    ``allow_changes``: whether a page may send tree changes (``False``: each is refused with
    the reason ``refusal`` gives).

    Lifecycle: :meth:`start` binds the port (a port in use raises
    :class:`~ubf_async.errors.ConfigurationError` there) and subscribes; :meth:`aclose` closes
    every page's socket, then the server, then the subscriptions."""

    def __init__(self, *, bus: Bus, port: int = DEFAULT_PORT, host: str = DEFAULT_HOST,
                 name: str = "monitor", allow_changes: bool = True,
                 refusal: str = "this monitor is read-only",
                 max_frame_hz: float = MAX_FRAME_HZ) -> None:
        extras.require("monitor", "aiohttp", who="the tree monitor")
        super().__init__(bus=bus, name=name)
        if not 0 <= port <= 65535:
            raise ConfigurationError(f"--monitor port must be 0..65535, got {port}")
        if not max_frame_hz > 0:
            raise ConfigurationError(f"max_frame_hz must be > 0, got {max_frame_hz}")
        self.host, self.requested_port = host, port
        self.allow_changes, self.refusal = allow_changes, refusal
        self.min_interval_s = 1.0 / max_frame_hz
        self.model = MonitorModel()
        self.malformed: dict[str, int] = {}
        self._pages: dict[web.WebSocketResponse, asyncio.Event] = {}
        """Each page's socket, and its news: set when the model changed since its frame."""
        self._runner: web.AppRunner | None = None
        self._port: int | None = None
        self._fetching: asyncio.Task[None] | None = None
        self._asked_for: frozenset[str] = frozenset()
        """The trace's behaviours when the tree was last asked for."""

    @property
    def port(self) -> int | None:
        return self._port

    @property
    def url(self) -> str | None:
        return None if self._port is None else f"http://{self.host}:{self._port}/"

    @property
    def pages(self) -> int:
        """Pages connected now."""
        return len(self._pages)

    async def start(self) -> None:
        if self._runner is None and not self.closed:
            from aiohttp import web

            app = web.Application()
            app.router.add_get("/", self._page)
            app.router.add_get("/ws", self._socket)
            app.router.add_get("/{file}", self._page)
            runner = web.AppRunner(app, access_log=None, handle_signals=False)
            await runner.setup()
            site = web.TCPSite(runner, self.host, self.requested_port)
            try:
                await site.start()
            except OSError as exc:
                await runner.cleanup()
                raise ConfigurationError(
                    f"tree monitor on {self.host}:{self.requested_port}: {exc.strerror or exc}"
                ) from None
            self._runner = runner
            self._port = int(runner.addresses[0][1])
        await super().start()

    async def run(self) -> None:
        keys = self.bus.keys
        self.subscribe_topic(TRACE.key(keys), TRACE, self._on(self.model.on_trace),
                             self.malformed, latest=False)
        self.subscribe_topic(DRIVE.key(keys), DRIVE, self._on(self.model.on_drive),
                             self.malformed)
        self.subscribe(keys.status("controller"), self._on_status)
        self.subscribe(keys.all_sensors, self._on_sample)
        await self._fetch_tree()
        await asyncio.Event().wait()  # until closed: the subscriptions do the work

    def _on(self, handler: Any) -> Any:
        def on_message(key: str, message: Message[Any], received_ns: int) -> None:
            handler(message)
            self._news()
        return on_message

    def _on_status(self, key: str, payload: bytes, received_ns: int) -> None:
        try:
            message = decode(payload)
        except ProtocolError:
            self.malformed[key] = self.malformed.get(key, 0) + 1
            return
        self.model.on_status(message)
        self._news()

    def _on_sample(self, key: str, payload: bytes, received_ns: int) -> None:
        try:
            message = decode(payload)
            source = self.bus.keys.source_of(key)
        except ProtocolError:
            self.malformed[key] = self.malformed.get(key, 0) + 1
            return
        self.model.on_sample(source, message)
        self._news()

    def _news(self) -> None:
        # Ask once per new shape: a robot without a tree service (a replay) is not asked at
        # every tick.
        if (self.model.shape_differs() and self.model.traced_names() != self._asked_for
                and (self._fetching is None or self._fetching.done())):
            self._asked_for = self.model.traced_names()
            self._fetching = asyncio.ensure_future(self._fetch_tree())
        self._tell_pages()

    def _tell_pages(self) -> None:
        for news in self._pages.values():
            news.set()

    async def _fetch_tree(self) -> None:
        """The robot's tree, from its tree service (a robot without one — an older robot, a
        replay — leaves the page drawing the tree from the traces alone)."""
        try:
            self.model.on_tree(await live.request(self.bus, {"op": "show"}, timeout_s=2.0))
        except (TimeoutError, UbfError) as exc:
            log.info("tree monitor: no tree from the robot's tree service (%s): drawing it "
                     "from the traces", exc)
        self._tell_pages()

    # -- the page ---------------------------------------------------------------------------

    async def _page(self, request: web.Request) -> web.StreamResponse:
        from aiohttp import web

        name = request.match_info.get("file", "index.html")
        if name not in PAGE_FILES:
            raise web.HTTPNotFound(text=f"no {name} here: the page is at /")
        body = resources.files("ubf_async.services").joinpath("monitor_page", name).read_bytes()
        return web.Response(body=body, content_type=PAGE_FILES[name],
                            headers={"Cache-Control": "no-store"})

    async def _socket(self, request: web.Request) -> web.StreamResponse:
        from aiohttp import WSMsgType, web

        ws = web.WebSocketResponse(heartbeat=10.0)
        await ws.prepare(request)
        await ws.send_json({"type": "hello", "robot": self.bus.robot,
                            "allow_changes": self.allow_changes,
                            "refusal": None if self.allow_changes else self.refusal,
                            "history_s": self.model.history_s,
                            "arbiters": ARBITERS.names()})
        news = self._pages[ws] = asyncio.Event()
        news.set()  # the newest frame at once
        tasks = {asyncio.ensure_future(self._send_frames(ws, news))}
        try:
            async for msg in ws:
                if msg.type is WSMsgType.TEXT:
                    task = asyncio.ensure_future(self._answer(ws, msg.data))
                    tasks.add(task)
                    task.add_done_callback(tasks.discard)
        except ConnectionError:
            pass  # the page went: nothing to tell it
        finally:
            self._pages.pop(ws, None)
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)
        return ws

    async def _send_frames(self, ws: web.WebSocketResponse, news: asyncio.Event) -> None:
        """Latest wins: wait for news, send the newest frame (and the tree if its shape is
        new to this page), then rest for the minimum interval; news while resting is in the
        next frame."""
        after, tree_sent = 0, -1
        with contextlib.suppress(ConnectionError):
            while not ws.closed:
                await news.wait()
                news.clear()
                model = self.model
                if model.tree_version != tree_sent and model.tree is not None:
                    await ws.send_json({"type": "tree", **model.tree})
                    tree_sent = model.tree_version
                frame = model.frame(after)
                if frame["ticks"]:
                    after = frame["ticks"][-1][0]
                await ws.send_json(frame)
                await asyncio.sleep(self.min_interval_s)

    async def _answer(self, ws: web.WebSocketResponse, text: str) -> None:
        reply: dict[str, Any]
        try:
            message = msgspec.json.decode(text)
            ident, data = message.get("id"), message["request"]
            if not isinstance(data, dict):
                raise TypeError("request must be an object")
        except (msgspec.DecodeError, KeyError, TypeError, AttributeError) as exc:
            await ws.send_json({"type": "reply", "id": None, "ok": False,
                                "error": f"not a request: {exc}"})
            return
        if data.get("op") != "show" and not self.allow_changes:
            reply = {"ok": False, "op": data.get("op"), "error": self.refusal}
        else:
            try:
                reply = await live.request(self.bus, data)
            except TimeoutError as exc:
                reply = {"ok": False, "op": data.get("op"), "error": str(exc)}
            except (ProtocolError, QueryError, UbfError) as exc:
                reply = {"ok": False, "op": data.get("op"), "error": str(exc)}
            else:
                self.model.on_tree(reply)
                self._tell_pages()
        with contextlib.suppress(ConnectionError):
            await ws.send_json({"type": "reply", "id": ident, **plain(reply)})

    async def aclose(self) -> None:
        if self.closed:
            return
        for ws in list(self._pages):
            with contextlib.suppress(Exception):
                await ws.close()
        runner, self._runner = self._runner, None
        if runner is not None:
            await runner.cleanup()
        if self._fetching is not None:
            self._fetching.cancel()
        await super().aclose()
