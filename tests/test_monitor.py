"""The tree monitor (issue 51, item 2) without a browser: what it keeps of the robot's messages
(:class:`MonitorModel`, plain logic), and its server on the in-process transport with a real
aggregator, controller and tree service, spoken to by a WebSocket client as the page speaks
to it. The page itself, in Chromium against a launched robot: tests/test_monitor_page.py."""

from __future__ import annotations

import asyncio
import json
import math
import re
import urllib.error
import urllib.request
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest
import pytest_asyncio
import websockets

from tests.conftest import eventually
from tests.test_live_tree import make_tree, start_robot
from tests.test_secure import robot_file
from ubf_async.access.setup import init
from ubf_async.assembly.robotfile import load_robot
from ubf_async.errors import ConfigurationError
from ubf_async.net.inprocess import InProcessTransport
from ubf_async.net.options import ConnectionOptions
from ubf_async.runtime.bus import Bus
from ubf_async.services import monitor as monitor_mod
from ubf_async.services.monitor import MonitorModel, MonitorServer, plain, winning_leaves
from ubf_async.tools import launch as launch_tool
from ubf_async.wire.protocol import Message
from ubf_async.wire.topics import TickTrace, TraceNode


def trace_message(tick: int, t_s: float, *, winner: str) -> Message[Any]:
    nodes = (TraceNode(name="root", depth=0, won=True, arbiter="HighestPriority", speed=30,
                       turn=0, vote=1),
             TraceNode(name="fwd", depth=1, won=winner == "fwd", speed=30, turn=0, vote=1),
             TraceNode(name="back", depth=1, won=winner == "back", speed=-30, turn=0, vote=5),
             TraceNode(name="idle", depth=1))
    return Message(schema="controller.trace", stamp_ns=int(t_s * 1e9), seq=tick,
                   data=TickTrace(tick=tick, nodes=nodes))


# -- the model: plain logic -------------------------------------------------------------------

def test_the_winners_are_the_leaves_whose_votes_made_the_command() -> None:
    nodes = [{"name": "root", "depth": 0, "won": True},
             {"name": "a", "depth": 1, "won": True},        # a composite: its child won
             {"name": "a1", "depth": 2, "won": True},
             {"name": "a2", "depth": 2},
             {"name": "b", "depth": 1, "won": True},        # a leaf that won
             {"name": "c", "depth": 1}]
    assert winning_leaves(nodes) == ["a1", "b"]
    assert winning_leaves([{"name": "root", "depth": 0}]) == []


def test_each_page_gets_every_ticks_winners_once_and_the_strip_keeps_its_window() -> None:
    model = MonitorModel(history_s=1.0)
    for tick in range(1, 6):
        model.on_trace(trace_message(tick, tick * 0.1, winner="fwd" if tick < 4 else "back"))
    first = model.frame(after_tick=0)
    assert [t[2] for t in first["ticks"]] == [1, 2, 3, 4, 5]
    assert [t[3] for t in first["ticks"]] == [["fwd"]] * 3 + [["back"]] * 2
    assert first["trace"]["tick"] == 5 and first["trace"]["t"] == pytest.approx(0.5)
    newest = first["ticks"][-1][0]
    model.on_trace(trace_message(6, 0.6, winner="back"))
    assert [t[2] for t in model.frame(after_tick=newest)["ticks"]] == [6]  # only what is new
    model.on_trace(trace_message(30, 3.0, winner="fwd"))  # 2.4 s later: older ticks leave
    assert [t[2] for t in model.ticks] == [30]


def test_the_tree_is_asked_for_again_when_a_trace_names_a_behaviour_it_lacks() -> None:
    model = MonitorModel()
    model.on_trace(trace_message(1, 0.1, winner="fwd"))
    assert model.shape_differs()  # no tree yet
    tree = {"name": "root", "kind": "composite", "arbiter": "HighestPriority", "children": [
        {"name": n, "kind": "behavior", "priority": 1, "weight": 1.0}
        for n in ("fwd", "back", "idle")]}
    model.on_tree({"ok": True, "tree": tree, "version": 0})
    assert not model.shape_differs() and model.tree_version == 1
    model.on_tree({"ok": True, "tree": tree, "version": 0})  # the same: no news
    assert model.tree_version == 1
    model.on_tree({"ok": False, "error": "refused"})  # a refusal leaves the tree
    assert model.tree is not None and model.tree["tree"]["name"] == "root"
    smaller = {**tree, "children": tree["children"][:2]}
    model.on_tree({"ok": True, "tree": smaller, "version": 1})
    assert model.shape_differs()  # idle ran, but the tree has no idle


def test_state_values_are_json_ready_and_short() -> None:
    assert plain({"img": b"\x00" * 5000, "x": math.nan, "y": [1.5, math.inf]}) == \
        {"img": "<5000 bytes>", "x": None, "y": [1.5, None]}
    model = MonitorModel()
    model.on_sample("camera/front", Message(schema="camera.seekcolor", stamp_ns=2 * 10**9, seq=1,
                                            data={"bins": list(range(500))}))
    sample = model.state["camera/front"]
    assert sample["t"] == 2.0 and sample["schema"] == "camera.seekcolor"
    assert isinstance(sample["data"]["bins"], str) and sample["data"]["bins"].endswith("…")
    assert len(sample["data"]["bins"]) <= monitor_mod.MAX_VALUE_CHARS + 1


# -- the server, in-process -------------------------------------------------------------------

class Page:
    """A WebSocket client speaking as the page does."""

    def __init__(self, ws: Any) -> None:
        self.ws = ws
        self.messages: list[dict[str, Any]] = []
        self._ids = 0

    async def next(self, kind: str, *, timeout_s: float = 10.0) -> dict[str, Any]:
        async with asyncio.timeout(timeout_s):
            while True:
                msg = json.loads(await self.ws.recv())
                self.messages.append(msg)
                if msg["type"] == kind:
                    return msg

    async def ask(self, **request: Any) -> dict[str, Any]:
        self._ids += 1
        await self.ws.send(json.dumps({"id": self._ids, "request": request}))
        reply = await self.next("reply")
        assert reply["id"] == self._ids
        return reply


@pytest_asyncio.fixture
async def robot() -> AsyncIterator[tuple[Bus, Any]]:
    net = InProcessTransport()
    bus = Bus(transport=net, robot="mon")
    live, components = await start_robot(bus, make_tree())
    yield bus, live
    for c in reversed(components):
        await c.aclose()
    await bus.aclose()


async def serve(bus: Bus, port: int = 0, **kwargs: Any) -> MonitorServer:
    server = MonitorServer(bus=bus, port=port, **kwargs)
    await server.start()
    return server


@pytest.mark.asyncio
async def test_a_page_sees_the_tree_each_tick_and_changes_it(robot: tuple[Bus, Any]) -> None:
    bus, live = robot
    server = await serve(bus)
    try:
        assert server.url is not None and server.url.startswith("http://127.0.0.1:")
        async with websockets.connect(f"ws://127.0.0.1:{server.port}/ws") as ws:
            page = Page(ws)
            hello = await page.next("hello")
            assert hello["robot"] == "mon" and hello["allow_changes"] is True
            assert {"HighestPriority", "HighestActivation", "MonteCarlo"} <= set(
                hello["arbiters"])
            tree = await page.next("tree")
            assert tree["tree"]["arbiter"] == "HighestPriority"
            assert [c["name"] for c in tree["tree"]["children"]] == ["fwd", "back", "idle"]
            frame = await page.next("frame")
            while frame["trace"] is None:
                frame = await page.next("frame")
            assert winning_leaves(frame["trace"]["nodes"]) == ["fwd"]

            reply = await page.ask(op="set_arbiter", composite="root",
                                   arbiter="HighestActivation")
            assert reply["ok"] is True and reply["version"] == 1, reply
            assert (await page.next("tree"))["tree"]["arbiter"] == "HighestActivation"
            await eventually(lambda: live.winners() == ["back"], timeout_s=5)

            async def back_wins() -> None:
                while True:
                    frame = await page.next("frame")
                    if frame["trace"] and winning_leaves(frame["trace"]["nodes"]) == ["back"]:
                        return
            await asyncio.wait_for(back_wins(), 10)
            assert len(live.controller.tree_changes) == 1

            reply = await page.ask(op="set_child", composite="root", child="fwd", priority=-5)
            assert reply["ok"] is True and reply["version"] == 2
            refused = await page.ask(op="set_arbiter", composite="root", arbiter="Nope")
            assert refused["ok"] is False and "Nope" in refused["error"]
            await ws.send("not json")
            bad = await page.next("reply")
            assert bad["ok"] is False and bad["error"].startswith("not a request")
            await ws.send(json.dumps({"id": 9, "request": ["op", "show"]}))
            bad = await page.next("reply")
            assert bad["ok"] is False and "must be an object" in bad["error"]
            # The page's connection survives its bad requests.
            assert (await page.ask(op="show"))["ok"] is True
        await eventually(lambda: server.pages == 0, timeout_s=5, what="the page's socket gone")
    finally:
        await server.aclose()


@pytest.mark.asyncio
async def test_frames_are_throttled_but_the_strip_misses_no_tick(
        robot: tuple[Bus, Any]) -> None:
    """The controller ticks at 100 Hz; a page gets at most ``max_frame_hz`` frames a second,
    and the winners of every tick among them."""
    bus, _ = robot
    server = await serve(bus, max_frame_hz=5.0)
    try:
        async with websockets.connect(f"ws://127.0.0.1:{server.port}/ws") as ws:
            page = Page(ws)
            await page.next("hello")
            loop = asyncio.get_running_loop()
            frames, ticks = [], []
            start = loop.time()
            while len(frames) < 6:
                frame = await page.next("frame")
                frames.append(loop.time())
                ticks += [t[0] for t in frame["ticks"]]
            elapsed = frames[-1] - frames[0]
            # 5 intervals at ≥ 0.2 s each (a slow machine only stretches them)
            assert elapsed >= 5 * 0.2 * 0.95, (elapsed, loop.time() - start)
            assert ticks == list(range(ticks[0], ticks[0] + len(ticks)))  # no tick skipped
            assert len(ticks) > len(frames)  # several ticks a frame: latest wins
    finally:
        await server.aclose()


@pytest.mark.asyncio
async def test_a_read_only_monitor_refuses_changes_with_its_reason(
        robot: tuple[Bus, Any]) -> None:
    bus, live = robot
    server = await serve(bus, allow_changes=False, refusal="watching only (--read-only)")
    try:
        async with websockets.connect(f"ws://127.0.0.1:{server.port}/ws") as ws:
            page = Page(ws)
            hello = await page.next("hello")
            assert hello["allow_changes"] is False
            assert hello["refusal"] == "watching only (--read-only)"
            reply = await page.ask(op="set_arbiter", composite="root",
                                   arbiter="HighestActivation")
            assert reply == {"type": "reply", "id": 1, "ok": False, "op": "set_arbiter",
                             "error": "watching only (--read-only)"}
            assert (await page.ask(op="show"))["ok"] is True  # looking is fine
        assert live.controller.tree_changes == []
    finally:
        await server.aclose()


@pytest.mark.asyncio
async def test_in_secure_mode_the_identity_decides_and_says_who_may(
        robot: tuple[Bus, Any], tmp_path: Path) -> None:
    """A monitor whose identity may not query the tree (``inspector``) has each change
    refused before it is sent, with the ACL's one-line reason."""
    bus, live = robot
    init(tmp_path / "s", robot=load_robot(robot_file(tmp_path, "mon")))
    watcher = Bus(transport=bus.transport, options=ConnectionOptions(
        robot="mon", secure=tmp_path / "s", identity="inspector"))
    server = await serve(watcher)
    try:
        async with websockets.connect(f"ws://127.0.0.1:{server.port}/ws") as ws:
            page = Page(ws)
            await page.next("hello")
            reply = await page.ask(op="set_arbiter", composite="root",
                                   arbiter="HighestActivation")
            assert reply["ok"] is False
            assert "identity 'inspector' may not query ubf/mon/tree" in reply["error"]
            assert "--identity operator" in reply["error"]
        assert live.controller.tree_changes == []
    finally:
        await server.aclose()
        await watcher.aclose()


@pytest.mark.asyncio
async def test_the_page_files_are_served_and_a_port_in_use_is_one_line(
        robot: tuple[Bus, Any]) -> None:
    bus, _ = robot
    server = await serve(bus)
    try:
        def get(path: str) -> tuple[int, str, str]:
            try:
                with urllib.request.urlopen(f"{server.url}{path}", timeout=10) as r:
                    return r.status, r.headers["Content-Type"], r.read().decode()
            except urllib.error.HTTPError as exc:
                return exc.code, exc.headers["Content-Type"], exc.read().decode()

        status, kind, body = await asyncio.to_thread(get, "")
        assert status == 200 and kind.startswith("text/html") and "monitor.js" in body
        assert "://" not in body  # nothing fetched from elsewhere
        status, kind, body = await asyncio.to_thread(get, "monitor.js")
        assert status == 200 and "new WebSocket" in body
        # (the one address in it is SVG's namespace, a name, not fetched)
        assert re.findall(r"\w+://[\w.]+", body) == ["http://www.w3.org"]
        status, _, body = await asyncio.to_thread(get, "secrets.txt")
        assert status == 404 and "the page is at /" in body
        with pytest.raises(ConfigurationError, match=rf"tree monitor on 127.0.0.1:"
                                                     rf"{server.port}: .*in use"):
            await serve(bus, port=server.port)
    finally:
        await server.aclose()
    with pytest.raises(ConfigurationError, match=r"--monitor port must be 0\.\.65535"):
        MonitorServer(bus=bus, port=70000)


def test_launch_takes_monitor_with_or_without_a_port() -> None:
    def parsed(*argv: str) -> Any:
        return launch_tool.parse_args(list(argv))

    assert parsed("--monitor").monitor == monitor_mod.DEFAULT_PORT
    assert parsed("--monitor", "0").monitor == 0
    args = parsed("--monitor", "my_robot.yaml")
    assert args.monitor == monitor_mod.DEFAULT_PORT and str(args.robot_file) == "my_robot.yaml"
    assert parsed("--monitor-host", "0.0.0.0", "--monitor", "9000").monitor_host == "0.0.0.0"
    assert parsed().monitor is None
