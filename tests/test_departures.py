"""Issue 48, item 2: a component that leaves is not a refusal. One that said goodbye (closed
cleanly: a last heartbeat with ``leaving``, then its token goes) is reported **left**; one whose
token vanished without a goodbye is **gone**; the sources they published say so instead of an
age that keeps growing, and the table's housekeeping (a silent source forgotten) is never
counted with refused traffic.

And (issue 55, item 1 of what to build) a component's health: one that sends no heartbeat —
a token-only component, as a microcontroller's may be — is judged by its token, healthy while
it is present, as is a joiner whose token is heard before its first heartbeat; only one whose
heartbeats stopped while its token stays is UNHEALTHY."""

from __future__ import annotations

import asyncio
import re
import signal
import time
from collections.abc import AsyncIterator
from dataclasses import dataclass
from pathlib import Path

import pytest
import pytest_asyncio

from tests.conftest import eventually
from tests.ports import free_port
from tests.remote_robot import Process
from tests.test_inprocess_units import tree
from ubf_async.clocks.clock import SimClock
from ubf_async.net.inprocess import InProcessTransport
from ubf_async.runtime.aggregator import StateAggregator
from ubf_async.runtime.bus import Bus
from ubf_async.runtime.component import Component, HealthMonitor
from ubf_async.runtime.controller import Controller
from ubf_async.services.status import status_fields
from ubf_async.wire.topics import HEARTBEAT, RANGE

ROOT = Path(__file__).resolve().parent.parent


class Ranger(Component):
    """A range finder that publishes one reading, then idles until closed."""

    async def run(self) -> None:
        self.publisher(RANGE, self.name, period_s=0.04).publish(
            {"range_mm": 300, "status": "ok"})
        await asyncio.Event().wait()


@dataclass
class Robot:
    net: InProcessTransport
    bus: Bus
    health: HealthMonitor
    aggregator: StateAggregator
    controller: Controller

    def fields(self) -> list[str]:
        return status_fields("unit", 1.0, self.controller, self.aggregator, self.health)


@pytest_asyncio.fixture
async def robot() -> AsyncIterator[Robot]:
    net = InProcessTransport()
    bus = Bus(transport=net, robot="unit", clock=SimClock(10**9))
    health = HealthMonitor(bus)
    health.start()
    aggregator = StateAggregator(bus=bus, departures=health)
    controller = Controller(bus=bus, aggregator=aggregator, root=tree(), rate_hz=10)
    await aggregator.start()
    await net.settle()
    yield Robot(net, bus, health, aggregator, controller)
    await aggregator.aclose()
    health.close()
    await bus.aclose()


async def announced(robot: Robot, name: str) -> None:
    await eventually(lambda: bool(robot.health.components.get(name)
                                  and robot.health.components[name].publishes)
                     and f"range/{name}" in robot.aggregator.entries,
                     timeout_s=5, what=f"{name}'s heartbeat and sample")


@pytest.mark.asyncio
async def test_a_component_that_closes_has_left_and_its_source_says_so(robot: Robot) -> None:
    other = Bus(transport=robot.net, robot="unit", clock=SimClock(10**9))
    ranger = Ranger(bus=other, name="left")
    try:
        await ranger.start()
        await announced(robot, "left")
        assert robot.aggregator.sources()[0].departed is None
        await ranger.aclose()
        await robot.net.settle()
        health = robot.health.components["left"]
        assert health.departed is not None and health.departed.how == "left"
        (source,) = robot.aggregator.sources()
        assert source.departed is not None and source.departed.component == "left"
        fields = robot.fields()
        assert any(re.fullmatch(r"range/left LEFT \d+\.\ds ago", f) for f in fields), fields
        assert not any(f.startswith(("UNHEALTHY", "refused")) for f in fields), fields
        status = robot.controller.status()
        (shown,) = status["sources"]
        assert shown["departed"] == "left"
        assert shown["departed_why"].startswith("its component left said goodbye")
        # Back under the same name: no longer departed.
        again = Ranger(bus=other, name="left")
        await again.start()
        await announced(robot, "left")
        await eventually(lambda: robot.aggregator.sources()[0].departed is None, timeout_s=5,
                         what="the source back")
        await again.aclose()
    finally:
        await ranger.aclose()
        await other.aclose()


@pytest.mark.asyncio
async def test_a_component_whose_token_vanishes_without_a_goodbye_is_gone(
        robot: Robot) -> None:
    """What a killed process looks like from the robot: its heartbeat said nothing of
    leaving, and then its token went."""
    other = Bus(transport=robot.net, robot="unit", clock=SimClock(10**9))
    try:
        token = other.declare_token(other.keys.alive("lost"))
        sample = other.publisher(RANGE, "lost", period_s=0.04)
        sample.publish({"range_mm": 300, "status": "ok"})
        other.publisher(HEARTBEAT, "lost", period_s=0.5).publish(
            {"component": "lost", "publishes": [{"key": sample.key, "pub": sample.pub}]})
        await robot.net.settle()
        await announced(robot, "lost")
        token.undeclare()
        await robot.net.settle()
        (source,) = robot.aggregator.sources()
        assert source.departed is not None and source.departed.how == "gone"
        assert any(re.fullmatch(r"range/lost GONE \d+\.\ds ago", f) for f in robot.fields())
        assert robot.controller.status()["sources"][0]["departed_why"].startswith(
            "its component lost vanished without a goodbye")
        # A source of the same key from another publisher is not the departed one's.
        newcomer = other.publisher(RANGE, "lost", period_s=0.04)
        newcomer.publish({"range_mm": 200, "status": "ok"})
        await robot.net.settle()
        assert robot.aggregator.sources()[0].departed is None
    finally:
        await other.aclose()


@pytest.mark.asyncio
async def test_a_token_is_healthy_without_heartbeats_and_stopped_heartbeats_are_not(
        robot: Robot) -> None:
    """20 joiners whose token is heard before their first heartbeat are never UNHEALTHY, nor
    a component that sends no heartbeat at all; a component whose heartbeats stopped (its
    token still there) is, 3 periods after its last."""
    other = Bus(transport=robot.net, robot="unit", clock=SimClock(10**9))
    try:
        for i in range(20):
            token = other.declare_token(other.keys.alive(f"joiner{i}"))
            await robot.net.settle()
            assert robot.health.unhealthy() == [], i  # the token first: not yet a heartbeat
            other.publisher(HEARTBEAT, f"joiner{i}", period_s=0.5).publish(
                {"component": f"joiner{i}"})
            await robot.net.settle()
            assert robot.health.unhealthy() == [], i
            token.undeclare()
        other.declare_token(other.keys.alive("token-only"))
        other.declare_token(other.keys.alive("stuck"))
        other.publisher(HEARTBEAT, "stuck", period_s=0.5).publish({"component": "stuck"})
        await robot.net.settle()
        stuck = robot.health.components["stuck"]
        assert stuck.last_heartbeat_s is not None
        assert stuck.healthy(stuck.last_heartbeat_s + 1.5)
        assert not stuck.healthy(stuck.last_heartbeat_s + 1.6)  # 3 periods of 0.5 s late
        assert robot.health.components["token-only"].healthy(time.monotonic() + 3600)
        assert not any(f.startswith("UNHEALTHY") for f in robot.fields())
    finally:
        await other.aclose()


@pytest.mark.asyncio
async def test_a_forgotten_source_is_housekeeping_not_a_refusal(robot: Robot) -> None:
    other = Bus(transport=robot.net, robot="unit", clock=SimClock(10**9))
    try:
        other.publisher(RANGE, "quiet", period_s=0.04).publish({"range_mm": 1, "status": "ok"})
        await robot.net.settle()
        assert "range/quiet" in robot.aggregator.entries
        assert robot.aggregator.forget_silent(10**9 + 61 * 10**9) == 1
        assert robot.aggregator.dropped() == {"evicted": 0, "forgotten": 1}
        assert "forgotten" not in robot.aggregator.refusals()
        assert not any(f.startswith("refused") for f in robot.fields())
        assert robot.controller.status()["dropped"]["forgotten"] == 1
    finally:
        await other.aclose()


def test_a_device_process_stopped_has_left_one_killed_is_gone() -> None:
    """Real processes: the default simulated robot, and two range finders attached to it
    (``python -m components.range``): the one stopped (SIGINT, as Ctrl-C) is shown as LEFT,
    the one killed (SIGKILL: no goodbye) as GONE, on the robot's status line — and neither
    as a refusal nor as UNHEALTHY. A token-only range finder (examples/plain_range_sensor.py:
    plain zenoh and msgpack, no heartbeat) attached all along is never UNHEALTHY either."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    robot = Process("-m", "ubf_async.launch", "--listen", endpoint, "--status-period-s", "0.25",
                    "--duration", "600")
    rangers: list[Process] = []
    try:
        robot.wait_for_line("  controller:", timeout_s=60)
        plain = Process(str(ROOT / "examples" / "plain_range_sensor.py"), "--connect", endpoint,
                        "--robot", "mini", "--name", "plain", "--rate-hz", "25")
        rangers.append(plain)
        first = len(robot.lines)
        robot.wait_for_line("range/plain ", timeout_s=60)
        for name in ("polite", "killed"):
            ranger = Process("-m", "components.range", "--connect", endpoint, "--name", name)
            rangers.append(ranger)
            ranger.wait_for_line("attached to robot", timeout_s=60)
            robot.wait_for_line(f"range/{name} ", timeout_s=30)
        _, polite, killed = rangers
        polite.proc.send_signal(signal.SIGINT)
        assert polite.proc.wait(timeout=30) == 0, polite.output()
        killed.kill()
        robot.wait_for_match(r"range/killed GONE [\d.]+s ago.*range/polite LEFT [\d.]+s ago"
                             r"|range/polite LEFT [\d.]+s ago.*range/killed GONE [\d.]+s ago",
                             timeout_s=30)
        for later in robot.lines[first:]:
            assert "UNHEALTHY" not in later and "refused" not in later, later
    finally:
        for ranger in rangers:
            ranger.kill()
        robot.terminate()
