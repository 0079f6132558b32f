"""Shared fixtures: real zenoh sessions on loopback, multicast scouting off."""

from __future__ import annotations

import asyncio
import contextlib
import os
import sys
import time
from collections.abc import AsyncIterator, Callable
from pathlib import Path
from typing import Any

import msgspec
import pytest
import pytest_asyncio
import zenoh

from tests.ports import free_port
from ubf_async.clocks.clock import Hold, WallClock
from ubf_async.net.options import ConnectionOptions
from ubf_async.net.transport import ZenohTransport
from ubf_async.runtime import lending
from ubf_async.runtime.bus import Bus


def pytest_configure(config: pytest.Config) -> None:
    # looptime's plugin asks the policy for "the" event loop before every test. Before the
    # first async test has run, Python 3.11's policy makes a new loop for that question, and
    # nobody closes it (an unclosed-loop warning, an error here). Saying "no loop" up front
    # makes the question fail instead, as it does after any async test.
    asyncio.set_event_loop(None)
    keep_the_bytecode_of_spawned_processes(config)
    one_blas_thread_per_process()


def one_blas_thread_per_process() -> None:
    """NumPy's OpenBLAS starts a thread per core when it is imported, and they spin a while
    waiting for work that never comes: ≈ 0.06 s of CPU in each of the hundreds of processes
    the suite spawns (robots, tools, render processes, the workers). Nothing here multiplies
    matrices big enough for OpenBLAS to use a second thread (a camera's 3×3 rotations, norms
    of a few points), so one thread computes the same numbers. Set before the workers start,
    so every process of the session inherits it; a value given in the environment is kept."""
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


def keep_the_bytecode_of_spawned_processes(config: pytest.Config) -> None:
    """Under ``PYTHONDONTWRITEBYTECODE`` (set on many machines and images) each of the
    hundreds of Python processes the suite spawns compiled this project's modules from source
    again, ≈ 0.2 s of CPU each — a tenth of the suite's CPU. The session's processes (workers
    included: they start after this) write their bytecode under pytest's cache instead
    (``PYTHONPYCACHEPREFIX``), outside the source tree, as the variable asks."""
    if not os.environ.get("PYTHONDONTWRITEBYTECODE") or "PYTHONPYCACHEPREFIX" in os.environ:
        return
    if not config.pluginmanager.has_plugin("cacheprovider"):
        return  # -p no:cacheprovider: no cache folder (config.cache is not there at all)
    os.environ["PYTHONPYCACHEPREFIX"] = str(config.cache.mkdir("pycache"))
    del os.environ["PYTHONDONTWRITEBYTECODE"]


def pytest_xdist_auto_num_workers(config: pytest.Config) -> int:
    """``--numprocesses=auto``: one worker more than the cores this process may use (at least
    2; ``--maxprocesses`` caps it): most tests spend their time waiting — on a subprocess, a
    zenoh session, a simulated run's wall-time bound — so a core would idle between them
    (on 2 cores: 4 min 28 s with three workers, 5 min 34 s with two)."""
    return max(2, len(os.sched_getaffinity(0)) + 1)


LENDING_TESTS = ("test_lending.py",)
"""Test modules of the opt-in lending loop itself (``UBF_LOOP=lending``): run on it."""


def pytest_asyncio_loop_factories(config: pytest.Config, item: pytest.Item
                                  ) -> dict[str, Callable[[], asyncio.AbstractEventLoop]]:
    """Async tests run on the event loop every entry point runs on by default
    (:func:`ubf_async.cli.run.loop_factory` without ``UBF_LOOP``: asyncio's selector loop that
    tells the lockstep when it is idle and lends itself to no thread); the lending loop's own
    tests (:data:`LENDING_TESTS`) on the lending loop."""
    if item.path.name in LENDING_TESTS:
        return {"lending": lending.new_event_loop}
    return {"asyncio": lending.new_idle_event_loop}


@pytest.fixture
def endpoint() -> str:
    return f"tcp/127.0.0.1:{free_port()}"


@pytest.fixture
def robot(request: pytest.FixtureRequest) -> str:
    """A robot name unique to the test, so concurrent runs never cross-talk."""
    return "t" + str(abs(hash(request.node.nodeid)) % 10**8)


async def eventually(
    predicate: Callable[[], bool], *, timeout_s: float = 5.0, what: str = "condition"
) -> None:
    """Wait until ``predicate()`` holds, polling every 5 ms; fail after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s}s waiting for {what}")
        await asyncio.sleep(0.005)


class LoopClock:
    """The robot's clock as the event loop's own time: wall time on a normal loop, virtual
    time in a test marked ``@pytest.mark.looptime`` (which fast-forwards the loop's time
    whenever every task waits on a timer). :class:`~ubf_async.clocks.clock.WallClock` reads
    ``time.monotonic_ns()``, which looptime cannot move: a component stamped and scheduled by
    this clock runs on one virtual time with the loop's own timers (restart backoffs,
    heartbeats, ``asyncio.wait_for``). Only for buses without zenoh threads (the in-process
    transport): looptime cannot know that a sample is on its way from another thread."""

    is_simulated = False
    resets = 0

    def __init__(self) -> None:
        self._loop = asyncio.get_running_loop()

    def now_ns(self) -> int:
        return round(self._loop.time() * 1e9)

    def stalled_s(self, wall_now_ns: int | None = None) -> float:
        return 0.0

    def hold(self, until_ns: int) -> Hold:
        return WallClock().hold(until_ns)  # loop time waits for nobody either

    async def sleep_until_ns(self, deadline_ns: int) -> None:
        await asyncio.sleep(max(0.0, (deadline_ns - self.now_ns()) / 1e9))

    async def sleep(self, seconds: float) -> None:
        await asyncio.sleep(max(0.0, seconds))



REPOSITORY = Path(__file__).resolve().parent.parent


def repository_env() -> dict[str, str]:
    """The environment for a child process that runs this repository's code: ``python -m``
    from the root finds it first anyway, but a script (``python examples/x.py``) puts its
    own folder first and would import the installed package, maybe another checkout's."""
    paths = [str(REPOSITORY), *filter(None, [os.environ.get("PYTHONPATH")])]
    return {**os.environ, "PYTHONPATH": os.pathsep.join(paths), "PYTHONUNBUFFERED": "1"}


async def spawn(*args: str) -> asyncio.subprocess.Process:
    """``python ARGS`` from the repository's root, running this repository's code
    (:func:`repository_env`), its stdout and stderr on a pipe (read it with
    :func:`read_until`)."""
    return await asyncio.create_subprocess_exec(
        sys.executable, *args, cwd=REPOSITORY, env=repository_env(),
        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.STDOUT)


async def stop(proc: asyncio.subprocess.Process) -> None:
    """Kill ``proc`` (if it still runs) and reap it."""
    with contextlib.suppress(ProcessLookupError):
        proc.kill()
    await proc.wait()


async def read_until(proc: asyncio.subprocess.Process, text: str, *,
                     timeout_s: float = 30.0) -> str:
    """Read ``proc``'s stdout line by line until a line contains ``text``; return all read.
    Launch prints ``controller:`` once every component has started (and listens)."""
    assert proc.stdout is not None
    printed = ""
    while text not in printed:
        line = await asyncio.wait_for(proc.stdout.readline(), timeout_s)
        assert line, f"the process ended before printing {text!r}: {printed}"
        printed += line.decode()
    return printed


@pytest_asyncio.fixture
async def robot_bus(endpoint: str, robot: str) -> AsyncIterator[Bus]:
    """The robot's session, listening on a loopback endpoint."""
    bus = await Bus.open(ConnectionOptions(robot=robot, listen=[endpoint]))
    yield bus
    await bus.aclose()


def zenoh_session(bus: Bus) -> zenoh.Session:
    """The zenoh session under a bus made by ``Bus.open`` (its transport owns it): tests reach
    around the bus with it, as another program on the network would."""
    transport = bus.transport
    assert isinstance(transport, ZenohTransport), transport
    return transport.session


@pytest_asyncio.fixture
async def peer_bus(robot_bus: Bus, endpoint: str, robot: str) -> AsyncIterator[Bus]:
    """Another session (think: another process) connected to the robot's."""
    bus = await Bus.open(ConnectionOptions(robot=robot, connect=[endpoint]))
    await eventually(lambda: len(list(zenoh_session(robot_bus).info.peers_zid())) > 0,
                     what="peer session to connect")
    yield bus
    await bus.aclose()


class SimRobot:
    """The simulated robot in this process: simulator + device components on ``bus``."""

    def __init__(self, bus: Bus, world_config: object, *, speed: float, devices: tuple[str, ...],
                 **device_options: object) -> None:
        from components.sim.runner.stepper import SimulatorComponent, simulated_devices
        from components.sim.world.physics import World
        from ubf_async.clocks.clock import SimClock

        self.clock = SimClock()
        bus.clock = self.clock
        self.bus = bus
        self.world = World(world_config)  # type: ignore[arg-type]
        self.devices = simulated_devices(bus=bus, world=self.world, devices=devices,
                                         **device_options)  # type: ignore[arg-type]
        self.sim = SimulatorComponent(bus=bus, world=self.world, clock=self.clock, speed=speed)
        self.extra: list[object] = []

    def device(self, prefix: str) -> object:
        return next(d for d in self.devices if d.name.startswith(prefix))

    async def __aenter__(self) -> SimRobot:
        for c in self.devices:
            await c.start()
        await self.sim.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.sim.aclose()
        for c in reversed(self.devices):
            await c.aclose()


async def start_seeking_robot(bus: Bus, run: object) -> tuple[object, list[object]]:
    """The default tree (seek_pink_ball) on a simulation run's devices: devices, aggregator,
    controller and the run's own components, started in that order. Returns (controller,
    components); close the components in reverse order."""
    from components.sim.runner.stepper import simulated_devices
    from ubf_async.behaviors.pink_ball import seek_pink_ball
    from ubf_async.runtime.aggregator import StateAggregator
    from ubf_async.runtime.controller import Controller

    devices = simulated_devices(bus=bus, world=run.world, seed=run.seed)  # type: ignore[attr-defined]
    run.add_devices(devices)  # type: ignore[attr-defined]
    aggregator = StateAggregator(bus=bus)
    controller = Controller(bus=bus, aggregator=aggregator, root=seek_pink_ball())
    components = [aggregator, controller, *devices, *run.components()]  # type: ignore[attr-defined]
    for component in components:
        await component.start()
    return controller, components


def as_dict(data: Any) -> dict[str, Any]:
    """A decoded message's data as the plain map a msgpack client sees (fields left at their
    defaults are absent): for tests that collect commands and compare them as maps."""
    plain: dict[str, Any] = msgspec.msgpack.decode(msgspec.msgpack.encode(data))
    return plain
