"""The observation hooks: StateAggregator.on_receive / on_ingest / on_sample and
Controller.on_tick (what benchmarks and tools use instead of subclasses or a wrapped publish).

Aggregator ordering rules are unit-tested in-process (``ingest`` with a stand-in bus);
everything crossing a session runs on real zenoh sessions on loopback."""

from __future__ import annotations

import asyncio
import logging
from typing import Any

import pytest

from tests.conftest import as_dict, eventually, zenoh_session
from ubf_async import Action, FunctionBehavior, State
from ubf_async.clocks.clock import WallClock
from ubf_async.core.behavior import Trace
from ubf_async.errors import ProtocolError
from ubf_async.runtime.aggregator import SourceEntry, StateAggregator
from ubf_async.runtime.bus import Bus
from ubf_async.runtime.component import Component
from ubf_async.runtime.controller import Controller
from ubf_async.wire.keys import Keys
from ubf_async.wire.protocol import Message, decode

CAMERA = {"bins": [0, 0, 140, 0, 0], "total": 140}


class _Bus:  # what ingest needs, for in-process unit tests
    clock = WallClock()
    keys = Keys("mini")


def message(seq: int, *, stamp_ns: int | None = None, range_mm: int = 500) -> Message:
    return Message(schema="range", stamp_ns=stamp_ns or WallClock().now_ns(), seq=seq,
                   data={"range_mm": range_mm, "status": "ok"}, pub=7)


async def start(*components: Component) -> None:
    for c in components:
        await c.start()
    for c in components:
        await asyncio.wait_for(c.running.wait(), 5)


def avoid(state: State) -> Action | None:
    mm = state.value("range/front", "range_mm")
    return None if mm is None else Action(speed=-50 if mm < 200 else 20)


# ---------------------------------------------------------------------------------------------
# Aggregator


def test_on_sample_sees_each_accepted_sample_in_order_and_not_the_refused() -> None:
    agg = StateAggregator(bus=_Bus())  # type: ignore[arg-type]
    calls: list[tuple[str, str, int, int]] = []
    agg.on_sample(lambda source, entry: calls.append(("first", source, entry.message.seq,
                                                      entry.version)))
    remove = agg.on_sample(lambda source, entry: calls.append(("second", source,
                                                                entry.message.seq,
                                                                entry.version)))
    offered: list[tuple[str, int]] = []
    agg.on_ingest(lambda source, msg, received_ns: offered.append((source, msg.seq)))
    assert agg.ingest("range/front", message(1), 0)
    assert not agg.ingest("range/front", message(1), 0)  # a replay: refused
    assert not agg.ingest("range/front", message(2, stamp_ns=2**62), 0)  # future: refused
    assert calls == [("first", "range/front", 1, 1), ("second", "range/front", 1, 1)]
    assert offered == [("range/front", 1), ("range/front", 1), ("range/front", 2)]
    remove()
    remove()  # idempotent
    assert agg.ingest("range/front", message(3), 0)
    assert calls[2:] == [("first", "range/front", 3, 2)]


def test_on_sample_runs_after_the_entry_is_stored_and_waiters_resolved() -> None:
    agg = StateAggregator(bus=_Bus())  # type: ignore[arg-type]
    seen: list[tuple[int, int]] = []

    def check(source: str, entry: SourceEntry) -> None:
        held = agg.entries[source]
        seen.append((held.message.seq, agg.snapshot()[source].seq))

    agg.on_sample(check)
    agg.ingest("range/front", message(1), 0)
    agg.ingest("range/front", message(2), 0)
    assert seen == [(1, 1), (2, 2)]


def test_a_raising_sample_hook_is_logged_and_removed_the_others_go_on(
    caplog: pytest.LogCaptureFixture,
) -> None:
    agg = StateAggregator(bus=_Bus())  # type: ignore[arg-type]
    calls: list[str] = []

    def faulty(source: str, entry: SourceEntry) -> None:
        calls.append("faulty")
        raise RuntimeError("hook bug")

    agg.on_sample(faulty)
    agg.on_sample(lambda source, entry: calls.append("good"))
    with caplog.at_level(logging.ERROR, logger="ubf_async.runtime.hooks"):
        for seq in (1, 2, 3):
            assert agg.ingest("range/front", message(seq), 0)
    assert calls == ["faulty", "good", "good", "good"]
    assert agg.entries["range/front"].version == 3
    assert sum("sample hook" in r.getMessage() for r in caplog.records) == 1


@pytest.mark.asyncio
async def test_on_receive_sees_raw_samples_malformed_ones_too(
    robot_bus: Bus, peer_bus: Bus
) -> None:
    agg = StateAggregator(bus=robot_bus)
    received: list[tuple[str, bytes, int]] = []
    offered: list[int] = []
    agg.on_receive(lambda key, payload, received_ns: received.append((key, payload,
                                                                       received_ns)))
    agg.on_ingest(lambda source, msg, received_ns: offered.append(msg.seq))
    async with agg:
        await asyncio.wait_for(agg.running.wait(), 5)
        key, bad_key = (peer_bus.keys.sensor("range", side) for side in ("front", "left"))
        pub = peer_bus.publisher(key, "range")
        await pub.wait_for_subscribers()
        zenoh_session(peer_bus).put(bad_key, b"\xc1 not msgpack")  # another key: never coalesced
        await eventually(lambda: agg.malformed == {bad_key: 1}, what="the malformed sample")
        seq, _ = pub.publish({"range_mm": 300, "status": "ok"})
        await eventually(lambda: "range/front" in agg.entries, what="the good sample")
    assert [r[0] for r in received] == [bad_key, key]
    assert received[0][1] == b"\xc1 not msgpack"
    assert decode(received[1][1]).seq == seq
    assert all(r[2] > 0 for r in received)
    assert offered == [seq]  # the malformed one never reached ingest


# ---------------------------------------------------------------------------------------------
# Controller


@pytest.mark.asyncio
async def test_on_tick_gets_the_state_trace_and_the_command_that_went_out(
    robot_bus: Bus, peer_bus: Bus
) -> None:
    agg = StateAggregator(bus=robot_bus)
    ctl = Controller(bus=robot_bus, aggregator=agg, root=FunctionBehavior(avoid, name="avoid"),
                     mode="event", trigger="range/front", rate_hz=2)
    ticks: list[tuple[State, Trace | None, Any, int | None]] = []
    ctl.on_tick(lambda state, trace, command: ticks.append(
        (state, trace, command, ctl.last_action.speed if ctl.last_action else None)))
    drives: list[Message] = []
    robot_bus.subscribe(robot_bus.keys.cmd("drive"), lambda k, p, t: drives.append(decode(p)),
                        latest=False)
    await start(agg, ctl)
    pub = peer_bus.publisher(peer_bus.keys.sensor("range", "front"), "range")
    await pub.wait_for_subscribers()
    sent = []
    for n, mm in enumerate((150, 600), start=1):  # one at a time: the bridge keeps the newest
        sent.append(pub.publish({"range_mm": mm, "status": "ok"}))
        await eventually(lambda n=n: len(ticks) == n and ctl.stats.ticks == n,
                         what=f"tick {n}")
    await eventually(lambda: sum(not d.data.hold for d in drives) == 2)
    await ctl.aclose()
    await agg.aclose()
    commands = [d.data for d in drives if not d.data.hold]
    for (state, trace, command, _), (seq, stamp), drive in zip(
            ticks, sent, commands, strict=True):
        assert state["range/front"].seq == seq
        assert trace is not None and trace.winning_leaves() == ["avoid"]
        assert command == drive  # exactly what went out on cmd/drive
        assert as_dict(command["based_on"]) == {"source": "range/front", "seq": seq,
                                                "stamp_ns": stamp}
    assert [t[2]["speed"] for t in ticks] == [-50, 20]
    # It runs before last_action is updated: it sees the previous tick's.
    assert [t[3] for t in ticks] == [None, -50]


@pytest.mark.asyncio
async def test_on_tick_runs_for_clock_and_reflex_ticks(robot_bus: Bus, peer_bus: Bus) -> None:
    agg = StateAggregator(bus=robot_bus)
    ctl = Controller(bus=robot_bus, aggregator=agg, root=FunctionBehavior(avoid), rate_hz=20,
                     reflex_sources=("range/",))
    kinds: list[str] = []
    periodic = [0]

    def on_tick(state: State, trace: Trace | None, command: Any) -> None:
        # stats.periodic already counts a clock tick when the hook runs.
        kinds.append("clock" if ctl.stats.periodic > periodic[0] else "reflex")
        periodic[0] = ctl.stats.periodic

    ctl.on_tick(on_tick)
    await start(agg, ctl)
    pub = peer_bus.publisher(peer_bus.keys.sensor("range", "front"), "range")
    await pub.wait_for_subscribers()
    pub.publish({"range_mm": 150, "status": "ok"})
    await eventually(lambda: ctl.stats.triggered == 1 and ctl.stats.periodic >= 3,
                     what="a reflex tick and some clock ticks")
    await ctl.aclose()
    await agg.aclose()
    assert len(kinds) == ctl.stats.ticks
    assert kinds.count("reflex") == ctl.stats.triggered == 1
    assert kinds.count("clock") == ctl.stats.periodic


@pytest.mark.asyncio
async def test_holds_in_sync_mode_do_not_call_on_tick(robot_bus: Bus, peer_bus: Bus) -> None:
    agg = StateAggregator(bus=robot_bus)
    ctl = Controller(bus=robot_bus, aggregator=agg, root=FunctionBehavior(avoid), mode="sync",
                     rate_hz=50)
    ticks: list[Any] = []
    ctl.on_tick(lambda state, trace, command: ticks.append(command))
    drives: list[dict[str, Any]] = []
    robot_bus.subscribe(robot_bus.keys.cmd("drive"),
                        lambda k, p, t: drives.append(as_dict(decode(p).data)), latest=False)
    await start(agg, ctl)
    await eventually(lambda: ctl.stats.holds >= 3, what="holds without a camera")
    assert ticks == []
    camera = peer_bus.publisher(peer_bus.keys.sensor("camera", "front"), "camera.seekcolor",
                                period_s=0.11)
    await camera.wait_for_subscribers()
    camera.publish(CAMERA)
    await eventually(lambda: ctl.stats.ticks == 1, what="the camera's tick")
    holds = ctl.stats.holds
    await eventually(lambda: ctl.stats.holds >= holds + 3, what="holds after the tick")
    await ctl.aclose()
    await agg.aclose()
    assert len(ticks) == 1 and ticks[0]["tick"] == 1 and not ticks[0].hold
    assert sum(1 for d in drives if d.get("hold")) >= 6  # the holds did go out


@pytest.mark.asyncio
async def test_a_raising_tick_hook_is_cut_off_and_the_controller_goes_on(
    robot_bus: Bus, caplog: pytest.LogCaptureFixture
) -> None:
    agg = StateAggregator(bus=robot_bus)
    ctl = Controller(bus=robot_bus, aggregator=agg,
                     root=FunctionBehavior(lambda s: Action(speed=20)), rate_hz=50)
    calls: list[str] = []

    def faulty(state: State, trace: Trace | None, command: Any) -> None:
        calls.append("faulty")
        raise RuntimeError("observer bug")

    ctl.on_tick(faulty)
    ctl.on_tick(lambda state, trace, command: calls.append("good"))
    drives: list[dict[str, Any]] = []
    robot_bus.subscribe(robot_bus.keys.cmd("drive"),
                        lambda k, p, t: drives.append(as_dict(decode(p).data)), latest=False)
    with caplog.at_level(logging.ERROR, logger="ubf_async.runtime.hooks"):
        await start(agg, ctl)
        await eventually(lambda: len(drives) >= 3, what="three commands")
    await ctl.aclose()
    await agg.aclose()
    assert calls[:3] == ["faulty", "good", "good"] and "faulty" not in calls[1:]
    assert all(d["speed"] == 20 for d in drives)
    assert ctl.stats.errors == 0 and ctl.stats.publish_errors == 0 and ctl.restarts == 0
    assert ctl.last_action == Action(speed=20, turn=0.0)
    assert sum("tick hook" in r.getMessage() for r in caplog.records) == 1


@pytest.mark.asyncio
async def test_on_tick_gets_the_plain_stop_when_the_command_could_not_go_out(
    robot_bus: Bus,
) -> None:
    agg = StateAggregator(bus=robot_bus)
    ctl = Controller(bus=robot_bus, aggregator=agg,
                     root=FunctionBehavior(lambda s: Action(speed=20)), rate_hz=50)
    commands: list[dict[str, Any]] = []
    ctl.on_tick(lambda state, trace, command: commands.append(command))
    await start(agg, ctl)
    await eventually(lambda: len(commands) >= 1)
    real_publish = ctl._drive.publish

    def failing(data: dict[str, Any], **kw: Any) -> tuple[int, int]:  # fault injection
        if data.get("speed") == 20:
            raise ProtocolError("injected")
        return real_publish(data)

    ctl._drive.publish = failing  # type: ignore[method-assign]
    await eventually(lambda: ctl.stats.publish_errors >= 2)
    await ctl.aclose()
    await agg.aclose()
    stop = commands[-1]
    assert as_dict(stop) == {"speed": 0.0, "turn": 0.0, "tick": stop["tick"],
                             "based_on": None, "hold": False, "winners": [],
                             "ticked_by": "clock"}
