"""The robot side of the latency benchmark: a ubf_async controller process, instrumented.

Run as a child process by ``bench/latency.py``::

    python -m bench.latency_robot '<json config>'

``role: "controller"`` — a zenoh session listening on a loopback endpoint, the project's
:class:`~ubf_async.runtime.aggregator.StateAggregator` and
:class:`~ubf_async.runtime.controller.Controller` with :func:`reflex_tree` (avoid above the
thesis's seek-the-pink-ball), configured by
``mode`` (periodic, sync or event), ``rate_hz``, ``trigger`` and ``reflex`` (the periodic
controller's ``reflex_sources``; ``python -m ubf_async.launch`` defaults to ``["range/"]``).
Prints ``READY`` once both components run, serves until its stdin closes, then prints
``RESULT <json>`` with what the instrumentation saw.

``instrument: false`` leaves the hooks alone (the controller as it runs for a user; only the
round trip is measured); ``loop`` chooses the event loop (``asyncio`` — the default of every
entry point —, ``lending`` or ``uvloop``: ``UBF_LOOP``, :func:`ubf_async.cli.run.loop_factory`).

``role: "echo"`` — the transport floor's responder: raw zenoh, no asyncio, no ubf_async
runtime. Its subscriber callback (on zenoh's thread) unpacks the sample and puts a minimal
``drive``-shaped msgpack reply with ``based_on`` at once.

``role: "tree_echo"`` — the Python floor: the echo doing the controller's essential work in its
zenoh callback — decode and validate the sample (``ubf_async.wire.protocol``), store it in a
:class:`~ubf_async.runtime.aggregator.StateAggregator`, snapshot, evaluate :func:`reflex_tree`,
encode the ``drive`` command — with no bus, no event loop, no hooks, no bookkeeping: what any
Python controller of this tree pays at least.

``role: "simrobot"`` — the full simulated robot in this process (simulator at speed 1 on
wall-clock pacing, camera, encoders, IR, motors, radio) plus aggregator and the launch's
default controller (periodic at ``rate_hz``, reflexes on ``range/``), for ``duration_s`` of
simulated time (as long in wall time unless the machine is too busy to keep up); reports tick
timing in wall and simulated time.

The components are the framework's own, unmodified: no subclass, no wrapped method. The
instrumentation (:class:`Recorder`) reads ``time.monotonic_ns()`` in the documented hooks
only: the aggregator's ``on_receive`` (handler start), ``on_ingest`` (decode and validation
done), ``on_sample`` (stored; one added before the controller's, one after it for the end of
a triggered tick) and the controller's ``on_tick`` (right after the drive command's put
returned; the tick's start is its state's ``now_ns``). It adds a few µs per sample.
"""

from __future__ import annotations

import asyncio
import json
import os
import sys
import threading
import time
from collections.abc import Callable, Mapping
from typing import Any

from ubf_async import Action, Behavior, Child, Composite, HighestPriority, State
from ubf_async.behaviors.pink_ball import seek_pink_ball
from ubf_async.cli.run import run_loop
from ubf_async.net.options import ConnectionOptions
from ubf_async.runtime.aggregator import SourceEntry, StateAggregator
from ubf_async.runtime.bus import Bus
from ubf_async.runtime.controller import Controller
from ubf_async.runtime.gcfreeze import freeze_startup_objects

AVOID_BELOW_MM = 200
AVOID_SPEED = -50.0
PROFILE_ENV = "UBF_BENCH_PROFILE_DIR"
"""If set, the controller role runs under cProfile and writes ``controller-<mode>-<pid>.prof``
there (the figures of such a run are slowed by the profiler: read them only relative)."""
DEFAULT_REFLEX = ("range/",)
"""``python -m ubf_async.launch``'s default ``--reflex``."""


class Avoid(Behavior):
    """The bench's reflex: an IR reading nearer than 200 mm → back off at speed −50."""

    def __init__(self, *, source: str = "range/front", name: str = "avoid") -> None:
        super().__init__(name=name)
        self.source = source

    def act(self, state: State) -> Action | None:
        reading = state.fresh(self.source)
        if reading is None:
            return None
        mm = reading.value.get("range_mm")
        if reading.value.get("status") == "too_close" or (mm is not None and mm < AVOID_BELOW_MM):
            return Action(speed=AVOID_SPEED, turn=0.0)
        return None


def reflex_tree(camera_source: str = "camera/front") -> Composite:
    """Avoid (priority 2) above the thesis's seek-the-pink-ball composite (priority 1)."""
    return Composite(name="root", arbiter=HighestPriority(), children=[
        Child(Avoid(), priority=2),
        Child(seek_pink_ball(source=camera_source, search_period_s=4.0), priority=1),
    ])


# ---------------------------------------------------------------------------------------------
# Instrumentation through the documented hooks (see docs/latency.md)


def _field(data: Any, name: str) -> Any:
    """A field of drive data, whether the codec hands out a mapping or a typed struct."""
    return data.get(name) if isinstance(data, Mapping) else getattr(data, name, None)


class Recorder:
    """Stamps ``time.monotonic_ns()`` at the framework's hooks, per sample and per tick.

    Per accepted sample: the bridge's ``received_ns`` (its zenoh callback), the
    aggregator's ``on_receive`` (handler start: the bridge hand-off is over), ``on_ingest``
    (decoded and validated) and ``on_sample`` (stored; added before the controller's own
    ``on_sample``, so before its triggered tick).

    Per tick (``Controller.on_tick``, which runs right after the drive command's ``publish``
    returned): the tick's start (``state.now_ns``: the robot clock is host monotonic time
    on a wall-clock bus; with ``wall_start=False`` — simulated time — the hook's own stamp
    stands in), the robot clock, the sample it was based on, the camera sample it saw,
    whether a sample triggered it (``stats.periodic`` counts clock ticks before the hook
    runs) and when the drive command's put returned. The tick's end comes from a second
    ``on_sample`` hook added after the controller started (it runs when the controller's
    hook — the triggered tick — returns)."""

    LIMIT = 200_000

    def __init__(self, agg: StateAggregator, ctl: Controller, *, wall_start: bool = True
                 ) -> None:
        self.samples: list[tuple[str, int, int, int, int, int]] = []
        """(source, seq, received_ns, handler_start_ns, ingest_start_ns, stored_ns)"""
        self.ticks: list[list[Any]] = []
        """[wall_start_ns, wall_end_ns, robot_now_ns, basis_source, basis_seq,
        basis_stamp_ns, camera_seq, camera_stamp_ns, triggered, drive_put_returned_ns]"""
        self._ctl = ctl
        self._wall_start = wall_start
        self._camera = ctl.sync_source
        self._handler_ns = 0
        self._ingest_ns = 0
        self._periodic = 0
        agg.on_receive(self._received)
        agg.on_ingest(self._ingested)
        agg.on_sample(self._stored)
        ctl.on_tick(self._ticked)

    def after_controller_started(self, agg: StateAggregator) -> None:
        agg.on_sample(self._tick_returned)

    def _received(self, key: str, payload: bytes, received_ns: int) -> None:
        self._handler_ns = time.monotonic_ns()

    def _ingested(self, source: str, message: Any, received_ns: int) -> None:
        self._ingest_ns = time.monotonic_ns()

    def _stored(self, source: str, entry: SourceEntry) -> None:
        stored = time.monotonic_ns()
        if len(self.samples) < self.LIMIT:
            self.samples.append((source, entry.message.seq, entry.received_ns,
                                 self._handler_ns, self._ingest_ns, stored))

    def _ticked(self, state: State, trace: Any, command: Any) -> None:
        put_returned = time.monotonic_ns()
        periodic = self._ctl.stats.periodic
        triggered = periodic == self._periodic
        self._periodic = periodic
        if len(self.ticks) >= self.LIMIT:
            return
        basis = _field(command, "based_on")
        camera = state.get(self._camera)
        self.ticks.append([
            state.now_ns if self._wall_start else put_returned, None, state.now_ns,
            None if basis is None else _field(basis, "source"),
            None if basis is None else _field(basis, "seq"),
            None if basis is None else _field(basis, "stamp_ns"),
            -1 if camera is None else camera.seq, -1 if camera is None else camera.stamp_ns,
            triggered, put_returned,
        ])

    def _tick_returned(self, source: str, entry: SourceEntry) -> None:
        """The tick based on this sample, if it was the last, has returned (its end stamp)."""
        end = time.monotonic_ns()
        last = self.ticks[-1] if self.ticks else None
        if (last is not None and last[1] is None and last[4] == entry.message.seq
                and last[3] == source):
            last[1] = end


# ---------------------------------------------------------------------------------------------
# Roles


def _stdin_closed_event(loop: asyncio.AbstractEventLoop) -> asyncio.Event:
    """An event set when the parent closes our stdin (how it tells us to stop)."""
    done = asyncio.Event()

    def reader() -> None:
        sys.stdin.read()
        loop.call_soon_threadsafe(done.set)

    threading.Thread(target=reader, daemon=True).start()
    return done


def build_controller(bus: Bus, agg: StateAggregator, cfg: dict[str, Any]) -> Controller:
    return Controller(bus=bus, aggregator=agg, root=reflex_tree(), mode=cfg["mode"],
                      rate_hz=cfg.get("rate_hz", 50.0), trigger=cfg.get("trigger"),
                      reflex_sources=tuple(cfg.get("reflex") or ()))


async def controller_role(cfg: dict[str, Any]) -> dict[str, Any]:
    options = ConnectionOptions(robot=cfg["robot"], listen=[cfg["endpoint"]])
    bus = await Bus.open(options)
    stop = _stdin_closed_event(asyncio.get_running_loop())
    # As launch does, the trigger is one of the robot's own sources (never evicted).
    agg = StateAggregator(bus=bus, protected_sources=[s for s in (cfg.get("trigger"),) if s])
    ctl = build_controller(bus, agg, cfg)
    rec = Recorder(agg, ctl) if cfg.get("instrument", True) else None
    try:
        for c in (agg, ctl):
            await c.start()
        for c in (agg, ctl):
            await asyncio.wait_for(c.running.wait(), 10)
        if rec is not None:
            rec.after_controller_started(agg)
        freeze_startup_objects()  # as launch does once everything has started
        print("READY", flush=True)
        await stop.wait()
        bridge = agg.subscription.stats if agg.subscription is not None else None
        return {
            "samples": rec.samples if rec else [], "ticks": rec.ticks if rec else [],
            "overruns": ctl.stats.overruns,
            "errors": ctl.stats.errors, "triggered": ctl.stats.triggered,
            "malformed": sum(agg.malformed.values()),
            "coalesced": bridge.coalesced if bridge else None,
            "received": bridge.received if bridge else None,
            "direct": bridge.direct if bridge else None,
            "lane": bridge.lane if bridge else None,
            **{k: getattr(bridge, k) if bridge else None
               for k in ("lane_waited", "lane_busy", "lane_deferred")},
        }
    finally:
        await ctl.aclose()
        await agg.aclose()
        await bus.aclose()


async def simrobot_role(cfg: dict[str, Any]) -> dict[str, Any]:
    from components.camera.component import CameraComponent
    from components.sim.runner.stepper import SimulatorComponent, simulated_devices
    from components.sim.scenarios.scenes import ball_in_view
    from components.sim.world.physics import World
    from ubf_async.clocks.clock import SimClock

    clock = SimClock()
    bus = await Bus.open(ConnectionOptions(robot=cfg["robot"], listen=[cfg["endpoint"]]),
                         clock=clock)
    world = World(ball_in_view(seed=0))
    sim = SimulatorComponent(bus=bus, world=world, clock=clock, speed=1.0)
    devices = simulated_devices(bus=bus, world=world, seed=0)
    agg = StateAggregator(bus=bus)
    ctl = Controller(bus=bus, aggregator=agg, root=reflex_tree(), mode="periodic",
                     rate_hz=cfg["rate_hz"],
                     reflex_sources=tuple(cfg.get("reflex", DEFAULT_REFLEX)))
    # Simulated time: a tick's wall-clock moment is when its command left (the hook's stamp).
    rec = Recorder(agg, ctl, wall_start=False)
    components = [agg, *devices, sim, ctl]
    try:
        for c in components:
            await c.start()
        await asyncio.wait_for(clock.started.wait(), 10)
        # The warm-up (the camera's first frames, the controller settling) and the window are
        # of simulated time: at speed 1 they take as long in wall time on an idle machine, and
        # a busy one, which slows the simulator, only stretches them — the window still holds
        # duration_s of ticks (wall_s says how long it took).
        await clock.sleep(cfg.get("warmup_s", 1.0))
        first_tick = len(rec.ticks)
        sim0, wall0 = world.time_s, time.monotonic()
        late0 = sim.late_steps
        await clock.sleep(cfg["duration_s"])
        ticks = rec.ticks[first_tick:]
        return {
            "ticks": ticks,
            "sim_s": world.time_s - sim0, "wall_s": time.monotonic() - wall0,
            "late_steps": sim.late_steps - late0, "step_s": sim.step_s,
            "overruns": ctl.stats.overruns, "camera_frames": next(
                (d.frames for d in devices
                 if d.name.startswith("camera") and isinstance(d, CameraComponent)), 0),
        }
    finally:
        for c in reversed(components):
            await c.aclose()
        await bus.aclose()


def serve_raw(cfg: dict[str, Any], answer: Callable[[bytes, int], bytes]) -> dict[str, Any]:
    """A raw zenoh session (no asyncio, no bus) answering each ``range/front`` sample in its
    subscriber callback, on zenoh's thread, with ``answer(payload, count)`` put on
    ``cmd/drive``; serves until stdin closes."""
    import zenoh

    from ubf_async.wire.keys import Keys

    keys = Keys(cfg["robot"])
    session = zenoh.open(ConnectionOptions(robot=cfg["robot"], listen=[cfg["endpoint"]])
                         .zenoh_config())
    pub = session.declare_publisher(keys.cmd("drive"))
    count = [0]

    def on_sample(sample: zenoh.Sample) -> None:
        count[0] += 1
        pub.put(answer(sample.payload.to_bytes(), count[0]))

    sub = session.declare_subscriber(keys.sensor("range", "front"), on_sample)
    print("READY", flush=True)
    sys.stdin.read()
    sub.undeclare()
    pub.undeclare()
    session.close()
    return {"replies": count[0]}


def echo_role(cfg: dict[str, Any]) -> dict[str, Any]:
    import msgpack

    def answer(payload: bytes, count: int) -> bytes:
        msg = msgpack.unpackb(payload)
        return bytes(msgpack.packb({
            "schema": "drive", "v": 1, "stamp_ns": time.monotonic_ns(), "seq": count,
            "data": {"speed": 0.0, "turn": 0.0, "based_on": {
                "source": "range/front", "seq": msg["seq"], "stamp_ns": msg["stamp_ns"]}},
        }))

    return serve_raw(cfg, answer)


def tree_echo_role(cfg: dict[str, Any]) -> dict[str, Any]:
    from ubf_async.clocks.clock import WallClock
    from ubf_async.wire.keys import Keys
    from ubf_async.wire.protocol import Encoder, decode
    from ubf_async.wire.topics import DRIVE, RANGE, BasedOn, Drive

    class StandInBus:  # what StateAggregator.ingest and snapshot read
        clock = WallClock()
        keys = Keys(cfg["robot"])

    agg = StateAggregator(bus=StandInBus())  # type: ignore[arg-type]
    tree = reflex_tree()
    # The controller's own drive encoding (built valid, not checked again): the floor does
    # the essential work with the cheapest means the framework has.
    encoder = Encoder(DRIVE, trusted=True)

    def answer(payload: bytes, count: int) -> bytes:
        received = time.monotonic_ns()
        message = decode(payload, topic=RANGE)
        agg.ingest("range/front", message, received)
        trace = tree.evaluate(agg.snapshot())
        action = trace.action if trace is not None else None
        return encoder.encode(Drive(
            speed=float(action.speed) if action is not None and action.speed is not None
            else 0.0,
            turn=float(action.turn) if action is not None and action.turn is not None else 0.0,
            based_on=BasedOn(source="range/front", seq=message.seq, stamp_ns=message.stamp_ns),
            tick=count), stamp_ns=time.monotonic_ns(), seq=count)

    return serve_raw(cfg, answer)


def main(argv: list[str] | None = None) -> int:
    cfg = json.loads((argv or sys.argv[1:])[0])
    role = cfg["role"]
    if "loop" in cfg:  # the event loop this controller runs on (ubf_async.cli.run.loop_factory)
        os.environ["UBF_LOOP"] = cfg["loop"]

    if role == "echo":
        result = echo_role(cfg)
    elif role == "tree_echo":
        result = tree_echo_role(cfg)
    elif role == "controller":
        profile_dir = os.environ.get(PROFILE_ENV)
        if profile_dir:  # cProfile the whole controller process (it slows every figure)
            import cProfile

            name = f"{cfg['mode']}-{cfg.get('loop', 'default')}"
            with cProfile.Profile() as prof:
                result = run_loop(controller_role(cfg))
            prof.dump_stats(os.path.join(profile_dir, f"controller-{name}-{os.getpid()}.prof"))
        else:
            result = run_loop(controller_role(cfg))
    elif role == "simrobot":
        result = run_loop(simrobot_role(cfg))
    else:
        raise SystemExit(f"unknown role {role!r}")
    sys.stdout.write("RESULT " + json.dumps(result) + "\n")
    sys.stdout.flush()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
