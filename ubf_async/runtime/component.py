"""Components: supervised async resources with a liveliness token and a heartbeat.

A component is used as ``async with SomeComponent(bus=bus, ...) as c:`` or started with
``await c.start()`` and stopped with ``await c.aclose()``. ``aclose()`` always closes — its
tasks, everything :meth:`Component.run` opened, its token — and calling it twice is harmless.

Lifecycle — when each hook runs:

* :meth:`Component.run` runs in the component's own task once :meth:`start` is called, and
  is expected to run until cancelled. Publishers and subscriptions it opens through
  :meth:`publisher` / :meth:`subscribe` are closed when it ends, however it ends.
* If ``run`` raises, the error is logged with its traceback, counted in ``restarts`` and
  ``run`` is called again after a backoff (doubling from ``restart_backoff_s`` up to
  ``max_backoff_s``, reset after ``run`` has stayed up for ``healthy_after_s``). Other
  components are unaffected.
* If ``run`` returns normally the component has finished its work; it stays "alive" (token
  and heartbeat) until closed.

Liveness: the token ``ubf/<robot>/alive/<name>`` only proves that the zenoh session lives.
The heartbeat (``ubf/<robot>/heartbeat/<name>``, every ``heartbeat_period_s``) proves the
component's event loop is turning: it carries a sequence number, the number of restarts and
the loop lag the heartbeat task itself observed, what it publishes (each publisher's ``pub``)
and its process (pid and host), so that a receiver can name the process behind a sample.
:class:`HealthMonitor` checks both.

Leaving: a component that closes says goodbye — one last heartbeat with ``leaving`` before its
token goes — so that the robot reports it **left**; one whose token vanishes without it (a
killed process, a lost link) is **gone**. Neither is a fault of the robot's: the sources they
published are reported as theirs, not as refusals (:meth:`HealthMonitor.departure`).
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import logging
import os
import socket
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import Any, TypeVar

from ubf_async.clocks.port import Closing
from ubf_async.errors import NameTakenError
from ubf_async.runtime.bus import Bus, Lane, Publisher, SampleHandler, Screen, Subscription
from ubf_async.wire.protocol import Message
from ubf_async.wire.topics import (
    HEARTBEAT,
    MAX_ANNOUNCED,
    MAX_ANNOUNCED_KEY_CHARS,
    Heartbeat,
    Published,
    Topic,
)

__all__ = ["HOST", "MAX_WATCHED_COMPONENTS", "Component", "ComponentHealth", "Departure",
           "EveryMessageComponent", "HealthMonitor", "ensure_name_free"]

T = TypeVar("T")

log = logging.getLogger(__name__)

HOST = socket.gethostname()[:253] or None
"""This host's name, as heartbeats name it."""
MAX_WATCHED_COMPONENTS = 1024
"""Components the :class:`HealthMonitor` keeps track of (the oldest departed one goes first)."""


async def ensure_name_free(bus: Bus, name: str, *, hint: str = "", timeout_s: float = 2.0
                           ) -> None:
    """Refuse to join under a name another process already uses on this robot.

    A process that attaches a component to a running robot (a standalone device, a remote
    behaviour's host) calls this before :meth:`Component.start`: two components under one
    name would share a liveliness token and their samples would silently merge into one
    source. Raises :class:`NameTakenError` when the token ``ubf/<robot>/alive/<name>`` is
    alive (``hint`` says how to pick another name). Two processes checking in the same
    instant can still both pass; the check is for the honest mistake, not an attacker.
    """
    key = bus.keys.alive(name)
    if await bus.alive_tokens(key, timeout_s=timeout_s):
        raise NameTakenError(
            f"a component named {name!r} is already alive on robot {bus.robot!r} ({key}); "
            f"{hint or 'give this one another name'}")


class Component:
    """Base class of every component. Subclasses implement :meth:`run`."""

    def __init__(
        self,
        *,
        bus: Bus,
        name: str,
        heartbeat_period_s: float = 0.5,
        restart_backoff_s: float = 0.1,
        max_backoff_s: float = 5.0,
        healthy_after_s: float = 10.0,
    ) -> None:
        self.bus = bus
        self.name = name
        self.heartbeat_period_s = heartbeat_period_s
        self.restart_backoff_s = restart_backoff_s
        self.max_backoff_s = max_backoff_s
        self.healthy_after_s = healthy_after_s
        self.restarts = 0
        self.last_error: BaseException | None = None
        self.running = asyncio.Event()
        """Set while :meth:`run` is executing (cleared between restarts)."""
        self._tasks: list[asyncio.Task[None]] = []
        self._token: Any = None
        self._attempt_resources: list[Publisher | Closing] = []
        self._started = False
        self._closed = False
        self._on_close: list[Callable[[], Awaitable[object]]] = []

    # -- for subclasses ----------------------------------------------------------------------
    async def run(self) -> None:
        """The component's work; runs until cancelled. Override this."""
        raise NotImplementedError

    def publisher(self, topic: Topic[Any] | str, *parts: str, period_s: float | None = None,
                  trusted: bool = False, **named_parts: str) -> Publisher:
        """A publisher (:meth:`Bus.publisher <ubf_async.runtime.bus.Bus.publisher>`) closed
        automatically when this run attempt ends."""
        pub = self.bus.publisher(topic, *parts, period_s=period_s, trusted=trusted,
                                 **named_parts)
        self._attempt_resources.append(pub)
        return pub

    def subscribe(
        self, key_expr: str, handler: SampleHandler, *, latest: bool = True,
        direct: bool = False,
    ) -> Subscription:
        """A subscription closed automatically when this run attempt ends (``direct``: see
        :meth:`Bus.subscribe <ubf_async.runtime.bus.Bus.subscribe>`)."""
        return self._keep_for_attempt(
            self.bus.subscribe(key_expr, handler, latest=latest, direct=direct))

    def subscribe_screened(self, key_expr: str, screen: Screen, *, latest: bool = True,
                           direct: bool = False, lane: Lane | None = None) -> Subscription:
        """:meth:`Bus.subscribe_screened <ubf_async.runtime.bus.Bus.subscribe_screened>`,
        closed automatically when this run attempt ends."""
        return self._keep_for_attempt(self.bus.subscribe_screened(
            key_expr, screen, latest=latest, direct=direct, lane=lane))

    def subscribe_topic(self, key_expr: str, topic: Topic[T],
                        on_message: Callable[[str, Message[T], int], None],
                        malformed: dict[str, int], *, latest: bool = True) -> Subscription:
        """:meth:`Bus.subscribe_topic <ubf_async.runtime.bus.Bus.subscribe_topic>` (decoded
        samples; malformed ones counted in ``malformed`` and never displacing a valid one),
        closed automatically when this run attempt ends."""
        return self._keep_for_attempt(
            self.bus.subscribe_topic(key_expr, topic, on_message, malformed, latest=latest))

    def _keep_for_attempt(self, sub: Subscription) -> Subscription:
        self._attempt_resources.append(sub)
        return sub

    def publishes(self, key: str) -> bool:
        """Whether this run attempt publishes on ``key`` (through :meth:`publisher`): a
        process attaching a component tells its user what the robot refuses of it
        (:class:`~ubf_async.runtime.refusals.RefusalWatch`)."""
        return any(isinstance(r, Publisher) and r.key == key for r in self._attempt_resources)

    def keep(self, resource: Publisher | Closing) -> None:
        """Close ``resource`` (made on another bus than the component's, say) when this run
        attempt ends, as :meth:`publisher` and :meth:`subscribe` do for theirs."""
        self._attempt_resources.append(resource)

    def close_on_exit(self, close: Callable[[], Awaitable[object]]) -> None:
        """Await ``close()`` when this component closes, after its run has stopped (a device's
        backend is closed with its device: releasing pins only once nothing drives them).
        One that raises is logged; the others still run."""
        self._on_close.append(close)

    # -- lifecycle ---------------------------------------------------------------------------
    async def start(self) -> None:
        if self._closed:
            raise RuntimeError(f"component {self.name!r} is closed")
        if self._started:
            return
        self._started = True
        self._tasks = [asyncio.create_task(self._supervise(), name=f"{self.name}:run")]
        alive = self.bus.keys.alive(self.name)
        if self.bus.rights.allows("liveliness_token", alive):
            self._token = self.bus.declare_token(alive)
            self._tasks.append(asyncio.create_task(self._heartbeat(),
                                                   name=f"{self.name}:heartbeat"))
        else:  # a read-only identity (the inspector's, recording): it observes unannounced
            log.info("component %s runs unannounced: its identity may not announce itself "
                     "on %s (secure mode)", self.name, alive)

    async def aclose(self) -> None:
        """Stop and release everything. Idempotent; safe even if never started."""
        if self._closed:
            return
        self._closed = True
        for task in self._tasks:
            task.cancel()
        for task in self._tasks:
            with contextlib.suppress(asyncio.CancelledError):
                await task
        self._release_attempt()
        if self._token is not None:
            with contextlib.suppress(Exception):
                self._token.undeclare()
            self._token = None
        closers, self._on_close = self._on_close, []
        for close in closers:
            try:
                await close()
            except Exception:
                log.exception("component %s: closing %r failed", self.name, close)

    async def __aenter__(self) -> Component:
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.aclose()

    @property
    def closed(self) -> bool:
        return self._closed

    # -- internals ---------------------------------------------------------------------------
    def _release_attempt(self) -> None:
        resources, self._attempt_resources = self._attempt_resources, []
        for resource in reversed(resources):
            resource.close()

    async def _supervise(self) -> None:
        # Timed on the loop's clock, the one the backoff sleeps on (CLOCK_MONOTONIC, as
        # time.monotonic(); a test's virtual time when it runs the loop on one).
        loop = asyncio.get_running_loop()
        task = asyncio.current_task()
        assert task is not None, "start() runs it as a task"
        backoff = self.restart_backoff_s
        while True:
            started = loop.time()
            self.running.set()
            try:
                await self.run()
            except asyncio.CancelledError:
                raise
            except Exception as exc:
                if task.cancelling():
                    # Cancelled (closed), and what the run did on its way out failed: the
                    # motors' stop pulse published on a session already closed, say. That is
                    # the component's end, not a failure: a restart would run it again, and
                    # fail again, on whatever is gone — a task that never ends when
                    # cancelled (an event loop's teardown that waited for it for ever).
                    log.warning("component %s: its run failed while closing: %r", self.name,
                                exc)
                    raise asyncio.CancelledError from exc
                self.last_error = exc
                self.restarts += 1
                if loop.time() - started >= self.healthy_after_s:
                    backoff = self.restart_backoff_s
                log.exception(
                    "component %s failed (restart #%d in %.2fs)", self.name, self.restarts, backoff
                )
            else:
                log.info("component %s finished its run", self.name)
                return
            finally:
                self.running.clear()
                self._release_attempt()
            await asyncio.sleep(backoff)  # real time: backoff protects the host, not the sim
            backoff = min(self.max_backoff_s, backoff * 2)

    def _announced(self) -> list[dict[str, Any]]:
        """What this run attempt publishes (the heartbeat's ``publishes``: tools name a key's
        publishers by it, docs/protocol.md)."""
        publishers = (r for r in self._attempt_resources
                      if isinstance(r, Publisher) and len(r.key) <= MAX_ANNOUNCED_KEY_CHARS)
        return [{"key": p.key, "pub": p.pub}
                for p in itertools.islice(publishers, MAX_ANNOUNCED)]

    async def _heartbeat(self) -> None:
        pub = self.bus.publisher(HEARTBEAT, self.name,
                                 period_s=self.heartbeat_period_s)
        loop = asyncio.get_running_loop()  # the lag on the clock the sleep runs on
        try:
            lag = 0.0
            while True:
                pub.publish({
                    "component": self.name,
                    "restarts": self.restarts,
                    "loop_lag_s": lag,
                    "running": "yes" if self.running.is_set() else "no",
                    "publishes": self._announced(),
                    "pid": os.getpid(),  # (asked each time: a forked child is another)
                    "host": HOST,
                })
                expected = loop.time() + self.heartbeat_period_s
                await asyncio.sleep(self.heartbeat_period_s)
                lag = max(0.0, loop.time() - expected)
        finally:
            if self._closed:  # the goodbye, before aclose() lets the token go
                with contextlib.suppress(Exception):  # a session already closed: gone, then
                    pub.publish({"component": self.name, "restarts": self.restarts,
                                 "running": "no", "leaving": True, "pid": os.getpid(),
                                 "host": HOST})
            pub.close()


class EveryMessageComponent(Component):
    """A component that takes every message of its robot (``ubf/<robot>/**``), each in order
    (``latest=False``), until closed: the recorder's and the live view's base. Subclasses
    implement :meth:`_on_message`."""

    async def run(self) -> None:
        self.subscribe(f"{self.bus.keys.prefix}/**", self._on_message, latest=False)
        await asyncio.Event().wait()  # until closed: the subscription does the work

    def _on_message(self, key: str, payload: bytes, received_ns: int) -> None:
        """One message, on the event loop. Override this."""
        raise NotImplementedError


@dataclass
class ComponentHealth:
    name: str
    alive: bool = False
    """Liveliness token present."""
    last_heartbeat_s: float | None = None
    """Host monotonic time the last heartbeat arrived."""
    heartbeat_period_s: float | None = None
    restarts: int = 0
    loop_lag_s: float = 0.0
    publishes: tuple[Published, ...] = ()
    """What its newest heartbeat announces it publishes (empty: it does not say); kept from
    before its goodbye once it has left."""
    departed: Departure | None = None
    """Once it has left (said goodbye) or is gone (its token vanished without one)."""

    def healthy(self, now_s: float, *, missed: float = 3.0) -> bool:
        """Alive, and — if it sends heartbeats — its last not more than ``missed`` periods
        late (host monotonic time). A component that has sent none is judged by its token:
        heartbeats are optional (a microcontroller's component may send none), and a joiner's
        token may be heard before its first heartbeat."""
        if not self.alive:
            return False
        if self.last_heartbeat_s is None:
            return True
        period = self.heartbeat_period_s or 1.0
        return now_s - self.last_heartbeat_s <= missed * period

    def announces(self, key: str, pub: int | None) -> bool:
        """Whether its heartbeat announced publishing on ``key`` (with that ``pub``, if
        the sample carried one)."""
        return any(p.key == key and (pub is None or p.pub == pub) for p in self.publishes)


@dataclass(frozen=True, slots=True)
class Departure:
    """A component that is no longer there: ``how`` it went — ``"left"`` (it said goodbye)
    or ``"gone"`` (its token vanished without one) — and when (host monotonic seconds)."""

    component: str
    how: str
    at_s: float

    def describe(self, now_s: float) -> str:
        """``LEFT 3.2s ago`` — for a status line."""
        return f"{self.how.upper()} {max(0.0, now_s - self.at_s):.1f}s ago"

    def explain(self, now_s: float) -> str:
        """The inspector's sentence."""
        why = "said goodbye" if self.how == "left" else "vanished without a goodbye"
        return f"its component {self.component} {why} {max(0.0, now_s - self.at_s):.1f}s ago"


class HealthMonitor:
    """Watches the robot's liveliness tokens and heartbeats (the watchdog's eyes)."""

    def __init__(self, bus: Bus) -> None:
        self.bus = bus
        self.components: dict[str, ComponentHealth] = {}
        self.malformed: dict[str, int] = {}
        self._subs: list[Subscription] = []
        self.changed = asyncio.Event()

    def start(self) -> None:
        keys = self.bus.keys
        self._subs.append(self.bus.watch_liveliness(keys.all_alive, self._on_liveliness))
        self._subs.append(self.bus.subscribe_topic(keys.all_heartbeats, HEARTBEAT,
                                                   self._on_heartbeat, self.malformed))

    def close(self) -> None:
        for sub in self._subs:
            sub.close()
        self._subs = []

    def _entry(self, name: str) -> ComponentHealth:
        entry = self.components.get(name)
        if entry is None:
            if len(self.components) >= MAX_WATCHED_COMPONENTS:
                # Bounded against junk heartbeat names: a departed component goes first.
                gone = next((n for n, h in self.components.items() if not h.alive),
                            next(iter(self.components)))
                del self.components[gone]
            entry = self.components[name] = ComponentHealth(name)
        return entry

    def _on_liveliness(self, key: str, alive: bool) -> None:
        name = self.bus.keys.component_of_alive(key)
        entry = self._entry(name)
        entry.alive = alive
        if alive:
            entry.departed = None  # back (a restart under the same name)
        elif entry.departed is None:  # no goodbye came first
            entry.departed = Departure(name, "gone", time.monotonic())
        self.changed.set()

    def _on_heartbeat(self, key: str, message: Message[Heartbeat], received_ns: int) -> None:
        data = message.data
        name = key.rsplit("/", 1)[-1]
        entry = self._entry(name)
        if data.leaving:
            # A goodbye may come just after its token's end was heard: still "left", as of
            # when the first of the two came.
            at_s = entry.departed.at_s if entry.departed is not None else time.monotonic()
            entry.departed = Departure(name, "left", at_s)
            self.changed.set()
            return
        entry.departed = None
        entry.last_heartbeat_s = received_ns / 1e9
        entry.heartbeat_period_s = message.period_s
        entry.restarts = data.restarts
        entry.loop_lag_s = data.loop_lag_s
        entry.publishes = data.publishes
        self.changed.set()

    def departure(self, key: str, pub: int | None) -> Departure | None:
        """How the component that announced publishing on ``key`` (with ``pub``) went, if it
        has: the state aggregator reports such a source as left or gone, not as stale."""
        for health in self.components.values():
            if health.departed is not None and health.announces(key, pub):
                return health.departed
        return None

    async def heard_from_all(self, within_s: float) -> bool:
        """Wait until every component whose token this has seen has also sent a heartbeat
        (which announces what it publishes), at most ``within_s``; whether it came to that.
        Call after :meth:`start`: on a busy machine the robot's tokens and heartbeats can take
        seconds to arrive, and a judgement on "who publishes what" must not come before."""
        loop = asyncio.get_running_loop()
        deadline = loop.time() + within_s
        while True:
            self.changed.clear()
            alive = [h for h in self.components.values() if h.alive]
            if alive and all(h.last_heartbeat_s is not None for h in alive):
                return True
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self.changed.wait(), deadline - loop.time())
            if loop.time() >= deadline:
                return False

    def alive_names(self) -> list[str]:
        return sorted(name for name, h in self.components.items() if h.alive)

    def unhealthy(self) -> list[str]:
        now = time.monotonic()
        return sorted(name for name, h in self.components.items()
                      if h.alive and h.departed is None and not h.healthy(now))
