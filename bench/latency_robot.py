"""The robot side of the latency benchmark: a ubf_async controller process, instrumented.

Run as a child process by ``bench/latency.py``::

    python -m bench.latency_robot '<json config>'

``role: "controller"`` — a zenoh session listening on a loopback endpoint, the project's
:class:`~ubf_async.aggregator.StateAggregator` and :class:`~ubf_async.controller.Controller`
with :func:`reflex_tree` (avoid above the thesis's seek-the-pink-ball), configured by
``mode`` (periodic, sync or event), ``rate_hz``, ``trigger`` and ``reflex`` (the periodic
controller's ``reflex_sources``; ``python -m ubf_async.launch`` defaults to ``["range/"]``).
Prints ``READY`` once both components run, serves until its stdin closes, then prints
``RESULT <json>`` with what the instrumentation saw.

With ``wake_task: true`` the controller ticks the way event mode did before triggered ticks
moved into the aggregator's listener: its own task awaits
:meth:`~ubf_async.aggregator.StateAggregator.wait_for_update` on ``range/front`` and calls
:meth:`~ubf_async.controller.Controller.tick` (both public), so each sample costs one more
pass through the event loop. It is kept beside the real event mode for comparison only.

``role: "echo"`` — the transport floor's responder: raw zenoh, no asyncio, no ubf_async
runtime. Its subscriber callback (on zenoh's thread) unpacks the sample and puts a minimal
``drive``-shaped msgpack reply with ``based_on`` at once.

``role: "simrobot"`` — the full simulated robot in this process (simulator at speed 1 on
wall-clock pacing, camera, encoders, IR, motors, radio) plus aggregator and the launch's
default controller (periodic at ``rate_hz``, reflexes on ``range/``), for ``duration_s`` of
wall time; reports tick timing in wall and simulated time.

The instrumentation only reads ``time.monotonic_ns()`` through public hooks and methods: the
handler given to :meth:`~ubf_async.component.Component.subscribe` is wrapped (its start),
:meth:`~ubf_async.aggregator.StateAggregator.ingest` (its start: decode is done), a state
listener registered before the controller's (the sample is stored),
:meth:`~ubf_async.controller.Controller.tick` (its start and end) and the drive publisher's
``publish`` (when it returns, wrapped through the public
:meth:`~ubf_async.component.Component.publisher`). It adds a few µs per sample.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import sys
import threading
import time
from typing import Any

from ubf_async import Action, Behavior, Child, Composite, HighestPriority, State
from ubf_async.aggregator import SourceEntry, StateAggregator
from ubf_async.behaviors import seek_pink_ball
from ubf_async.bus import Bus, ConnectionOptions, Publisher, SampleHandler, Subscription
from ubf_async.controller import Controller

AVOID_BELOW_MM = 200
AVOID_SPEED = -50.0
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
# Instrumented subclasses (public methods and hooks only; see docs/latency.md)


class TimedAggregator(StateAggregator):
    """Records, per accepted sample: zenoh callback time (the bridge's ``received_ns``), the
    loop handler's start, ingest's start (decode and validation done) and the moment the
    sample is stored (a listener registered before any other, so before the controller's,
    whose triggered tick runs inside ingest)."""

    def __init__(self, **kw: Any) -> None:
        super().__init__(**kw)
        self.samples: list[tuple[str, int, int, int, int, int]] = []
        """(source, seq, received_ns, handler_start_ns, ingest_start_ns, stored_ns)"""
        self.subscription: Subscription | None = None
        self._handler_ns = 0
        self._ingest_ns = 0
        self.add_listener(self._stored)

    def subscribe(self, key_expr: str, handler: SampleHandler, *, latest: bool = True
                  ) -> Subscription:
        def timed(key: str, payload: bytes, received_ns: int) -> None:
            self._handler_ns = time.monotonic_ns()
            handler(key, payload, received_ns)

        self.subscription = super().subscribe(key_expr, timed, latest=latest)
        return self.subscription

    def ingest(self, source: str, message: Any, received_ns: int) -> None:
        self._ingest_ns = time.monotonic_ns()
        super().ingest(source, message, received_ns)

    def _stored(self, source: str, entry: SourceEntry) -> None:
        stored = time.monotonic_ns()
        if len(self.samples) < 200_000:
            self.samples.append((source, entry.message.seq, entry.received_ns,
                                 self._handler_ns, self._ingest_ns, stored))


class TimedController(Controller):
    """Records, per tick: wall start/end, robot-clock time, the sample it was based on,
    whether a sample triggered it (clock ticks have no ``based_on``) and when the drive
    command's ``publish`` (stamp, encode, zenoh put) returned."""

    def __init__(self, **kw: Any) -> None:
        super().__init__(**kw)
        self.ticks: list[tuple[Any, ...]] = []
        """(wall_start_ns, wall_end_ns, robot_now_ns, basis_source, basis_seq,
        basis_stamp_ns, camera_seq, camera_stamp_ns, triggered, drive_put_returned_ns)"""
        self._drive_returned_ns: int | None = None

    def publisher(self, key: str, schema: str, *, period_s: float | None = None) -> Publisher:
        pub = super().publisher(key, schema, period_s=period_s)
        if schema == "drive":
            publish = pub.publish

            def timed_publish(data: Any, *, stamp_ns: int | None = None) -> tuple[int, int]:
                sent = publish(data, stamp_ns=stamp_ns)
                self._drive_returned_ns = time.monotonic_ns()
                return sent

            pub.publish = timed_publish  # type: ignore[method-assign]
        return pub

    def tick(self, *, based_on: Any = None) -> Any:
        t0 = time.monotonic_ns()
        self._drive_returned_ns = None
        basis = based_on if based_on is not None else self.aggregator.newest()
        trace = super().tick(based_on=based_on)
        t1 = time.monotonic_ns()
        camera = self.aggregator.entries.get(self.sync_source)
        if len(self.ticks) < 200_000:
            self.ticks.append((
                t0, t1, self.stats.tick_starts_ns[-1],
                None if basis is None else basis.source,
                None if basis is None else basis.message.seq,
                None if basis is None else basis.message.stamp_ns,
                -1 if camera is None else camera.message.seq,
                -1 if camera is None else camera.message.stamp_ns,
                based_on is not None, self._drive_returned_ns,
            ))
        return trace


async def wake_task_ticks(agg: StateAggregator, ctl: Controller, source: str) -> None:
    """The pre-listener event mode, from public calls: the controller's own task waits for
    each new sample of ``source`` (a future resolved inside ingest) and then ticks."""
    version = 0
    while True:
        entry = await agg.wait_for_update(source, after_version=version)
        version = entry.version
        ctl.tick(based_on=entry)


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


def build_controller(bus: Bus, agg: StateAggregator, cfg: dict[str, Any]) -> TimedController:
    mode, trigger = cfg["mode"], cfg.get("trigger")
    if cfg.get("wake_task"):
        # Event mode on a source that never publishes: no listener tick; wake_task_ticks
        # does the ticking.
        mode, trigger = "event", "bench/none"
    return TimedController(bus=bus, aggregator=agg, root=reflex_tree(), mode=mode,
                           rate_hz=cfg.get("rate_hz", 50.0), trigger=trigger,
                           reflex_sources=tuple(cfg.get("reflex") or ()))


async def controller_role(cfg: dict[str, Any]) -> dict[str, Any]:
    options = ConnectionOptions(robot=cfg["robot"], listen=[cfg["endpoint"]])
    bus = await Bus.open(options)
    stop = _stdin_closed_event(asyncio.get_running_loop())
    agg = TimedAggregator(bus=bus)
    ctl = build_controller(bus, agg, cfg)
    waker: asyncio.Task[None] | None = None
    try:
        for c in (agg, ctl):
            await c.start()
        for c in (agg, ctl):
            await asyncio.wait_for(c.running.wait(), 10)
        if cfg.get("wake_task"):
            waker = asyncio.create_task(wake_task_ticks(agg, ctl, "range/front"))
        print("READY", flush=True)
        await stop.wait()
        bridge = agg.subscription.stats if agg.subscription is not None else None
        return {
            "samples": agg.samples, "ticks": ctl.ticks, "overruns": ctl.stats.overruns,
            "errors": ctl.stats.errors, "triggered": ctl.stats.triggered,
            "malformed": sum(agg.malformed.values()),
            "coalesced": bridge.coalesced if bridge else None,
            "received": bridge.received if bridge else None,
        }
    finally:
        if waker is not None:
            waker.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await waker
        await ctl.aclose()
        await agg.aclose()
        await bus.aclose()


async def simrobot_role(cfg: dict[str, Any]) -> dict[str, Any]:
    from components.sim.component import SimulatorComponent, simulated_devices
    from components.sim.scenes import ball_in_view
    from components.sim.world import World
    from ubf_async.clock import SimClock

    clock = SimClock()
    bus = await Bus.open(ConnectionOptions(robot=cfg["robot"], listen=[cfg["endpoint"]]),
                         clock=clock)
    world = World(ball_in_view(seed=0))
    sim = SimulatorComponent(bus=bus, world=world, clock=clock, speed=1.0)
    devices = simulated_devices(bus=bus, world=world, seed=0)
    agg = TimedAggregator(bus=bus)
    ctl = TimedController(bus=bus, aggregator=agg, root=reflex_tree(), mode="periodic",
                          rate_hz=cfg["rate_hz"],
                          reflex_sources=tuple(cfg.get("reflex", DEFAULT_REFLEX)))
    components = [agg, *devices, sim, ctl]
    try:
        for c in components:
            await c.start()
        await asyncio.wait_for(clock.started.wait(), 10)
        # Warm-up (wall time): let the camera deliver frames and the controller settle.
        await asyncio.sleep(cfg.get("warmup_s", 1.0))
        first_tick = len(ctl.ticks)
        sim0, wall0 = world.time_s, time.monotonic()
        late0 = sim.late_steps
        await asyncio.sleep(cfg["duration_s"])
        ticks = ctl.ticks[first_tick:]
        return {
            "ticks": ticks,
            "sim_s": world.time_s - sim0, "wall_s": time.monotonic() - wall0,
            "late_steps": sim.late_steps - late0, "step_s": sim.step_s,
            "overruns": ctl.stats.overruns, "camera_frames": next(
                (d.frames for d in devices if d.name.startswith("camera")), 0),
        }
    finally:
        for c in reversed(components):
            await c.aclose()
        await bus.aclose()


def echo_role(cfg: dict[str, Any]) -> dict[str, Any]:
    import msgpack
    import zenoh

    from ubf_async.protocol import Keys

    keys = Keys(cfg["robot"])
    session = zenoh.open(ConnectionOptions(robot=cfg["robot"], listen=[cfg["endpoint"]])
                         .zenoh_config())
    pub = session.declare_publisher(keys.cmd("drive"))
    count = [0]

    def on_sample(sample: zenoh.Sample) -> None:
        msg = msgpack.unpackb(sample.payload.to_bytes())
        count[0] += 1
        pub.put(msgpack.packb({
            "schema": "drive", "v": 1, "stamp_ns": time.monotonic_ns(), "seq": count[0],
            "data": {"speed": 0.0, "turn": 0.0, "based_on": {
                "source": "range/front", "seq": msg["seq"], "stamp_ns": msg["stamp_ns"]}},
        }))

    sub = session.declare_subscriber(keys.sensor("range", "front"), on_sample)
    print("READY", flush=True)
    sys.stdin.read()
    sub.undeclare()
    pub.undeclare()
    session.close()
    return {"replies": count[0]}


def main(argv: list[str] | None = None) -> int:
    cfg = json.loads((argv or sys.argv[1:])[0])
    role = cfg["role"]
    if role == "echo":
        result = echo_role(cfg)
    elif role == "controller":
        result = asyncio.run(controller_role(cfg))
    elif role == "simrobot":
        result = asyncio.run(simrobot_role(cfg))
    else:
        raise SystemExit(f"unknown role {role!r}")
    sys.stdout.write("RESULT " + json.dumps(result) + "\n")
    sys.stdout.flush()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
