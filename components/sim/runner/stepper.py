"""The simulator on the bus: steps the pymunk world, owns simulation time, wires devices.

:class:`SimulatorComponent` steps the :class:`~components.sim.world.physics.World` in fixed steps,
paced to ``speed`` × real time (``--speed K``), advances the shared
:class:`~ubf_async.clocks.clock.SimClock` of its process and publishes the time on
``ubf/<robot>/clock`` so components in other processes follow it, with this run's random
``epoch`` (a new one for each simulator component: followers tell runs apart by it, see
:mod:`ubf_async.clocks.timesource`). It also publishes ground
truth (robot pose, ball position) on ``ubf/<robot>/sim/truth`` — outside ``sensor/``, so
behaviours never see it; tests and tools do — and the whole world snapshot on
``ubf/<robot>/sim/world``, from which sim-backed devices started in other processes
(``python -m components.range`` …) measure and render; a motors process sends its pulses back
on ``ubf/<robot>/sim/pulses``.

Lockstep: simulated time is a barrier, not a race. Before each 5 ms step the simulator waits
(:meth:`SimulatorComponent._barrier`) until everything of the current instant is done: its
process's event loop had nothing left to run
(:meth:`~ubf_async.runtime.lending.IdleEventLoop.idle` — a periodic wake-up, the samples it
publishes, a reflex tick and the drive command it sends have all run, however many loop
iterations that took on however slow a machine), no component of the process
:meth:`holds <ubf_async.clocks.clock.SimClock.hold>` the clock (the camera while it renders a
frame, the recorder while it writes one), and every lockstep participant of another process has
acknowledged the instant (:mod:`ubf_async.clocks.lockstep`). Only then does time advance, so a run
gives the same result at any speed, on any machine, under any load; simulated time starts
once the holds taken at the start are released (and, if asked, the participants joined).

Flat out, the barrier of an instant at which nothing of this process is due — no sleeper of
the clock wakes, no hold forbids the next step, no process elsewhere waits for the instant's
clock sample (a lockstep participant, a follower) — would find the loop idle at once: the
simulator steps on without the round of the event loop (:meth:`SimulatorComponent._step`
says whether a step gave the loop work). The run is the same, only faster: in the shipped
robot's ball-in-sight run, 5 000 steps take 1 868 rounds of the loop.

Pacing: ``speed`` K paces that lockstep to K× real time — each step is due at an absolute
wall time (start + simulated time / K, time spent held not made up afterwards); ahead of
schedule the simulator sleeps. ``speed`` ``math.inf`` runs it flat out. A machine that cannot
keep up just runs slower than K; the achieved real-time factor is reported
(:meth:`SimulatorComponent.real_time_factor`, and per 0.25 s window in
:attr:`SimulatorComponent.rtf_windows`; ``python -m bench.realtime`` measures it).
Components in other processes that are not participants follow the clock through zenoh: at
K× speed their messages cost K× the transport latency in simulated time.

:func:`simulated_devices` builds device components with simulator backends in this process,
through the registry (device kinds and ``<kind>.sim`` backends), as launch does from a robot
file.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import secrets
import time
from collections import deque
from collections.abc import Awaitable, Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from components.devices import KINDS, make_backend, make_device
from components.sim.world.physics import World
from components.sim.world.snapshot_data import snapshot_to_data
from ubf_async.assembly.context import DeviceContext
from ubf_async.clocks import lockstep
from ubf_async.clocks.clock import SimClock
from ubf_async.errors import ConfigurationError
from ubf_async.runtime import lending
from ubf_async.runtime.bus import Bus, Publisher
from ubf_async.runtime.component import Component
from ubf_async.wire.protocol import Message
from ubf_async.wire.topics import CLOCK, SIM_PULSES, SIM_TRUTH, SIM_WORLD, SimPulses

__all__ = ["CLOCK_MATCH_STEPS", "DEVICES", "RTF_WINDOWS_KEPT", "RTF_WINDOW_S", "STEP_LATENESS_KEPT",
           "SimulatorComponent", "simulated_devices"]

log = logging.getLogger(__name__)

DEVICES = KINDS
"""The devices of the simulated Mini-WHEGS."""
RTF_WINDOW_S = 0.25
CLOCK_MATCH_STEPS = 20
"""The simulator asks zenoh whether anyone follows its clock every this many steps (a
follower that appears starts receiving it within 0.1 simulated seconds)."""
RTF_WINDOWS_KEPT = 14_400
"""The last hour of wall time's windows are kept (a bounded deque, ≈ 0.5 MB)."""
STEP_LATENESS_KEPT = 12_000
"""The last minute of 5 ms steps' lateness is kept (a bounded deque, ≈ 0.4 MB)."""


@dataclass(slots=True, kw_only=True)
class _Served:
    """What the simulator publishes for one robot of its world."""

    robot: int
    bus: Bus
    clock: Publisher
    truth: Publisher
    world: Publisher
    clock_followed: bool = True
    zid: str | None = None
    """The bus's session id, which its clock samples carry (a follower connected to this
    session prefers this run to any other it hears)."""


@dataclass(slots=True, kw_only=True)
class _Schedule:
    """What the stepping carries from one step to the next."""

    origin_s: float
    """Wall time at which simulated time started, moved on by the time spent held."""
    window_wall_s: float
    window_sim_s: float
    next_truth_s: float
    next_world_s: float
    steps: int = 0


class SimulatorComponent(Component):
    def __init__(
        self,
        *,
        bus: Bus,
        world: World,
        clock: SimClock,
        speed: float = 1.0,
        step_s: float = 0.005,
        truth_period_s: float = 0.05,
        world_period_s: float = 0.02,
        name: str = "sim",
        more_robots: Sequence[Bus] = (),
        lockstep_participants: int = 0,
        **component_options: float,
    ) -> None:
        """``more_robots``: a fleet's further robots of ``world`` (robot ``i`` on
        ``more_robots[i - 1]``, a bus of that robot's name sharing ``clock``): each gets the
        clock, its truth and its view of the world on its own keys, and its pulses from
        there. ``lockstep_participants``: simulated time starts only once this many lockstep
        participants of other processes have joined (:mod:`ubf_async.clocks.lockstep`), so a run
        with them is repeatable from its first instant."""
        super().__init__(bus=bus, name=name, **component_options)
        if lockstep_participants < 0:
            raise ValueError(f"lockstep_participants must be >= 0, got {lockstep_participants}")
        self.lockstep_participants = lockstep_participants
        if len(more_robots) != world.robot_count - 1:
            raise ValueError(f"the world has {world.robot_count} robots: give a bus for each "
                             f"but the first ({world.robot_count - 1}), not {len(more_robots)}")
        self.more_robots = tuple(more_robots)
        if not speed > 0:
            raise ValueError(f"speed must be > 0, got {speed}")
        self.world = world
        self.clock = clock
        self.speed = speed
        self.step_s = step_s
        self.truth_period_s = truth_period_s
        self.world_period_s = world_period_s
        self.malformed: dict[str, int] = {}
        self.epoch = secrets.token_hex(8)
        """This run's id on ``ubf/<robot>/clock``: the same across restarts of the component
        (its time goes on), a new one for every simulator."""
        self.wall_started_s: float | None = None
        self.wall_stopped_s: float | None = None
        self.sim_started_s = world.time_s
        self.late_steps = 0
        self.rtf_windows: deque[float] = deque(maxlen=RTF_WINDOWS_KEPT)
        """Real-time factor over each successive ``RTF_WINDOW_S`` of wall time (the last
        ``RTF_WINDOWS_KEPT``): shows whether the run kept up throughout, not just on average."""
        self._lockstep = lockstep.LockstepBarrier((bus, *self.more_robots))
        self._idle: Callable[[], Awaitable[None]] | None = None
        self.step_lateness_s: deque[float] = deque(maxlen=STEP_LATENESS_KEPT)
        """How late each step started, in wall seconds after its due time (the last
        ``STEP_LATENESS_KEPT``): what every follower of this clock inherits as tick jitter
        (``bench.fleet_scaling``)."""

    def real_time_factor(self) -> float | None:
        """Simulated seconds per wall second from the simulator's start (once the components
        holding the start were ready) until now, or until it stopped."""
        if self.wall_started_s is None:
            return None
        end = self.wall_stopped_s if self.wall_stopped_s is not None else time.monotonic()
        wall = end - self.wall_started_s
        return (self.world.time_s - self.sim_started_s) / wall if wall > 0 else None

    def _pulses_handler(self, robot: int) -> Callable[[str, Message[SimPulses], int], None]:
        def on_pulses(key: str, message: Message[SimPulses], received_ns: int) -> None:
            """Motor pulses from a motors component in another process."""
            self.world.set_motor_pulses(message.data.left_ms, message.data.right_ms,
                                        robot=robot)

        return on_pulses

    def truth(self, robot: int = 0) -> dict[str, object]:
        snap = self.world.snapshot_for(robot)
        state = snap.robot
        out: dict[str, object] = {
            "time_s": snap.time_s,
            "robot": {"x_m": state.x_m, "y_m": state.y_m, "heading_rad": state.heading_rad,
                      "speed_m_s": state.forward_speed_m_s, "yaw_rate_rad_s": state.yaw_rate_rad_s,
                      "left_wheel_rad": state.left_wheel_angle_rad,
                      "right_wheel_rad": state.right_wheel_angle_rad},
        }
        if snap.ball is not None:
            out["ball"] = {"x_m": snap.ball.x_m, "y_m": snap.ball.y_m}
        return out

    async def run(self) -> None:
        idle = lending.idle_waiter(asyncio.get_running_loop())
        if idle is None:
            raise ConfigurationError(
                "simulated time advances in lockstep, which needs ubf_async's event loop "
                "(lending.new_idle_event_loop, the default of every entry point, or "
                "UBF_LOOP=lending); uvloop cannot tell when a step's work is done")
        self._idle = idle
        served = [self._serve(bus, robot)
                  for robot, bus in enumerate((self.bus, *self.more_robots))]
        for subscription in self._lockstep.open():
            self.keep(subscription)
        with self.clock.driven():
            self.clock.advance_to(round(self.world.time_s * 1e9))
            # Components of this process that are still getting ready (the camera building
            # its renderer's caches) hold the start: time starts, and is measured, once they
            # are done. Meanwhile the world goes out with the clock, so that sim-backed
            # devices elsewhere can attach (and join the lockstep) however long that takes.
            await self._barrier(served, self.clock.now_ns() + 1, starting=True)
            if self.lockstep_participants:
                await self._wait_for_participants(served)
            self.wall_started_s = time.monotonic()
            self.sim_started_s = self.world.time_s
            self.wall_stopped_s = None
            try:
                await self._step_forever(served, self.wall_started_s)
            finally:
                self.wall_stopped_s = time.monotonic()

    def _serve(self, bus: Bus, robot: int) -> _Served:
        """Publishers of one robot's clock, truth and world, and its pulses' subscription
        (closed when the run attempt ends)."""
        served = _Served(robot=robot, bus=bus, clock=bus.publisher(CLOCK, period_s=self.step_s),
                         truth=bus.publisher(SIM_TRUTH, period_s=self.truth_period_s),
                         world=bus.publisher(SIM_WORLD, period_s=self.world_period_s),
                         zid=bus.session_id)
        for resource in (served.clock, served.truth, served.world,
                         bus.subscribe_topic(SIM_PULSES.key(bus.keys), SIM_PULSES,
                                             self._pulses_handler(robot), self.malformed)):
            self.keep(resource)
        return served

    async def _step_forever(self, served: list[_Served], started_s: float) -> None:
        schedule = _Schedule(origin_s=started_s, window_wall_s=started_s,
                             window_sim_s=self.world.time_s, next_truth_s=self.world.time_s,
                             next_world_s=self.world.time_s)
        step_ns = round(self.step_s * 1e9)
        while True:
            next_ns = self.clock.now_ns() + step_ns
            barrier_started_s = time.monotonic()
            waited = await self._barrier(served, next_ns)
            if waited:  # time spent held is not made up afterwards in a burst of fast steps
                schedule.origin_s += time.monotonic() - barrier_started_s
            if self.speed != math.inf:
                await self._pace(schedule)
            busy = self._step(served, schedule)
            # Flat out, the instants at which nothing of this process is due pass without a
            # round of the event loop: the barrier would find it idle at once (module
            # docstring, Lockstep), so the run is the same, only faster.
            while (self.speed == math.inf and not busy
                   and self._barrier_is_idle(served, self.clock.now_ns() + step_ns)):
                busy = self._step(served, schedule)

    async def _pace(self, schedule: _Schedule) -> None:
        """Sleep until the next step is due at ``speed`` × real time."""
        due_s = schedule.origin_s + (self.world.time_s + self.step_s
                                     - self.sim_started_s) / self.speed
        delay = due_s - time.monotonic()
        if delay > 0:
            # The loop's timer has ~1 ms resolution, so this may oversleep; the schedule is
            # absolute, and the steps that fall due meanwhile run back to back.
            await asyncio.sleep(delay)
        else:
            self.late_steps += 1
        self.step_lateness_s.append(max(0.0, time.monotonic() - due_s))

    def _barrier_is_idle(self, served: list[_Served], next_ns: int) -> bool:
        """Whether the barrier before the step to ``next_ns`` would pass at once, the event
        loop having run nothing since the last step: no hold forbids it, and no process
        elsewhere waits for this instant's clock sample (a lockstep participant, a follower)."""
        held = self.clock.held_until_ns()
        return ((held is None or held >= next_ns) and not self._lockstep.has_participants()
                and not any(robot.clock_followed for robot in served))

    def _step(self, served: list[_Served], schedule: _Schedule) -> bool:
        """One step of the world and the clock, and what is published with it. Returns
        whether it gave the event loop work: a sleeper woken, a sample published."""
        self.world.advance(self.step_s)
        now_s = self.world.time_s
        now_ns = round(now_s * 1e9)
        wakeup = self.clock.next_wakeup_ns()
        busy = wakeup is not None and wakeup <= now_ns
        self.clock.advance_to(now_ns)
        wall_s = time.monotonic()
        if wall_s - schedule.window_wall_s >= RTF_WINDOW_S:
            self.rtf_windows.append((now_s - schedule.window_sim_s)
                                    / (wall_s - schedule.window_wall_s))
            schedule.window_wall_s, schedule.window_sim_s = wall_s, now_s
        schedule.steps += 1
        # Whether anyone follows the clock, asked every CLOCK_MATCH_STEPS steps (zenoh's
        # check is not free); the clock sample itself goes out at the barrier.
        if schedule.steps % CLOCK_MATCH_STEPS == 1:
            for robot in served:
                robot.clock_followed = robot.clock.has_subscribers()
        truth_due = now_s >= schedule.next_truth_s
        world_due = now_s >= schedule.next_world_s
        for robot in served:
            # Truth and the world snapshot cost encoding time on the loop: build them only
            # when some process listens (zenoh knows its matching subscribers).
            if truth_due and robot.truth.has_subscribers():
                robot.truth.publish(self.truth(robot.robot), stamp_ns=now_ns)
                busy = True
            if world_due and robot.world.has_subscribers():
                self._publish_world(robot)
                busy = True
        if truth_due:
            schedule.next_truth_s += self.truth_period_s
        if world_due:
            schedule.next_world_s += self.world_period_s
        return busy

    def _publish_world(self, robot: _Served) -> None:
        robot.world.publish(snapshot_to_data(self.world.snapshot_for(robot.robot)),
                            stamp_ns=self.clock.now_ns())

    def _publish_clock(self, robot: _Served) -> None:
        rtf = self.real_time_factor()
        robot.clock.publish({"real_time_factor": rtf or 0.0, "epoch": self.epoch,
                             "zid": robot.zid}, stamp_ns=self.clock.now_ns())

    async def _barrier(self, served: list[_Served], next_ns: int, *,
                       starting: bool = False) -> bool:
        """The lockstep barrier before the step to ``next_ns``; return whether a hold made it
        wait. In order:

        1. everything of the current instant in this process is done: the event loop had
           nothing left to run (:meth:`~ubf_async.runtime.lending.IdleEventLoop.idle`) and no
           hold forbids ``next_ns`` (a camera render, a frame being written, a device
           getting ready) — while a hold keeps it waiting, the clock sample is sent again
           every :data:`~ubf_async.clocks.lockstep.RESEND_S` of wall time, so followers in other
           processes know the simulator is alive (:class:`~ubf_async.clocks.clock.SilenceLimit`)
           — and, ``starting``, the world with it (:meth:`_announce`);
        2. the clock sample of this instant goes out to the processes that follow it — after
           the samples of this instant, which zenoh delivers first;
        3. every lockstep participant of another process has acknowledged this instant
           (:mod:`ubf_async.clocks.lockstep`), and what they sent for it has been handled here.
        """
        idle = self._idle
        assert idle is not None, "run() sets it"
        waited = False
        while True:
            await idle()
            held = self.clock.held_until_ns()
            if held is None or held >= next_ns:
                break
            waited = True
            await lockstep.wait_resending(
                self.clock.wait_for_holds(next_ns),
                (lambda: self._announce(served)) if starting
                else (lambda: self._publish_clocks(served)))
        self._publish_clocks(served)
        if self._lockstep.has_participants():
            await self._lockstep.wait(self.clock.now_ns(),
                                      resend=lambda: self._publish_clocks(served))
            await idle()
        return waited

    async def _wait_for_participants(self, served: list[_Served]) -> None:
        """Before time starts: until :attr:`lockstep_participants` participants have joined
        and acknowledged the start (the clock sample is sent again meanwhile, so they find
        it), or :data:`~ubf_async.clocks.lockstep.JOIN_WAIT_S` has passed (then with a warning)."""
        barrier = self._lockstep
        log.info("simulated time waits for %d lockstep participant(s)",
                 self.lockstep_participants)
        deadline = time.monotonic() + lockstep.JOIN_WAIT_S
        while len(barrier.participants) < self.lockstep_participants:
            if time.monotonic() > deadline:
                log.warning("only %d of %d lockstep participants joined within %g s: "
                            "simulated time starts without the others",
                            len(barrier.participants), self.lockstep_participants,
                            lockstep.JOIN_WAIT_S)
                break
            barrier.changed.clear()
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(barrier.changed.wait(), lockstep.RESEND_S)
            self._announce(served, force=True)
        await self._barrier(served, self.clock.now_ns() + 1)

    def _announce(self, served: list[_Served], *, force: bool = False) -> None:
        """Before time starts: the clock sample of now (:meth:`_publish_clocks`) and the
        world, to each robot whose world someone elsewhere waits for — sim-backed devices
        in other processes attach once they see it."""
        self._publish_clocks(served, force=force)
        for robot in served:
            if robot.world.has_subscribers():
                self._publish_world(robot)

    def _publish_clocks(self, served: list[_Served], *, force: bool = False) -> None:
        """The clock sample of now, to each robot's followers and participants (to each
        robot with ``force``)."""
        for robot in served:
            if (force or robot.clock_followed
                    or self._lockstep.has_participants(robot.bus.robot)):
                self._publish_clock(robot)


def simulated_devices(
    *,
    bus: Bus,
    world: World,
    devices: Iterable[str] = DEVICES,
    seed: int = 0,
    params: Mapping[str, Mapping[str, Any]] | None = None,
    camera_latency_s: float | None = None,
    motor_timeout_s: float | None = None,
) -> list[Component]:
    """The robot's device components with ``<kind>.sim`` backends on ``world``, in this
    process, each under its kind's usual name and built through the registry.

    ``params`` maps a kind to its device parameters (``{"range": {"yaw_deg": 45}}``);
    ``camera_latency_s`` and ``motor_timeout_s`` are shorthands for the camera's
    ``latency_s`` and the motors' ``timeout_s``. ``seed`` is the run's seed.
    """
    wanted = list(devices)
    unknown = sorted(set(wanted) - set(DEVICES))
    if unknown:
        raise ValueError(f"unknown device(s) {unknown}; choose from {list(DEVICES)}")
    chosen: dict[str, dict[str, Any]] = {kind: dict(p) for kind, p in (params or {}).items()}
    if camera_latency_s is not None:
        chosen.setdefault("camera", {})["latency_s"] = camera_latency_s
    if motor_timeout_s is not None:
        chosen.setdefault("motors", {})["timeout_s"] = motor_timeout_s
    context = DeviceContext(bus=bus, clock=bus.clock, seed=seed, simulation=world)
    out: list[Component] = []
    for kind in DEVICES:  # in a fixed order, whatever the order asked for
        if kind in wanted:
            backend = make_backend(kind, "sim", context=context)
            out.append(make_device(kind, context=context, backend=backend,
                                   params=chosen.get(kind)))
    return out
