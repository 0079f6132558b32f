"""Live tree changes over the ``ubf/<robot>/tree`` queryable, on real zenoh sessions.

The robot (state aggregator, controller, tree service, and remote behaviours where needed)
runs in the test process on ``robot_bus``; requests come from another session (``peer_bus``),
from the inspector in a subprocess, or from a launched robot's inspector.
"""

from __future__ import annotations

import asyncio
import contextlib
import io
import json
import sys
from collections.abc import AsyncIterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import msgpack
import pytest
import pytest_asyncio

from tests.conftest import eventually, read_until
from ubf_async.behaviors.basic import ConstantDrive
from ubf_async.core.action import Action
from ubf_async.core.arbiters import HighestPriority
from ubf_async.core.behavior import Behavior, Composite
from ubf_async.core.state import State
from ubf_async.errors import ProtocolError, QueryError
from ubf_async.runtime.aggregator import StateAggregator
from ubf_async.runtime.bus import Bus
from ubf_async.runtime.controller import Controller
from ubf_async.services.live import (
    REQUEST_SCHEMA,
    TreeService,
    decode_reply,
    encode_request,
    render_tree_data,
    request,
)
from ubf_async.services.remote import RemoteBehaviorHost, RemoteBehaviors
from ubf_async.tools.inspector import program as inspector_program
from ubf_async.tools.inspector.parser import build_parser
from ubf_async.wire.protocol import decode, encode

ROOT = Path(__file__).resolve().parent.parent
pytestmark = pytest.mark.asyncio


class Recording(ConstantDrive):
    """A constant drive behaviour that records its lifecycle calls."""

    def __init__(self, *, name: str, speed: float, vote: float) -> None:
        super().__init__(name=name, speed=speed, vote=vote)
        self.calls: list[str] = []

    def setup(self) -> None:
        self.calls.append("setup")

    def shutdown(self) -> None:
        self.calls.append("shutdown")


class Idle(Behavior):
    """Always abstains."""

    def act(self, state: State) -> Action | None:
        return None


def make_tree() -> Composite:
    """HighestPriority picks ``fwd`` (priority 2), HighestActivation ``back`` (vote 5); a
    third child, ``idle``, abstains (so a Conditional, which needs exactly two, is refused)."""
    root = Composite(name="root", arbiter=HighestPriority())
    root.add(Recording(name="fwd", speed=30, vote=1), priority=2)
    root.add(Recording(name="back", speed=-30, vote=5), priority=1)
    root.add(Idle(name="idle"), priority=0)
    return root


@dataclass
class LiveRobot:
    bus: Bus
    controller: Controller
    service: TreeService
    remotes: RemoteBehaviors | None

    async def next_tick(self) -> None:
        """Wait for a tick that starts after this call."""
        self.controller.ticked.clear()
        await asyncio.wait_for(self.controller.ticked.wait(), 5.0)

    def winners(self) -> list[str]:
        trace = self.controller.last_trace
        assert trace is not None
        return trace.winning_leaves()


async def start_robot(bus: Bus, root: Composite, *, with_remotes: bool = False,
                      seed: int | None = 1) -> tuple[LiveRobot, list[Any]]:
    aggregator = StateAggregator(bus=bus)
    controller = Controller(bus=bus, aggregator=aggregator, root=root, rate_hz=100.0)
    remotes = (RemoteBehaviors(bus=bus, root=root, config={"root/teleop": (10, 1.0)})
               if with_remotes else None)
    service = TreeService(bus=bus, controller=controller, remotes=remotes, seed=seed)
    components: list[Any] = [aggregator, controller, service]
    if remotes is not None:
        components.append(remotes)
    for c in components:
        await c.start()
    live = LiveRobot(bus=bus, controller=controller, service=service, remotes=remotes)
    await live.next_tick()
    return live, components


@pytest_asyncio.fixture
async def live(robot_bus: Bus) -> AsyncIterator[LiveRobot]:
    robot, components = await start_robot(robot_bus, make_tree())
    yield robot
    for c in reversed(components):
        await c.aclose()


async def ask(bus: Bus, **data: Any) -> dict[str, Any]:
    return await request(bus, data, timeout_s=10.0)


# ---------------------------------------------------------------------------------------------


async def test_show_returns_the_running_tree(live: LiveRobot, peer_bus: Bus) -> None:
    reply = await ask(peer_bus, op="show")
    assert reply["ok"] is True and reply["op"] == "show" and reply["version"] == 0
    tree = reply["tree"]
    assert (tree["name"], tree["kind"], tree["arbiter"]) == ("root", "composite",
                                                            "HighestPriority")
    assert "priority" not in tree  # the root has no place in a parent
    children = [(c["name"], c["kind"], c["type"], c["priority"], c["weight"])
                for c in tree["children"]]
    assert children == [("fwd", "behavior", "Recording", 2, 1.0),
                        ("back", "behavior", "Recording", 1, 1.0),
                        ("idle", "behavior", "Idle", 0, 1.0)]
    assert render_tree_data(tree).splitlines() == [
        "root <HighestPriority>",
        "  fwd (Recording) [p=2 w=1]",
        "  back (Recording) [p=1 w=1]",
        "  idle (Idle) [p=0 w=1]",
    ]
    assert live.winners() == ["fwd"]


async def test_arbiter_swap_and_child_change_apply_on_the_next_tick(
    live: LiveRobot, peer_bus: Bus
) -> None:
    drives: list[list[str]] = []

    def on_drive(key: str, payload: bytes, received_ns: int) -> None:
        drives.append(list(decode(payload, schema="drive").data.winners))

    peer_bus.subscribe(peer_bus.keys.cmd("drive"), on_drive, latest=False)
    assert live.winners() == ["fwd"]

    reply = await ask(peer_bus, op="set_arbiter", composite="root", arbiter="HighestActivation")
    assert reply["ok"] is True, reply
    assert reply["version"] == 1 and reply["tree"]["arbiter"] == "HighestActivation"
    # The reply is sent after the change: the very next tick runs the new arbiter.
    await live.next_tick()
    trace = live.controller.last_trace
    assert trace is not None and trace.arbiter == "HighestActivation"
    assert live.winners() == ["back"]
    await eventually(lambda: bool(drives) and drives[-1] == ["back"],
                     what="drive commands won by back")

    # With parameters, as {"type", "params"}.
    reply = await ask(peer_bus, op="set_arbiter", composite="root",
                      arbiter={"type": "MonteCarlo", "params": {"hold_ticks": 3, "seed": 7}})
    assert reply["ok"] is True and reply["tree"]["arbiter"] == "MonteCarlo(hold_ticks=3)"
    await live.next_tick()
    assert live.controller.last_trace is not None
    assert live.controller.last_trace.arbiter == "MonteCarlo"

    # Back to HighestPriority, then move `back` above `fwd`.
    assert (await ask(peer_bus, op="set_arbiter", composite="root",
                      arbiter="HighestPriority"))["ok"]
    await live.next_tick()
    assert live.winners() == ["fwd"]
    reply = await ask(peer_bus, op="set_child", composite="root", child="back", priority=5,
                      weight=0.5)
    assert reply["ok"] is True and reply["version"] == 4
    back = next(c for c in reply["tree"]["children"] if c["name"] == "back")
    assert (back["priority"], back["weight"]) == (5, 0.5)
    await live.next_tick()
    trace = live.controller.last_trace
    assert trace is not None and trace.winning_leaves() == ["back"]
    shown = {c.name: (c.priority, c.weight) for c in trace.children}
    assert shown == {"fwd": (2, 1.0), "back": (5, 0.5), "idle": (0, 1.0)}
    assert "back [p=5 w=0.5]" in trace.render()
    assert live.controller.stats.errors == 0
    assert live.service.version == 4 and live.service.refused == 0


BAD_REQUESTS: list[tuple[dict[str, Any] | bytes, str]] = [
    ({"op": "set_arbiter", "composite": "root", "arbiter": "NoSuchArbiter"},
     "cannot build arbiter 'NoSuchArbiter': unknown arbiter 'NoSuchArbiter'"),
    ({"op": "set_arbiter", "composite": "root",
      "arbiter": {"type": "Conditional", "params": {"predicate": "sees_color"}}},
     "Conditional needs exactly two children (if-true, if-false), got 3"),
    ({"op": "set_arbiter", "composite": "root",
      "arbiter": {"type": "MonteCarlo", "params": {"hold_ticks": 0}}},
     "cannot build arbiter 'MonteCarlo'"),
    ({"op": "set_arbiter", "composite": "nowhere", "arbiter": "HighestActivation"},
     "no composite named 'nowhere' in the tree (composites: root)"),
    ({"op": "set_arbiter", "composite": "fwd", "arbiter": "HighestActivation"},
     "'fwd' is a leaf behaviour, not a composite"),
    ({"op": "set_child", "composite": "root", "child": "ghost", "priority": 3},
     "composite 'root' has no child 'ghost' (its children: fwd, back, idle)"),
    ({"op": "set_child", "composite": "root", "child": "back", "priority": 10**7},
     "malformed request: tree.request data: Expected `int` <= 1000000 - at `data.priority`"),
    ({"op": "set_child", "composite": "root", "child": "back", "weight": -1},
     "malformed request: tree.request data: Expected `float` >= 0.0 - at `data.weight`"),
    ({"op": "set_child", "composite": "root", "child": "back"},
     "malformed request: tree.request data: op 'set_child' needs 'priority' and/or 'weight'"),
    ({"op": "set_arbiter", "composite": "root"},
     "malformed request: tree.request data: op 'set_arbiter' needs 'arbiter'"),
    ({"op": "show", "priority": 1},
     "malformed request: tree.request data: op 'show' takes no 'priority'"),
    ({"op": "explode"}, "malformed request: tree.request data: Invalid enum value 'explode'"),
    ({"op": "load", "tree": "name: x\narbiter: HighestPriority\nchildren:\n"
                            "  - behavior: no_such_behaviour\n"},
     "cannot load the tree: <fragment>:4: unknown behaviour 'no_such_behaviour'"),
    ({"op": "load", "tree": "name: [unclosed"},
     "cannot load the tree: <fragment>:1: not valid YAML"),
    ({"op": "load", "tree": "behavior: drive"},
     "cannot load the tree: <fragment>:1: a tree's root must be a composite"),
    (b"\xc1 not msgpack", "malformed request: envelope: MessagePack data is malformed"),
    (msgpack.packb({"schema": "drive", "v": 1, "stamp_ns": 1, "seq": 1,
                    "data": {"speed": 0, "turn": 0}}),
     "malformed request: envelope.schema: expected 'tree.request', got 'drive'"),
]


async def test_bad_changes_are_refused_and_the_old_tree_keeps_ticking(
    live: LiveRobot, peer_bus: Bus
) -> None:
    controller = live.controller
    root = controller.root
    assert isinstance(root, Composite)
    arbiter, children = root.arbiter, root.children
    await ask(peer_bus, op="show")  # the queryable is known to the peer from here on
    ticks_before = controller.stats.ticks
    key = peer_bus.keys.tree
    for bad, expected in BAD_REQUESTS:
        payload = bad if isinstance(bad, bytes) else msgpack.packb(
            {"schema": REQUEST_SCHEMA, "v": 1, "stamp_ns": 1, "seq": 1, "data": bad})
        ticks = controller.stats.ticks
        reply = decode_reply(await peer_bus.query(key, payload, timeout_s=10.0))
        assert reply["ok"] is False, bad
        assert expected in reply["error"], (bad, reply["error"])
        assert reply["version"] == 0
        assert "Traceback" not in reply["error"]
        # The old tree is untouched and keeps ticking, with the same winner.
        assert controller.root is root and root.arbiter is arbiter
        assert root.children == children
        await live.next_tick()
        assert controller.stats.ticks > ticks
        assert live.winners() == ["fwd"]
    assert controller.stats.errors == 0
    ticked = controller.stats.ticks - ticks_before
    assert controller.stats.winner_ticks["fwd"] >= ticked  # every tick went to fwd
    assert set(controller.stats.winner_ticks) == {"fwd"}
    assert live.service.version == 0
    assert live.service.malformed[key] == sum(
        1 for _, e in BAD_REQUESTS if e.startswith("malformed request"))
    assert live.service.refused == sum(
        1 for _, e in BAD_REQUESTS if not e.startswith("malformed request"))
    assert all(c.behavior.calls == ["setup"] for c in children  # type: ignore[attr-defined]
               if isinstance(c.behavior, Recording))
    # Still answering.
    assert (await ask(peer_bus, op="show"))["ok"] is True


async def test_request_codec_refuses_what_the_robot_would() -> None:
    with pytest.raises(ProtocolError, match="needs 'tree'"):
        encode_request({"op": "load"})
    with pytest.raises(ProtocolError, match="unknown field `prio`"):
        encode_request({"op": "set_child", "composite": "a", "child": "b", "prio": 1})
    long = "#" * 10_000 + "\nname: a\n"
    assert decode(encode_request({"op": "load", "tree": long.encode()})).data.tree == (
        long.encode())
    with pytest.raises(ProtocolError, match="utf-8"):
        encode_request({"op": "load", "tree": b"\xff\xfe"})
    with pytest.raises(ProtocolError, match="refusal carries an error"):
        encode("tree.reply", {"ok": False}, stamp_ns=1, seq=1)


FRAGMENT = """\
# a robot file's tree node, as `tree:`
tree:
  name: second
  arbiter: HighestActivation
  children:
    - behavior: drive
      name: spin
      params: {turn: 50, vote: 2}
    - behavior: stop
      priority: 3
    - remote: teleop
      priority: 9
"""


async def test_load_replaces_the_tree_between_ticks(live: LiveRobot, peer_bus: Bus) -> None:
    old = live.controller.root
    assert isinstance(old, Composite) and old.live
    recorders = [c.behavior for c in old.children if isinstance(c.behavior, Recording)]
    reply = await ask(peer_bus, op="load", tree=FRAGMENT)
    assert reply["ok"] is True, reply
    assert reply["version"] == 1
    assert render_tree_data(reply["tree"]).splitlines() == [
        "second <HighestActivation>",
        "  spin (ConstantDrive) [p=0 w=1]",
        "  stop (Stop) [p=3 w=1]",
    ]
    assert reply["slots"] == [{"composite": "second", "name": "teleop", "priority": 9,
                               "weight": 1.0}]
    new = live.controller.root
    assert new is not old and new.name == "second"
    assert isinstance(new, Composite) and new.live  # set up before it took over
    assert not old.live and all(r.calls == ["setup", "shutdown"] for r in recorders)
    await live.next_tick()
    trace = live.controller.last_trace
    assert trace is not None and (trace.name, trace.arbiter) == ("second", "HighestActivation")
    assert live.winners() == ["spin"]
    assert live.controller.last_action == Action(speed=0.0, turn=50.0)
    # Further changes apply to the new tree.
    reply = await ask(peer_bus, op="set_arbiter", composite="second", arbiter="HighestPriority")
    assert reply["ok"] and reply["version"] == 2
    await live.next_tick()
    assert live.winners() == ["stop"]
    refused = await ask(peer_bus, op="set_arbiter", composite="root", arbiter="HighestPriority")
    assert not refused["ok"] and "no composite named 'root'" in refused["error"]
    # A fragment longer than the protocol's longest string travels as UTF-8 bytes.
    long = ("# " + "x" * 5000 + "\n" + FRAGMENT.replace("second", "third")).encode()
    reply = await ask(peer_bus, op="load", tree=long)
    assert reply["ok"] and reply["tree"]["name"] == "third" and reply["version"] == 3
    await live.next_tick()
    assert live.controller.last_trace is not None
    assert live.controller.last_trace.name == "third"
    assert live.controller.stats.errors == 0


async def test_load_moves_remote_children_to_the_new_tree(
    robot_bus: Bus, peer_bus: Bus
) -> None:
    robot, components = await start_robot(robot_bus, make_tree(), with_remotes=True)
    remotes = robot.remotes
    assert remotes is not None
    host = RemoteBehaviorHost(bus=peer_bus, behavior=ConstantDrive(name="teleop", speed=77, vote=1),
                              composite="root", rate_hz=50.0, priority=10, ttl_s=2.0)
    try:
        await host.start()
        await eventually(lambda: remotes.attached() == ["root/teleop"], timeout_s=10.0,
                         what="teleop to attach")
        await robot.next_tick()
        assert robot.winners() == ["teleop"]
        shown = await ask(peer_bus, op="show")
        teleop = shown["tree"]["children"][-1]
        assert (teleop["name"], teleop["kind"], teleop["priority"]) == ("teleop", "remote", 10)

        # A new tree with a composite of the same name: teleop moves over at once.
        same = ("name: root\narbiter: HighestPriority\nchildren:\n"
                "  - {behavior: drive, name: slow, params: {speed: 5}}\n")
        assert (await ask(peer_bus, op="load", tree=same))["ok"]
        assert remotes.root is robot.controller.root
        assert remotes.attached() == ["root/teleop"]
        await robot.next_tick()
        assert robot.winners() == ["teleop"]

        # A tree without that composite: teleop is detached cleanly, the new tree runs.
        other = ("name: other\narbiter: HighestPriority\nchildren:\n"
                 "  - {behavior: drive, name: slow, params: {speed: 5}}\n")
        assert (await ask(peer_bus, op="load", tree=other))["ok"]
        assert remotes.attached() == []
        await robot.next_tick()
        assert robot.winners() == ["slow"]
        assert robot.controller.stats.errors == 0
    finally:
        await host.aclose()
        for c in reversed(components):
            await c.aclose()


async def test_no_tree_service_is_a_timeout(peer_bus: Bus) -> None:
    with pytest.raises(TimeoutError, match="no robot answered"):
        await request(peer_bus, {"op": "show"}, timeout_s=0.3)


async def test_a_failing_handler_is_an_error_reply_and_the_queryable_goes_on(
    robot_bus: Bus, peer_bus: Bus
) -> None:
    calls: list[bytes] = []

    def handler(key: str, payload: bytes) -> bytes:
        calls.append(payload)
        if payload == b"boom":
            raise RuntimeError("kaput")
        return b"echo " + payload

    queryable = robot_bus.declare_queryable(f"{robot_bus.keys.prefix}/echo", handler)
    key = f"{peer_bus.keys.prefix}/echo"
    deadline = asyncio.get_running_loop().time() + 10
    while True:  # the declaration reaches the peer asynchronously
        try:
            assert await peer_bus.query(key, b"hi", timeout_s=1.0) == b"echo hi"
            break
        except TimeoutError:
            assert asyncio.get_running_loop().time() < deadline
    with pytest.raises(QueryError, match="internal error: RuntimeError: kaput"):
        await peer_bus.query(key, b"boom", timeout_s=5.0)
    assert await peer_bus.query(key, b"again", timeout_s=5.0) == b"echo again"
    assert await robot_bus.query(key, b"local", timeout_s=5.0) == b"echo local"
    assert queryable.stats.handler_errors == 1 and queryable.stats.answered >= 3
    queryable.close()
    queryable.close()  # idempotent


# ---------------------------------------------------------------------------------------------
# The inspector's `tree` verbs: in a subprocess, and its program on this loop


async def inspector(*args: str, timeout_s: float = 30.0) -> tuple[int, str, str]:
    """Run ``python -m ubf_async.inspector`` without blocking the loop (the robot is here)."""
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "ubf_async.inspector", *args, cwd=ROOT,
        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE)
    out, err = await asyncio.wait_for(proc.communicate(), timeout_s)
    assert proc.returncode is not None
    return proc.returncode, out.decode(), err.decode()


async def inspector_here(*args: str, timeout_s: float = 30.0) -> tuple[int, str, str]:
    """What ``python -m ubf_async.inspector ARGS`` does, on this loop: the command line
    parsed, the inspector's session opened, the verb run; its status, stdout and stderr."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stderr(err):
        code = await asyncio.wait_for(inspector_program.run(build_parser().parse_args(args),
                                                            out), timeout_s)
    return code, out.getvalue(), err.getvalue()


async def test_inspector_tree_verbs(
    live: LiveRobot, endpoint: str, robot: str, tmp_path: Path
) -> None:
    """The first verb through the real command; the others through its program here."""
    conn = ("--connect", endpoint, "--robot", robot)
    code, out, err = await inspector("tree", "show", *conn)
    assert code == 0, err
    assert out.splitlines() == [
        f"robot {robot!r}: tree version 0",
        "root <HighestPriority>",
        "  fwd (Recording) [p=2 w=1]",
        "  back (Recording) [p=1 w=1]",
        "  idle (Idle) [p=0 w=1]",
    ]

    code, out, err = await inspector_here("tree", "set-arbiter", "root", "MonteCarlo", "--param",
                                     "hold_ticks=4", "-p", "seed=3", *conn)
    assert code == 0, err
    assert out.splitlines()[:2] == [f"robot {robot!r}: set-arbiter applied, tree version 1",
                                    "root <MonteCarlo(hold_ticks=4)>"]
    await live.next_tick()
    assert live.controller.last_trace is not None
    assert live.controller.last_trace.arbiter == "MonteCarlo"

    code, out, err = await inspector_here("tree", "set-arbiter", "root", "Conditional", "-p",
                                     "predicate=sees_color", *conn)
    assert code == 1 and out == ""
    assert err.startswith(f"python -m ubf_async.inspector: error: robot {robot!r} refused "
                          f"set-arbiter: ")
    assert "Conditional needs exactly two children" in err and "Traceback" not in err
    assert "(tree unchanged, version 1)" in err

    code, out, err = await inspector_here("tree", "set-child", "root", "back", "--priority", "7",
                                     *conn)
    assert code == 0, err
    assert "  back (Recording) [p=7 w=1]" in out.splitlines()
    code, _, err = await inspector_here("tree", "set-child", "root", "back", *conn)
    assert code == 2 and "give --priority and/or --weight" in err

    fragment = tmp_path / "tree.yaml"
    fragment.write_text(FRAGMENT, encoding="utf-8")
    code, out, err = await inspector_here("tree", "load", str(fragment), "--json", *conn)
    assert code == 0, err
    reply = json.loads(out)
    assert reply["ok"] and reply["version"] == 3 and reply["tree"]["name"] == "second"
    await live.next_tick()
    assert live.winners() == ["spin"]

    code, _, err = await inspector_here("tree", "load", str(tmp_path / "missing.yaml"), *conn)
    assert code == 2 and "missing.yaml: cannot read it" in err

    bad = tmp_path / "bad.yaml"
    bad.write_text("name: x\narbiter: HighestPriority\nchildren:\n  - behavior: nope\n")
    code, _, err = await inspector_here("tree", "load", str(bad), *conn)
    assert code == 1 and "<fragment>:4: unknown behaviour 'nope'" in err
    await live.next_tick()
    assert live.winners() == ["spin"]  # refused: the loaded tree still runs

    # Another robot name on the same endpoint: nobody answers.
    code, _, err = await inspector_here("tree", "show", "--connect", endpoint, "--robot",
                                   robot + "x", "--timeout", "1")
    assert code == 2 and f"no robot {robot + 'x'!r} answered" in err


async def logged(proc: asyncio.subprocess.Process, text: str, *, timeout_s: float = 30.0
                 ) -> str:
    """Read ``proc``'s stderr (its log) line by line until a line contains ``text``."""
    assert proc.stderr is not None
    while True:
        line = (await asyncio.wait_for(proc.stderr.readline(), timeout_s)).decode()
        assert line, f"the log ended before a line with {text!r}"
        if text in line:
            return line.rstrip("\n")


async def test_inspector_changes_a_launched_robot(endpoint: str, robot: str) -> None:
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "ubf_async.launch", "--no-sim", "--quiet", "--listen", endpoint,
        "--robot", robot, cwd=ROOT, stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.PIPE)
    try:
        await read_until(proc, "controller:")
        conn = ("--connect", endpoint, "--robot", robot, "--timeout", "20")
        code, out, err = await inspector("tree", "show", *conn)
        assert code == 0, err
        assert "seek_pink_ball <PriorityMerge>" in out
        code, out, err = await inspector("tree", "set-arbiter", "seek_pink_ball",
                                         "HighestPriority", *conn)
        assert code == 0, err
        assert "seek_pink_ball <HighestPriority>" in out
        # The robot's console shows the change it applied (at launch's default log level) …
        line = await logged(proc, "ubf_async.services.live:")
        assert line.endswith(" INFO ubf_async.services.live: tree changed, version 1: composite "
                             "'seek_pink_ball' now arbitrates with HighestPriority"), line
        code, _, err = await inspector("tree", "set-child", "seek_pink_ball", "nobody",
                                       "--weight", "2", *conn)
        assert code == 1 and "has no child 'nobody'" in err
        # … as it shows one it refused.
        line = await logged(proc, "ubf_async.services.live:")
        assert " WARNING ubf_async.services.live: refused tree request set_child: composite " \
               "'seek_pink_ball' has no child 'nobody'" in line, line
    finally:
        proc.terminate()
        await asyncio.wait_for(proc.wait(), 20)
